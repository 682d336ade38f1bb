"""Vector ``pourbench/Pour-v0``: N worlds in batched fluid solvers, Gymnasium 1.x autoreset.

``gymnasium.make_vec("pourbench/Pour-v0", num_envs=N, vectorization_mode="vector_entry_point",
workers=W)`` returns a :class:`PourVectorEnv`. Its worlds are split into ``W`` contiguous
groups (default: one per core, at most one per world); the first group is stepped in this
process and each other one in a worker process (:mod:`pourbench.envs.workers`), each group
by one :class:`~pourbench.envs.core.PourBatch` with one kernel launch per solver stage. World
``k`` reset with seed ``s + k`` follows the same episodes as a single
:class:`~pourbench.envs.pour_v0.PourEnv` reset with that seed, for any number of workers.

Autoreset: ``"next_step"`` (Gymnasium's default): a world whose episode ended is reset on the
next ``step`` call, which then returns its first observation with reward 0 and ignores its
action. ``"same_step"``: a finished world is reset within the same ``step``; its last
observation and info are in ``info["final_obs"]`` / ``info["final_info"]``.

A worker that dies raises :class:`~pourbench.envs.workers.WorkerError` in this process (and
closes the env); :meth:`PourVectorEnv.close` ends every worker.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from pourbench.envs.action_handler import as_actions
from pourbench.envs.core import PourBatch, check_memory
from pourbench.envs.options import ResetOptions
from pourbench.envs.pour_v0 import action_space, make_config, observation_space
from pourbench.envs.workers import (
    LocalGroup,
    RemoteGroup,
    WorkerError,
    default_workers,
    split,
)
from pourbench.errors import InvalidParameterError, check_index, check_int

_MODES = {"next_step": AutoresetMode.NEXT_STEP, "same_step": AutoresetMode.SAME_STEP}


class PourVectorEnv(VectorEnv):
    """``num_envs`` pouring worlds stepped together (see the module docstring).

    Args:
        num_envs: number of worlds.
        autoreset_mode: "next_step" (default) or "same_step".
        render_mode: None or "rgb_array" (``render()`` returns one image per world).
        workers: processes the worlds are spread over (None: one per core, at most one
            per world; 1: all in this process).
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
        workers: int | None = None,
        **kwargs: Any,
    ) -> None:
        mode = _MODES.get(autoreset_mode, autoreset_mode)
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise InvalidParameterError(
                f"autoreset_mode must be one of {list(_MODES)}, got {autoreset_mode!r}"
            )
        if render_mode not in (None, "rgb_array"):
            raise InvalidParameterError(
                f"render_mode must be None or 'rgb_array', got {render_mode!r}"
            )
        self.num_envs = check_int("num_envs", num_envs, minimum=1)
        if workers is None:
            workers = default_workers(self.num_envs)
        self.workers = check_int("workers", workers, minimum=1)
        if self.workers > self.num_envs:
            raise InvalidParameterError(
                f"workers={self.workers} is more than num_envs={self.num_envs} (at most one "
                "worker per world)"
            )
        self.config = make_config(**kwargs)
        check_memory(self.num_envs, self.config)  # before any worker starts
        self._groups: list[LocalGroup | RemoteGroup] = []
        self._closer = weakref.finalize(self, _close_groups, self._groups)
        self._slices = [slice(f, f + c) for f, c in split(self.num_envs, self.workers)]
        try:
            for i, sl in enumerate(self._slices[1:], start=1):
                count = sl.stop - sl.start
                self._groups.append(RemoteGroup(i, sl.start, count, self.config))
            local = LocalGroup(self._slices[0].stop, self.config)
            self._groups.insert(0, local)
            for g in self._groups[1:]:
                g.receive(timeout=_START_TIMEOUT_S)
        except BaseException:
            _close_groups(self._groups)
            raise
        self.batch: PourBatch | None = local.group.batch if self.workers == 1 else None
        """The in-process batch of every world (``workers=1`` only; None with workers)."""
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.render_mode = render_mode
        self.single_observation_space = observation_space()
        self.single_action_space = action_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._needs_reset = np.zeros(self.num_envs, bool)
        self._was_reset = np.zeros(self.num_envs, bool)
        self._closed = False

    def _all(self, method: str, *per_group: list[Any], shared: tuple = ()) -> list[Any]:
        """Call ``method`` in every group (the workers first), with the i-th element of each
        of ``per_group`` and then ``shared`` as arguments; their answers in group order."""
        if self._closed:
            raise InvalidParameterError(f"{method}(): this PourVectorEnv is closed")
        order = [*range(1, len(self._groups)), 0]
        try:
            for i in order:
                self._groups[i].send(method, *(p[i] for p in per_group), *shared)
            out: list[Any] = [None] * len(self._groups)
            error: BaseException | None = None
            for i in order:
                try:
                    out[i] = self._groups[i].receive()
                except WorkerError:
                    raise
                except Exception as exc:  # every group answers before the error is raised
                    error = error or exc
            if error is not None:
                raise error
            return out
        except WorkerError:
            self.close()
            raise

    def _split(self, a: np.ndarray) -> list[np.ndarray]:
        return [a[sl] for sl in self._slices]

    def set_lesson(self, k: int) -> None:
        """Draw liquids from curriculum lesson ``k`` at later resets, in every world."""
        self._all("set_lesson", shared=(k,))  # refused alike by every group

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every world (or those in ``options["reset_mask"]``).

        ``seed``: an int ``s`` seeds world ``k`` with ``s + k``; a list gives one per world.
        Other ``options`` (liquid, target_g, container, initial_g, start) apply to every
        world reset.
        """
        # seeds, mask and options are checked here, and every world's draws (its liquid's
        # capacity in a container) in its group, before any world is reset
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
        mask = np.ones(self.num_envs, bool)
        if isinstance(options, Mapping) and "reset_mask" in options:
            options = dict(options)
            mask = np.asarray(options.pop("reset_mask"))
        opts = ResetOptions.parse(options)
        if mask.shape != (self.num_envs,) or mask.dtype != bool:
            raise InvalidParameterError(
                f"reset_mask must be {self.num_envs} booleans, got {mask.tolist()!r}"
            )
        never = np.flatnonzero(~mask & ~self._was_reset)
        if len(never):
            raise InvalidParameterError(
                f"reset_mask leaves world {never[0]} unreset, and it was never reset"
            )
        self._all(
            "draw_resets", [seeds[sl] for sl in self._slices], self._split(mask), shared=(opts,)
        )
        super().reset(seed=first)
        answers = self._all("apply_resets")
        obs = np.concatenate([o for o, _ in answers])
        info = _concat([i for _, i in answers])
        self._was_reset |= mask
        self._needs_reset[mask] = False
        return obs, self._info(info, mask)

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        a = as_actions(actions, self.num_envs)  # checked before any world moves
        resetting = self._needs_reset.copy()
        # every world's physics advances together; a world due for its next-step autoreset
        # holds still through this step and is reset after it, so it returns its first
        # observation of the new episode
        same = self.autoreset_mode == AutoresetMode.SAME_STEP
        answers = self._all("step", self._split(a), self._split(resetting), shared=(same,))
        obs, rew, term, trunc = (np.concatenate([r[j] for r in answers]) for j in range(4))
        info = _concat([r[4] for r in answers])
        infos = self._info(info, np.ones(self.num_envs, bool))
        done = term | trunc
        if same and done.any():
            final_obs = np.empty(self.num_envs, dtype=object)
            for r, sl in zip(answers, self._slices, strict=True):
                for k in np.flatnonzero(done[sl]):
                    final_obs[sl.start + k] = r[5][0][k]
            ended = _concat([r[4] if r[5] is None else r[5][1] for r in answers])
            infos["final_obs"] = final_obs
            infos["_final_obs"] = done.copy()
            infos["final_info"] = self._info(ended, done)
            infos["_final_info"] = done.copy()
        elif not same:
            self._needs_reset = done
        return obs, rew.astype(np.float64), term, trunc, infos

    def solver_seconds(self, synchronize: bool | None = None) -> list[float]:
        """Seconds each group of worlds (this process's first, then each worker's) has spent
        in its solver's steps (``synchronize``: see
        :meth:`~pourbench.envs.core.PourBatch.time_solver`)."""
        return self._all("solver_seconds", shared=(synchronize,))

    def call_world(self, world: int, fn: Callable[..., Any], *args: Any) -> Any:
        """Run ``fn(batch, index, *args)`` in the process holding ``world``, where ``batch``
        is that process's :class:`PourBatch` and ``index`` the world's index in it; returns
        what ``fn`` returns (``fn``, its arguments and result must pickle). For inspection
        and tests; changing a world's state through it is the caller's responsibility."""
        w = check_index("world", world, self.num_envs)
        if self._closed:
            raise InvalidParameterError("call_world(): this PourVectorEnv is closed")
        i = next(i for i, sl in enumerate(self._slices) if sl.start <= w < sl.stop)
        group = self._groups[i]
        try:
            group.send("call", w - self._slices[i].start, fn, args)
            return group.receive()
        except WorkerError:
            self.close()
            raise

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
        return tuple(img for part in self._all("render") for img in part)

    def close_extras(self, **kwargs: Any) -> None:
        """End every worker (and the renderers)."""
        self._closed = True
        self._closer()


_START_TIMEOUT_S = 600.0  # a worker that has not built its worlds by then is stopped


def _close_groups(groups: list[LocalGroup | RemoteGroup]) -> None:
    for g in groups:
        g.close()


def _concat(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The groups' info dicts joined world-wise."""
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


__all__ = ["PourVectorEnv", "WorkerError"]
