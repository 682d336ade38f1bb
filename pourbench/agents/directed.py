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

The map is a bijection from the policy's tilt outputs onto the tilt rates Algorithm 4
applies, so the policy can still do everything the handler does, and every tilt output now
moves the container.

With ``--directed-approach`` the approach output ``v`` in [-1, 1] becomes the speed toward
the receiving container, ``r = (v + 1) / 2``; without it ``r = v``. This one drops actions:
Algorithm 4 also moves the container away for ``r < 0``, which only ever delays the pour (the
container pours only once above the receiving one, and the approach never steps past its
axis). A policy from scratch otherwise finds "back away and never pour" a safe optimum of any
error-based reward, and SAC collapsed onto it (docs/training.md).

The environment is unchanged: the maps run on the learner's side (:class:`DirectedTiltVecEnv`
in training, :func:`directed_policy` when acting), and the trained model records them as its
attributes :data:`ATTRIBUTE` (the tolerance the tilt map switches at) and
:data:`APPROACH_ATTRIBUTE` (saved in its ``.zip``), so
:func:`pourbench.agents.loading.load_policy` acts with the same map. Written by hand: no
library has it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnvWrapper

ATTRIBUTE = "directed_tilt_g"
"""The model attribute holding the tolerance (g) the directed tilt map switches at (absent or
None: the tilt passes unchanged)."""

APPROACH_ATTRIBUTE = "directed_approach"
"""The model attribute that is True when the approach output is mapped onto [0, 1] (absent or
False: it passes unchanged)."""

REMAINING = 9
"""Index of the remaining weight (target − filtered reading, g) in a Pour-v0 observation."""


def direct(
    actions: np.ndarray, obs: np.ndarray, tolerance_g: float | None, approach: bool = False
) -> np.ndarray:
    """The environment's (ω, r) for the policy's (u, v) in the observed states (module
    docstring), as float32; ``actions`` (n, 2) or (2,), ``obs`` the matching (n, 12) or
    (12,) observations. ``tolerance_g`` None leaves the tilt as it is, ``approach`` False
    the approach."""
    a = np.clip(np.asarray(actions, float), -1.0, 1.0)
    out = a.copy()
    if tolerance_g is not None:
        forward = np.asarray(obs, float)[..., REMAINING] > tolerance_g
        size = (a[..., 0] + 1.0) / 2.0
        out[..., 0] = np.where(forward, size, -size)
    if approach:
        out[..., 1] = (a[..., 1] + 1.0) / 2.0
    return out.astype(np.float32)


def model_map(model: Any) -> tuple[float | None, bool]:
    """The (tolerance, approach) of the map ``model`` was trained through; (None, False) for
    a plain policy."""
    return getattr(model, ATTRIBUTE, None), bool(getattr(model, APPROACH_ATTRIBUTE, False))


def mark(model: Any, tolerance_g: float | None, approach: bool) -> None:
    """Record the map on ``model`` so that its saved ``.zip`` acts through it."""
    if tolerance_g is not None:
        setattr(model, ATTRIBUTE, float(tolerance_g))
    if approach:
        setattr(model, APPROACH_ATTRIBUTE, True)


class DirectedTiltVecEnv(VecEnvWrapper):
    """``venv`` acted on through :func:`direct`, each world's map read from its latest
    observation; observations, rewards and infos are ``venv``'s."""

    def __init__(self, venv: Any, tolerance_g: float | None, approach: bool = False) -> None:
        super().__init__(venv)
        self.tolerance_g = None if tolerance_g is None else float(tolerance_g)
        self.approach = approach
        self._obs: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        self._obs = self.venv.reset()
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        self.venv.step_async(direct(actions, self._obs, self.tolerance_g, self.approach))

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        self._obs = obs  # a finished world's obs is already its next episode's first
        return obs, rewards, dones, infos


def directed_policy(act: Any, tolerance_g: float | None, approach: bool = False) -> Any:
    """The policy ``f(obs, new_episode)`` that maps ``act(obs, new_episode)`` through
    :func:`direct`."""

    def policy(obs: np.ndarray, new: bool) -> np.ndarray:
        return direct(act(obs, new), obs, tolerance_g, approach)

    return policy
