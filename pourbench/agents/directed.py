"""Directed tilt: the policy's tilt output mapped onto the half of the tilt rate that
Algorithm 4 acts on.

Algorithm 4 (:mod:`pourbench.envs.action_handler`) keeps only the forward part of the tilt
rate ω while the scale reads less than ``target − tolerance`` and only the backward part
after. Half of ω's range therefore does nothing in every state, and a Gaussian policy whose
mean sits in that half gets no gradient from it: the critic is flat there. That is where
learners from scratch stall: a policy whose mean ω drifts below zero before the target never
tilts again (the "never pour" optimum of docs/training.md), and one whose mean ω is above
zero after the target learns to tilt back only from its rare negative samples.

With ``pourbench train --directed-tilt`` the policy's tilt output ``u`` in [-1, 1] is the
tilt rate's size in the direction Algorithm 4 allows:

    ω = (u + 1) / 2        while the observed remaining weight exceeds the tolerance
    ω = −(u + 1) / 2       after

The approach rate passes unchanged. The map is a bijection from the policy's tilt outputs
onto the tilt rates Algorithm 4 applies, so the policy can still do everything the handler
does, and every tilt output now moves the container. The environment is unchanged: the map
runs on the learner's side (:class:`DirectedTiltVecEnv` in training, :func:`directed_policy`
when acting), and the trained model records the tolerance it was trained with as its
attribute :data:`ATTRIBUTE` (saved in its ``.zip``), so
:func:`pourbench.agents.loading.load_policy` acts with the same map. Written by hand: no
library has it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnvWrapper

ATTRIBUTE = "directed_tilt_g"
"""The model attribute holding the tolerance (g) the directed map switches at (absent or
None: a plain policy)."""

REMAINING = 9
"""Index of the remaining weight (target − filtered reading, g) in a Pour-v0 observation."""


def direct(actions: np.ndarray, obs: np.ndarray, tolerance_g: float) -> np.ndarray:
    """The environment's (ω, r) for the policy's (u, r) in the observed states (module
    docstring), as float32; ``actions`` (n, 2) or (2,), ``obs`` the matching (n, 12) or
    (12,) observations."""
    a = np.clip(np.asarray(actions, float), -1.0, 1.0)
    o = np.asarray(obs, float)
    forward = o[..., REMAINING] > tolerance_g
    size = (a[..., 0] + 1.0) / 2.0
    out = a.copy()
    out[..., 0] = np.where(forward, size, -size)
    return out.astype(np.float32)


class DirectedTiltVecEnv(VecEnvWrapper):
    """``venv`` acted on through :func:`direct`, each world's map read from its latest
    observation; observations, rewards and infos are ``venv``'s."""

    def __init__(self, venv: Any, tolerance_g: float) -> None:
        super().__init__(venv)
        self.tolerance_g = float(tolerance_g)
        self._obs: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        self._obs = self.venv.reset()
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        self.venv.step_async(direct(actions, self._obs, self.tolerance_g))

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        self._obs = obs  # a finished world's obs is already its next episode's first
        return obs, rewards, dones, infos


def directed_policy(act: Any, tolerance_g: float) -> Any:
    """The policy ``f(obs, new_episode)`` that maps ``act(obs, new_episode)`` through
    :func:`direct`."""

    def policy(obs: np.ndarray, new: bool) -> np.ndarray:
        return direct(act(obs, new), obs, tolerance_g)

    return policy
