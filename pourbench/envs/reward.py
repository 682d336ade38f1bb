"""Algorithm 5 of the thesis (PourNet's extrinsic reward), batched over worlds.

Per step, while the received weight is below ``target − tolerance`` (still pouring):
``−1 / max_steps``. On a collision between the containers: ``−1`` and the episode ends (no
bonus). When an episode ends normally: ``+1`` if its pouring error is at most ``success_g``
(10 g) and ``+1`` if the average error over the last ``n`` successfully completed episodes
(this one included) is at most ``average_success_g`` (20 g).

A denser option, off in the thesis' reward: ``final_error_per_g`` > 0 also takes
``final_error_per_g × error`` (g) off the reward when an episode ends normally or at the
step limit, so that every gram of the final error counts and not only the two thresholds
(and a policy cannot escape it by never finishing).

A progress option, off in the thesis' reward: ``progress_per_g`` > 0 adds
``progress_per_g × (error before the step − error after it)`` (g) every step. Over an episode
it sums to ``progress_per_g × (target − final error)``: every gram of the final error counts
as with ``final_error_per_g`` (up to a constant per episode), but paid while the scale moves,
not at the end. With a learner's discount γ < 1 a charge made at the end shrinks by γ^k when
the end comes k steps later, so a policy that has over-poured gains by holding its tilt to
the step limit (docs/training.md); charged as the grams arrive, the error leaves nothing to
gain by putting off the end.

A shaping option, off in the thesis' reward: ``shaping`` = k > 0 adds the potential-based
term F = γ Φ(s′) − Φ(s) of Ng, Harada & Russell (1999, "Policy invariance under reward
transformations"), with Φ = k (approach + tilted (1 − filled) / 2 + closeness): approach = 1 −
min(d / 0.3 m, 1), d the pouring container's horizontal distance from where it pours over
the receiving one; tilted = min(tilt / 90°, 1), the tilt a pour takes before liquid reaches
the scale, its weight fading as the scale fills; filled = min(measured / target, 1), the
scale's reading over the target; and closeness = 1 − min(|measured − target| / target, 2),
which rises to 1 as the scale reaches the target and falls again with every gram beyond it
(to −1 at three times the target), so an over-pour costs at the step that makes it and
tilting back to stop the stream pays there, not only at the episode's end. Φ = 0 once the
episode has ended, at the step limit too (the learners take it as a terminal state,
:mod:`pourbench.agents.sb3`); only where a diverged liquid truncated it, whose value the
learner bootstraps from its last state, does that state's potential stand.
A potential-based term leaves the optimal policies as they are (for the learner's discount
γ, ``shaping_gamma``); it gives a learner that starts from noise a gradient toward the
receiving container, which Algorithm 5 gives only once liquid reaches the scale (a random
policy never gets there in Algorithm 4's action mode).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_finite, check_int


@dataclass(frozen=True)
class RewardConfig:
    """Algorithm 5's constants.

    Attributes:
        success_g: episode error that earns the first bonus, g.
        average_success_g: running average error that earns the second bonus, g.
        window: number ``n`` of past completed episodes in the running average.
        final_error_per_g: reward taken off per gram of error at a normal end or at the
            step limit (0: the thesis' Algorithm 5).
        progress_per_g: reward per gram by which a step brings the pouring error down (and
            charge per gram by which it raises it), paid at that step (module docstring; 0:
            none).
        shaping: scale k of the potential-based shaping term (module docstring; 0: none).
        shaping_gamma: the learner's discount γ the shaping term is made for.
    """

    success_g: float = 10.0
    average_success_g: float = 20.0
    window: int = 10
    final_error_per_g: float = 0.0
    progress_per_g: float = 0.0
    shaping: float = 0.0
    shaping_gamma: float = 0.995

    def __post_init__(self) -> None:
        check_finite("reward.success_g", self.success_g, minimum=0.0)
        check_finite("reward.average_success_g", self.average_success_g, minimum=0.0)
        check_int("reward.window", self.window, minimum=1)
        check_finite("reward.final_error_per_g", self.final_error_per_g, minimum=0.0)
        check_finite("reward.progress_per_g", self.progress_per_g, minimum=0.0)
        check_finite("reward.shaping", self.shaping, minimum=0.0)
        gamma = check_finite("reward.shaping_gamma", self.shaping_gamma, minimum=0.0)
        if gamma > 1.0:
            raise InvalidParameterError(f"reward.shaping_gamma must be <= 1, got {gamma!r}")


def extrinsic_reward(
    pouring: np.ndarray,
    collided: np.ndarray,
    finished: np.ndarray,
    error_g: np.ndarray,
    average_error_g: np.ndarray,
    max_steps: int,
    config: RewardConfig = RewardConfig(),
    timed_out: np.ndarray | None = None,
    previous_error_g: np.ndarray | None = None,
) -> np.ndarray:
    """Algorithm 5's reward of one step for a batch of worlds.

    Args:
        pouring: (n,) received weight still below target − tolerance.
        collided: (n,) the containers collided this step (ends the episode, no bonus).
        finished: (n,) the episode ended normally this step (upright, stream stopped).
        error_g: (n,) this episode's pouring error |poured − target|, g.
        average_error_g: (n,) running average error over the last n completed episodes,
            including this one where ``finished``, g.
        max_steps: episode step limit.
        timed_out: (n,) the episode reached the step limit this step without another end
            (charged its final error by ``final_error_per_g``; Algorithm 5 gives it nothing).
        previous_error_g: (n,) the pouring error before this step, g (at a reset: the
            target); needed with ``progress_per_g``.
    """
    r = np.where(pouring, -1.0 / max_steps, 0.0)
    r = r - np.where(collided, 1.0, 0.0)
    bonus = finished & ~collided
    r = r + np.where(bonus & (error_g <= config.success_g), 1.0, 0.0)
    r = r + np.where(bonus & (average_error_g <= config.average_success_g), 1.0, 0.0)
    if config.final_error_per_g:
        charged = bonus if timed_out is None else bonus | timed_out
        r = r - np.where(charged, config.final_error_per_g * error_g, 0.0)
    if config.progress_per_g:
        if previous_error_g is None:
            raise InvalidParameterError("reward.progress_per_g needs the error before the step")
        r = r + config.progress_per_g * (previous_error_g - error_g)
    return r


SHAPING_DISTANCE_M = 0.3
"""The approach distance over which the shaping potential's approach part falls to 0, m (the
farthest start of Pour-v0's default range is 0.3 m from the receiving container)."""


SHAPING_TILT_RAD = 0.5 * np.pi
"""The tilt at which the shaping potential's tilt part is full, rad."""


def shaping_potential(
    distance_m: np.ndarray,
    tilt_rad: np.ndarray,
    measured_g: np.ndarray,
    target_g: np.ndarray,
    scale: float,
) -> np.ndarray:
    """Φ per world (module docstring): ``distance_m`` from the pouring position, the pouring
    container's ``tilt_rad``, the scale's reading ``measured_g`` and the ``target_g``, times
    ``scale``."""
    approach = 1.0 - np.minimum(distance_m / SHAPING_DISTANCE_M, 1.0)
    tilted = np.minimum(tilt_rad / SHAPING_TILT_RAD, 1.0)
    filled = np.clip(measured_g / target_g, 0.0, 1.0)
    closeness = 1.0 - np.minimum(np.abs(measured_g - target_g) / target_g, 2.0)
    return scale * (approach + 0.5 * tilted * (1.0 - filled) + closeness)


class ErrorHistory:
    """Per-world errors of the last ``window`` completed episodes (the thesis' Avg. Pouring
    Error, §6.5.1), kept as a (worlds, window) ring buffer."""

    def __init__(self, num_worlds: int, window: int = 10) -> None:
        self.window = int(window)
        self.errors = np.zeros((num_worlds, self.window))
        self.count = np.zeros(num_worlds, np.int64)  # episodes recorded per world

    def add(self, world: int | np.ndarray, error_g: float | np.ndarray) -> None:
        """Record completed episodes' errors (g): one world or an array of distinct worlds."""
        w = np.atleast_1d(np.asarray(world, np.int64))
        e = np.broadcast_to(np.asarray(error_g, float), w.shape)
        self.errors[w, self.count[w] % self.window] = e
        self.count[w] += 1

    def average(self) -> np.ndarray:
        """(n,) average error per world, g (0 before any completed episode)."""
        filled = np.minimum(self.count, self.window)
        return self.errors.sum(1) / np.maximum(filled, 1)
