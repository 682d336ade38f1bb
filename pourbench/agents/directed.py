"""Action maps on the learner's side: the directed tilt (the policy's tilt output mapped
onto the half of the tilt rate that Algorithm 4 acts on), the tilt target and the directed
approach.

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

With ``--tilt-target`` the tilt output is instead the tilt the container turns toward,
``θ* = (u + 1) / 2 · max_tilt``, at the rate that reaches it within the step where the
handler's full rate allows:

    ω = clip((θ* − θ) / (max_rate · dt), −1, 1)        θ the observed tilt

Algorithm 4 then keeps the part of ω it allows, as for any policy. Under Algorithm 4 a pour
is mostly a held tilt (the stream flows while the tilt stays), and the rate maps put that
hold at an edge of the output range (u = −1 for the directed tilt), which a squashed policy
(SAC, TD3) reaches only as its output before the squash grows without bound, where the
tanh's gradient vanishes. Here holding is ``θ* = θ``, inside the range at every tilt but
upright, and a held pour is a constant output. Nothing the handler does is lost: every rate
it applies is one output's. Not with the directed tilt (both map the tilt output). What it
changes in training is measured in docs/training.md ("The tilt as a target").

The environment is unchanged: the maps run on the learner's side (:class:`DirectedTiltVecEnv`
in training, :func:`directed_policy` when acting), and the trained model records them as its
attributes :data:`ATTRIBUTE` (the tolerance the tilt map switches at) and
:data:`APPROACH_ATTRIBUTE` and :data:`TARGET_ATTRIBUTE` (saved in its ``.zip``), so
:func:`pourbench.agents.loading.load_policy` acts with the same map. Written by hand: no
library has it.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from stable_baselines3.common.vec_env import VecEnvWrapper

from pourbench.errors import InvalidParameterError

ATTRIBUTE = "directed_tilt_g"
"""The model attribute holding the tolerance (g) the directed tilt map switches at (absent or
None: the tilt passes unchanged)."""

APPROACH_ATTRIBUTE = "directed_approach"
"""The model attribute that is True when the approach output is mapped onto [0, 1] (absent or
False: it passes unchanged)."""

TARGET_ATTRIBUTE = "tilt_target"
"""The model attribute holding the tilt-target map's (largest tilt, tilt at full rate over one
step), both rad (absent or None: no tilt-target map)."""

HANDLER_ATTRIBUTE = "handler_tolerance_g"
"""The model attribute holding the tolerance (g) of the Algorithm 4 it was trained under, with
or without a map: :func:`pourbench.agents.loading.model_policy` needs it to average the rate the
handler applies (absent: a model saved before it was recorded)."""

REMAINING = 9
"""Index of the remaining weight (target − filtered reading, g) in a Pour-v0 observation."""
TILT = 11
"""Index of the pouring container's tilt (rad) in a Pour-v0 observation."""


class TiltTarget(NamedTuple):
    """The tilt-target map's scales (module docstring), both rad."""

    max_tilt: float  # the tilt at u = 1 (the handler's ActionLimits.max_tilt)
    step: float  # the tilt the handler's full rate turns in one environment step

    @classmethod
    def of(cls, config: Any) -> TiltTarget:
        """The map for a :class:`~pourbench.envs.core.PourConfig`'s action limits and control
        rate."""
        limits = config.limits
        return cls(float(limits.max_tilt), float(limits.max_rate) / float(config.control_hz))


def direct(
    actions: np.ndarray,
    obs: np.ndarray,
    tolerance_g: float | None,
    approach: bool = False,
    tilt_target: TiltTarget | None = None,
) -> np.ndarray:
    """The environment's (ω, r) for the policy's (u, v) in the observed states (module
    docstring), as float32; ``actions`` (n, 2) or (2,), ``obs`` the matching (n, 12) or
    (12,) observations. ``tolerance_g`` (the directed tilt) and ``tilt_target`` map the tilt,
    at most one of them (None: as it is); ``approach`` False leaves the approach."""
    a = np.clip(np.asarray(actions, float), -1.0, 1.0)
    out = a.copy()
    if tolerance_g is not None:
        forward = np.asarray(obs, float)[..., REMAINING] > tolerance_g
        size = (a[..., 0] + 1.0) / 2.0
        out[..., 0] = np.where(forward, size, -size)
    if tilt_target is not None:
        goal = (a[..., 0] + 1.0) / 2.0 * tilt_target.max_tilt
        tilt = np.asarray(obs, float)[..., TILT]
        out[..., 0] = np.clip((goal - tilt) / tilt_target.step, -1.0, 1.0)
    if approach:
        out[..., 1] = (a[..., 1] + 1.0) / 2.0
    return out.astype(np.float32)


class ActionMap(NamedTuple):
    """The maps a model was trained through: :func:`direct`'s arguments after the action."""

    tolerance_g: float | None = None
    approach: bool = False
    tilt_target: TiltTarget | None = None

    @property
    def identity(self) -> bool:
        """Whether the map passes every action unchanged."""
        return self == ActionMap()


def model_map(model: Any) -> ActionMap:
    """The map ``model`` was trained through; the identity for a plain policy."""
    target = getattr(model, TARGET_ATTRIBUTE, None)
    return ActionMap(
        getattr(model, ATTRIBUTE, None),
        bool(getattr(model, APPROACH_ATTRIBUTE, False)),
        None if target is None else TiltTarget(*target),
    )


def mark(
    model: Any,
    tolerance_g: float | None,
    approach: bool,
    tilt_target: TiltTarget | None = None,
    handler_tolerance_g: float | None = None,
) -> None:
    """Record the map on ``model`` so that its saved ``.zip`` acts through it, and the
    tolerance of the Algorithm 4 it is trained under (:data:`HANDLER_ATTRIBUTE`) when
    given."""
    if handler_tolerance_g is not None:
        setattr(model, HANDLER_ATTRIBUTE, float(handler_tolerance_g))
    if tolerance_g is not None:
        setattr(model, ATTRIBUTE, float(tolerance_g))
    if approach:
        setattr(model, APPROACH_ATTRIBUTE, True)
    if tilt_target is not None:
        setattr(model, TARGET_ATTRIBUTE, tuple(tilt_target))


class DirectedTiltVecEnv(VecEnvWrapper):
    """``venv`` acted on through :func:`direct`, each world's map read from its latest
    observation; observations, rewards and infos are ``venv``'s."""

    def __init__(
        self,
        venv: Any,
        tolerance_g: float | None,
        approach: bool = False,
        tilt_target: TiltTarget | None = None,
    ) -> None:
        if tolerance_g is not None and tilt_target is not None:
            raise InvalidParameterError("the directed tilt and the tilt target both map the tilt")
        super().__init__(venv)
        self.tolerance_g = None if tolerance_g is None else float(tolerance_g)
        self.approach = approach
        self.tilt_target = tilt_target
        self._obs: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        self._obs = self.venv.reset()
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        mapped = direct(actions, self._obs, self.tolerance_g, self.approach, self.tilt_target)
        self.venv.step_async(mapped)

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        self._obs = obs  # a finished world's obs is already its next episode's first
        return obs, rewards, dones, infos


def directed_policy(act: Any, action_map: ActionMap) -> Any:
    """The policy ``f(obs, new_episode)`` that maps ``act(obs, new_episode)`` through
    :func:`direct` with ``action_map``."""

    def policy(obs: np.ndarray, new: bool) -> np.ndarray:
        return direct(act(obs, new), obs, *action_map)

    return policy
