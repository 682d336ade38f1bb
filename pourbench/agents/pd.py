"""Closed-loop PD pouring baseline (in the spirit of Dong et al.'s controller, thesis
Table 6.1): the tilt rate follows the error between a desired and the measured flow rate,
where the desired flow shrinks with the remaining weight to pour.

It reads only the environment's observation (the filtered scale weight, the target and the
tilt) and acts through Algorithm 4 (``action_mode="thesis"``): translate at full speed until
above the receiving container, then

* flow estimate ``q`` (g/s): the measured weight's rate of change, low-passed;
* predicted weight ``ŵ = w + q·lead`` (compensates the 1 Hz filter's delay);
* desired flow ``q* = clip(gain·(target − ŵ), min_flow, max_flow)``;
* ``ω = kp·(q* − q) − kd·dq/dt``, only forward, while ``ŵ`` is below the target;
* hold the tilt once ``ŵ`` has reached the target (Algorithm 4 refuses to turn back before
  the measured weight reaches target − tolerance), and turn back at full speed once the
  measured weight is there. If the stream stops short of it (no rise of the smoothed weight
  for ``stall_time``), or the return was triggered by a noisy sample (the smoothed weight
  stays ``short_margin_g`` below), return at full rate to the largest tilt reached so far
  and search on from there at ``search_rate``. While it searches, neither the predicted
  weight nor a single noisy sample stops it: only a rise of the smoothed weight (the stream
  again) re-arms the hold, and only the smoothed weight at target − tolerance turns it
  back.
* the flow onset counts only once the container has started to rotate, so sensor noise
  during the approach cannot end the approach early.

Works on batches: ``act(obs)`` takes (n, 12) or (12,) observations.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from pourbench.errors import InvalidParameterError, check_array, check_finite, check_int

WEIGHT, TARGET, TILT = 7, 8, 11


@dataclass(frozen=True)
class PDConfig:
    """Gains and limits (grams, seconds, radians, actions in [-1, 1]).

    Attributes:
        control_dt: environment step, s.
        fast_tilt: tilt reached at full rate before searching for the flow onset, rad.
        search_rate: tilt-rate action while searching for the onset and while pouring.
        detect_g: measured weight that marks the onset, g (about 2σ of the filtered noise).
        kp: tilt-rate action per g/s of flow error.
        kd: tilt-rate action per g/s² of flow change.
        gain: desired flow per gram still to pour, 1/s.
        min_flow, max_flow: bounds of the desired flow, g/s.
        lead: prediction horizon of the weight, s (filter delay plus stopping time).
        tolerance_g: the environment's Algorithm 4 tolerance ΔL_w, g.
        weight_smoothing: weight of the newest sample in the smoothed weight.
        stall_gain_g: rise of the smoothed weight's maximum that shows the stream still runs, g.
        stall_time: time without such a rise, short of the target, before pouring again, s.
        short_margin_g: how far below target − tolerance the smoothed weight must stay (for
            ``stall_time``) to undo a return triggered by a noisy sample, g.
        flow_smoothing: weight of the newest flow sample in its running average.
    """

    control_dt: float = 0.1
    fast_tilt: float = 0.6
    search_rate: float = 0.15
    detect_g: float = 5.0
    kp: float = 0.01
    kd: float = 0.001
    gain: float = 0.5
    min_flow: float = 5.0
    max_flow: float = 30.0
    lead: float = 0.4
    flow_smoothing: float = 0.5
    tolerance_g: float = 2.0
    weight_smoothing: float = 0.3
    stall_gain_g: float = 1.0
    stall_time: float = 1.0
    short_margin_g: float = 2.0

    def __post_init__(self) -> None:
        """Every field finite and non-negative (``max_flow`` and ``stall_time`` may be inf: no
        cap, no stall rule); ``control_dt`` and ``stall_time`` > 0, the smoothing weights in
        (0, 1], ``search_rate`` in [0, 1], ``min_flow <= max_flow``."""
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("max_flow", "stall_time") and v == float("inf"):
                continue
            check_finite(f.name, v, minimum=0.0)
        for name in ("control_dt", "stall_time"):
            if getattr(self, name) <= 0:
                raise InvalidParameterError(f"{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("flow_smoothing", "weight_smoothing"):
            if not 0 < getattr(self, name) <= 1:
                raise InvalidParameterError(
                    f"{name} must be in (0, 1], got {getattr(self, name)!r}"
                )
        if self.search_rate > 1:
            raise InvalidParameterError(f"search_rate must be in [0, 1], got {self.search_rate!r}")
        if self.min_flow > self.max_flow:
            raise InvalidParameterError(
                f"min_flow must be <= max_flow, got min_flow={self.min_flow!r} "
                f"and max_flow={self.max_flow!r}"
            )


class PDPourer:
    """The PD baseline for a batch of ``num_envs`` worlds (an integer >= 1)."""

    def __init__(self, num_envs: int = 1, config: PDConfig | None = None) -> None:
        self.config = config or PDConfig()
        self.n = check_int("num_envs", num_envs, minimum=1)
        self.last_w = np.full(self.n, np.nan)
        self.flow = np.zeros(self.n)
        self.onset = np.zeros(self.n, bool)
        self.hold = np.zeros(self.n, bool)
        self.smooth_w = np.zeros(self.n)
        self.best_w = np.zeros(self.n)
        self.stalled = np.zeros(self.n)
        self.max_tilt = np.zeros(self.n)
        self.catchup = np.zeros(self.n, bool)
        self.back = np.zeros(self.n, bool)
        self.short = np.zeros(self.n)
        self.searching = np.zeros(self.n, bool)

    def reset(self, mask: np.ndarray | None = None) -> None:
        """Forget the history of every world (or of those in ``mask``, ``n`` booleans)."""
        m = np.ones(self.n, bool) if mask is None else np.asarray(mask)
        if m.shape != (self.n,) or m.dtype != bool:
            raise InvalidParameterError(f"mask must be {self.n} booleans, got {mask!r}")
        self.last_w[m] = np.nan
        self.flow[m] = 0.0
        self.onset[m] = False
        self.hold[m] = False
        self.smooth_w[m] = 0.0
        self.best_w[m] = 0.0
        self.stalled[m] = 0.0
        self.max_tilt[m] = 0.0
        self.catchup[m] = False
        self.back[m] = False
        self.short[m] = 0.0
        self.searching[m] = False

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions (n, 2) ``(ω, r)`` for finite observations (n, 12) (or (2,) for (12,) when
        ``n`` is 1); bad observations are refused before any state changes."""
        single = self.n == 1 and np.ndim(obs) == 1
        o = check_array("obs", obs, (12,) if single else (self.n, 12)).reshape(-1, 12)
        c = self.config
        w, target, tilt = o[:, WEIGHT], o[:, TARGET], o[:, TILT]
        q_new = np.where(np.isnan(self.last_w), 0.0, (w - self.last_w) / c.control_dt)
        q_old = self.flow
        q = (1 - c.flow_smoothing) * q_old + c.flow_smoothing * q_new
        dq = (q - q_old) / c.control_dt
        self.last_w, self.flow = w.copy(), q
        self.smooth_w += c.weight_smoothing * (w - self.smooth_w)
        predicted = w + np.maximum(q, 0.0) * c.lead
        # the handler rotates only above the receiving container: before that, a weight is noise
        self.onset |= (w >= c.detect_g) & (tilt > 0.0)
        rising = self.smooth_w > self.best_w + c.stall_gain_g
        self.best_w = np.where(rising, self.smooth_w, self.best_w)
        self.searching &= ~rising
        there = target - c.tolerance_g
        self.hold |= self.onset & ~self.searching & (predicted >= target)
        # turn back once the measured weight reaches target − tolerance (when Algorithm 4
        # allows it; while searching, once the smoothed weight does); undo that if the
        # smoothed weight then stays clearly short of it
        self.back |= self.onset & (w >= there) & (~self.searching | (self.smooth_w >= there))
        short = self.back & (self.smooth_w < there - c.short_margin_g)
        self.short = np.where(short, self.short + 1, 0)
        undo = self.short * c.control_dt >= c.stall_time
        self.back &= ~undo
        self.short = np.where(undo, 0, self.short)
        self.stalled = np.where(self.hold & ~self.back & ~rising, self.stalled + 1, 0)
        resume = (self.stalled * c.control_dt >= c.stall_time) | undo
        self.hold &= ~resume
        self.stalled = np.where(resume, 0, self.stalled)
        self.searching |= resume
        self.max_tilt = np.maximum(self.max_tilt, tilt)
        self.catchup = (self.catchup | resume) & (tilt < self.max_tilt - 0.05) & ~self.hold
        q_star = np.clip(c.gain * (target - predicted), c.min_flow, c.max_flow)
        pour = np.clip(c.kp * (q_star - q) - c.kd * dq, 0.0, c.search_rate)
        omega = np.where(tilt < c.fast_tilt, 1.0, np.where(self.onset, pour, c.search_rate))
        omega = np.where(self.searching, c.search_rate, omega)
        omega = np.where(self.catchup, 1.0, omega)
        omega = np.where(self.hold, 0.0, omega)
        omega = np.where(self.back, -1.0, omega)
        # translate toward the receiving container until the handler starts rotating
        r = np.where((tilt <= 1e-6) & ~self.onset, 1.0, 0.0)
        a = np.stack([omega, r], axis=1).astype(np.float32)
        return a[0] if single else a
