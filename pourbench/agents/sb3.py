"""Thin Stable-Baselines3 adapter: a :class:`PourVectorEnv` as an SB3 ``VecEnv``.

The vector env runs in ``"same_step"`` autoreset mode; SB3's conventions follow from it: the
observation returned for a finished world is its next episode's first one, the last one is in
``infos[k]["terminal_observation"]``, and ``infos[k]["TimeLimit.truncated"]`` marks
truncations (step limit or diverged simulation) so value bootstrapping stays correct.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from pourbench.envs.vector import PourVectorEnv


class SB3PourVecEnv(VecEnv):
    """SB3 view of ``num_envs`` pouring worlds.

    Args:
        num_envs: number of worlds.
        seed: base seed (world ``k`` gets ``seed + k``); None for fresh entropy.
        **kwargs: fields of :class:`~pourbench.envs.core.PourConfig`.
    """

    def __init__(self, num_envs: int = 1, seed: int | None = None, **kwargs: Any) -> None:
        self.venv = PourVectorEnv(num_envs, autoreset_mode="same_step", **kwargs)
        super().__init__(
            num_envs, self.venv.single_observation_space, self.venv.single_action_space
        )
        self._seed = seed
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        obs, _ = self.venv.reset(seed=self._seed)
        self._seed = None  # later resets continue each world's generator
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        obs, rew, term, trunc, info = self.venv.step(self._actions)
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
                d["TimeLimit.truncated"] = bool(trunc[k] and not term[k])
            infos.append(d)
        return obs, rew.astype(np.float32), done, infos

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self.venv, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
    ) -> list[Any]:
        out = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [out] * len(self._indices(indices))

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices: Any) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)
