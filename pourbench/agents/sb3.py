"""Thin Stable-Baselines3 adapter: a :class:`PourVectorEnv` as an SB3 ``VecEnv``.

The vector env runs in ``"same_step"`` autoreset mode; SB3's conventions follow from it: the
observation returned for a finished world is its next episode's first one, the last one is in
``infos[k]["terminal_observation"]``, and ``infos[k]["TimeLimit.truncated"]`` marks the
episodes whose value SB3 should bootstrap: a diverged simulation only. The step limit is part
of the task the learner is given (the observation carries no clock, and the reward settles the
episode there), so the adapter reports it as a terminal state: bootstrapping ``γ V(s′)`` at
the limit would pay a policy that never finishes the value of a state that could still
succeed, and a warm-started LSTM learned exactly that (episodes stretched to the limit).
The vector env itself still reports ``truncated`` at the limit, as Gymnasium defines it.

``indices``: ``env_method("reset", indices=…)`` resets only those worlds (through the vector
env's ``reset_mask``) and returns each one's ``(obs, info)``; ``get_attr`` and
``env_is_wrapped`` answer for the given worlds (attributes are shared by all worlds). Other
methods and ``set_attr`` act on the one vector env, so they accept only all worlds
(``indices`` None or every index). Indices out of range are refused, and so are
``reset``, ``step`` and ``env_method`` after :meth:`close`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from pourbench.envs.vector import PourVectorEnv
from pourbench.errors import InvalidParameterError, check_index


class SB3PourVecEnv(VecEnv):
    """SB3 view of ``num_envs`` pouring worlds.

    Args:
        num_envs: number of worlds.
        seed: base seed (world ``k`` gets ``seed + k``); None for fresh entropy.
        workers: processes the worlds are spread over (None: one per core, at most one per
            world; see :class:`~pourbench.envs.vector.PourVectorEnv`).
        **kwargs: fields of :class:`~pourbench.envs.core.PourConfig`.
    """

    def __init__(
        self, num_envs: int = 1, seed: int | None = None, workers: int | None = None, **kwargs: Any
    ) -> None:
        self.venv = PourVectorEnv(num_envs, autoreset_mode="same_step", workers=workers, **kwargs)
        super().__init__(
            num_envs, self.venv.single_observation_space, self.venv.single_action_space
        )
        self._seed = seed
        self._actions: np.ndarray | None = None
        self._closed = False

    def _check_open(self, what: str) -> None:
        if self._closed:
            raise InvalidParameterError(f"{what}: this SB3PourVecEnv is closed")

    def reset(self) -> np.ndarray:
        self._check_open("reset()")
        obs, _ = self.venv.reset(seed=self._seed)
        self._seed = None  # later resets continue each world's generator
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._check_open("step()")
        self._actions = np.asarray(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        self._check_open("step()")
        if self._actions is None:
            raise InvalidParameterError("step_wait() called without step_async(actions)")
        actions, self._actions = self._actions, None
        obs, rew, term, trunc, info = self.venv.step(actions)
        done = term | trunc
        infos: list[dict[str, Any]] = []
        for k in range(self.num_envs):
            src = info["final_info"] if done[k] else info
            d = {
                key: v[k]
                for key, v in src.items()
                if not key.startswith("_") and key not in ("final_obs", "final_info")
            }
            if done[k]:
                d["terminal_observation"] = info["final_obs"][k]
                d["TimeLimit.truncated"] = bool(d["sim_diverged"])
            infos.append(d)
        return obs, rew.astype(np.float32), done, infos

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.venv.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self.venv, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        self._all_worlds(f"set_attr({attr_name!r})", indices)
        setattr(self.venv, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
    ) -> list[Any]:
        self._check_open("env_method()")
        idx = self._indices(indices)
        if method_name == "reset":
            return self._reset_worlds(idx, *method_args, **method_kwargs)
        self._all_worlds(f"env_method({method_name!r})", indices)
        out = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [out] * len(idx)

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _reset_worlds(
        self, idx: Sequence[int], *, seed: Any = None, options: dict[str, Any] | None = None
    ) -> list[tuple[np.ndarray, dict[str, Any]]]:
        """Reset the worlds ``idx`` only; each one's ``(obs, info)``."""
        mask = np.zeros(self.num_envs, bool)
        mask[list(idx)] = True
        obs, info = self.venv.reset(seed=seed, options={**(options or {}), "reset_mask": mask})
        return [
            (obs[k], {key: v[k] for key, v in info.items() if not key.startswith("_")}) for k in idx
        ]

    def _indices(self, indices: Any) -> Sequence[int]:
        """``indices`` (None: all worlds, an int, or ints) checked against ``num_envs``."""
        if indices is None:
            return range(self.num_envs)
        if isinstance(indices, int | np.integer):
            indices = [indices]
        try:
            items = list(indices)
        except TypeError:
            raise InvalidParameterError(
                f"indices must be None, a world index or a list of them, got {indices!r}"
            ) from None
        return [check_index("indices", i, self.num_envs) for i in items]

    def _all_worlds(self, what: str, indices: Any) -> None:
        """Refuse ``indices`` that are not every world: ``what`` acts on all of them."""
        if indices is not None and set(self._indices(indices)) != set(range(self.num_envs)):
            raise InvalidParameterError(
                f"{what} acts on all {self.num_envs} worlds together; indices {indices!r} "
                "are not supported (only None or every world; env_method('reset') takes any)"
            )
