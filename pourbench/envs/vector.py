"""Vector ``pourbench/Pour-v0``: N worlds in one fluid solver, Gymnasium 1.x autoreset.

``gymnasium.make_vec("pourbench/Pour-v0", num_envs=N, vectorization_mode="vector_entry_point")``
returns a :class:`PourVectorEnv`. One :class:`~pourbench.envs.core.PourBatch` steps all worlds
with one kernel launch per solver stage. World ``k`` reset with seed ``s + k`` follows the
same episodes as a single :class:`~pourbench.envs.pour.PourEnv` reset with that seed.

Autoreset: ``"next_step"`` (Gymnasium's default): a world whose episode ended is reset on the
next ``step`` call, which then returns its first observation with reward 0 and ignores its
action. ``"same_step"``: a finished world is reset within the same ``step``; its last
observation and info are in ``info["final_obs"]`` / ``info["final_info"]``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from pourbench.envs.core import PourBatch
from pourbench.envs.pour import RENDER_SIZE, action_space, make_config, observation_space
from pourbench.envs.pour import render_world as _render_world
from pourbench.errors import InvalidParameterError, check_int

_MODES = {"next_step": AutoresetMode.NEXT_STEP, "same_step": AutoresetMode.SAME_STEP}


class PourVectorEnv(VectorEnv):
    """``num_envs`` pouring worlds stepped together (see the module docstring).

    Args:
        num_envs: number of worlds.
        autoreset_mode: "next_step" (default) or "same_step".
        render_mode: None or "rgb_array" (``render()`` returns one image per world).
        **kwargs: fields of :class:`~pourbench.envs.core.PourConfig`.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"],
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        autoreset_mode: str | AutoresetMode = "next_step",
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        mode = _MODES.get(autoreset_mode, autoreset_mode)
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ValueError(
                f"autoreset_mode must be one of {list(_MODES)}, got {autoreset_mode!r}"
            )
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.num_envs = check_int("num_envs", num_envs, minimum=1)
        self.batch = PourBatch(self.num_envs, make_config(**kwargs))
        self.config = self.batch.config
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.render_mode = render_mode
        self.single_observation_space = observation_space()
        self.single_action_space = action_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._needs_reset = np.zeros(self.num_envs, bool)
        self._renderer: mujoco.Renderer | None = None

    def set_lesson(self, k: int) -> None:
        """Draw liquids from curriculum lesson ``k`` at later resets, in every world."""
        self.batch.set_lesson(k)

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every world (or those in ``options["reset_mask"]``).

        ``seed``: an int ``s`` seeds world ``k`` with ``s + k``; a list gives one per world.
        Other ``options`` (liquid, target_g, container, initial_g, start) apply to every
        world reset.
        """
        # everything is checked before the first world is reset
        first: int | None = None
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, list | tuple | np.ndarray):
            if len(seed) != self.num_envs:
                raise InvalidParameterError(f"{len(seed)} seeds for {self.num_envs} worlds")
            seeds = [None if s is None else check_int("seed", s, minimum=0) for s in seed]
        else:
            first = check_int("seed", seed, minimum=0)
            seeds = [first + k for k in range(self.num_envs)]
        opts = dict(options or {})
        mask = np.asarray(opts.pop("reset_mask", np.ones(self.num_envs, bool)))
        if mask.shape != (self.num_envs,) or mask.dtype != bool:
            raise InvalidParameterError(
                f"reset_mask must be {self.num_envs} booleans, got {mask.tolist()!r}"
            )
        never = [k for k in range(self.num_envs) if not mask[k] and self.batch.worlds[k] is None]
        if never:
            raise InvalidParameterError(
                f"reset_mask leaves world {never[0]} unreset, and it was never reset"
            )
        super().reset(seed=first)
        for k in np.flatnonzero(mask):
            self.batch.reset_world(int(k), seeds[k], opts)
        self.batch.flush()
        self._needs_reset[mask] = False
        info = self._info(self.batch.measure(), mask)
        return self.batch.observe(), info

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        resetting = self._needs_reset.copy()
        # every world's physics advances together; a world due for its next-step autoreset
        # holds still through this step and is reset after it, so it returns its first
        # observation of the new episode (the batch checks the actions)
        obs, rew, term, trunc, info = self.batch.step(actions, active=~resetting)
        if resetting.any():
            for k in np.flatnonzero(resetting):
                self.batch.reset_world(int(k))
            self.batch.flush()
            obs = self.batch.observe()
            fresh = self.batch.measure()
            for key, v in fresh.items():
                info[key] = np.where(resetting, v, info[key])
            for key in ("collided", "sim_diverged", "is_success"):
                info[key] = info[key] & ~resetting
        rew = np.where(resetting, 0.0, rew)
        term, trunc = term & ~resetting, trunc & ~resetting
        infos = self._info(info, np.ones(self.num_envs, bool))
        done = term | trunc
        if self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            final = np.empty(self.num_envs, dtype=object)
            for k in np.flatnonzero(done):
                final[k] = obs[k].copy()
            infos["final_obs"] = final
            infos["_final_obs"] = done.copy()
            infos["final_info"] = self._info(info, done)
            infos["_final_info"] = done.copy()
            for k in np.flatnonzero(done):
                self.batch.reset_world(int(k))
            self.batch.flush()
            obs = self.batch.observe()
        else:
            self._needs_reset = done
        return obs, rew.astype(np.float64), term, trunc, infos

    def _info(self, info: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in info.items():
            out[k] = v
            out[f"_{k}"] = mask.copy()
        return out

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One RGB image per world (``render_mode="rgb_array"``)."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.batch.model, *RENDER_SIZE, max_geom=20000)
        return tuple(_render_world(self.batch, w, self._renderer) for w in range(self.num_envs))

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


__all__ = ["PourVectorEnv"]
