"""Teleoperation link model: periodic packets, outages, and the deadline detector (§5.2).

The operator's command is sent every ``dt`` = 33 ms. An outage drops every packet sent in
``[start, start + duration)``. The robot side declares the link down when no packet arrived
for longer than the deadline ``lambda_deadline`` = 50 ms, i.e. from the second missed packet
on. Random outages come from a seeded ``numpy.random.Generator``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_finite, check_positive

__all__ = ["DeadlineDetector", "NetworkModel", "Outage", "random_outages", "task_outage"]


@dataclass(frozen=True)
class Outage:
    """Packets sent in ``[start, start + duration)`` seconds are lost."""

    start: float
    duration: float

    def __post_init__(self) -> None:
        check_finite("outage start", self.start, minimum=0.0)
        check_finite("outage duration", self.duration, minimum=0.0)


class NetworkModel:
    """Which packets arrive.

    Args:
        outages: disjoint or overlapping outage windows.
        dt: packet period, seconds.
    """

    def __init__(self, outages: Sequence[Outage] = (), dt: float = 0.033) -> None:
        self.dt = check_positive("dt", dt)
        self.outages = tuple(outages)
        for i, o in enumerate(self.outages):
            if not isinstance(o, Outage):
                raise InvalidParameterError(f"outages[{i}] must be an Outage, got {o!r}")

    def delivered(self, t: float) -> bool:
        """Whether the packet sent at time ``t`` (s) arrives."""
        return not any(o.start <= t < o.start + o.duration for o in self.outages)


class DeadlineDetector:
    """Declares a disconnection when no packet arrived for more than ``deadline`` seconds."""

    def __init__(self, deadline: float = 0.050) -> None:
        self.deadline = check_positive("deadline", deadline)
        self.last_rx: float | None = None

    def packet(self, t: float) -> None:
        """Record a packet received at ``t`` seconds.

        Raises:
            InvalidParameterError: ``t`` is not a finite number (a NaN time would disable
                the detector: no later time would ever be past the deadline); the detector
                is left unchanged.
        """
        self.last_rx = check_finite("t", t)

    def disconnected(self, t: float) -> bool:
        """True when the last packet is older than the deadline at time ``t``."""
        return self.last_rx is not None and t - self.last_rx > self.deadline + 1e-9


def task_outage(
    rng: np.random.Generator,
    task_duration: float,
    *,
    after_fraction: float = 0.4,
    latest_fraction: float = 0.6,
    max_duration: float = 5.0,
    min_duration: float = 0.5,
) -> Outage:
    """The benchmark's outage: starts uniformly in ``[after, latest]`` x task, lasts up to 5 s.

    Args:
        task_duration: seconds.
        after_fraction: earliest start as a fraction of the task (thesis: 40 %).
        latest_fraction: latest start as a fraction of the task.
        max_duration: longest outage, seconds (thesis: 5 s).
        min_duration: shortest outage, seconds.

    Raises:
        InvalidParameterError: unless ``0 <= after_fraction <= latest_fraction <= 1`` and
            ``0 <= min_duration <= max_duration``, all finite (``task_duration`` finite >= 0).
    """
    T = check_finite("task_duration", task_duration, minimum=0.0)
    after = check_finite("after_fraction", after_fraction, minimum=0.0)
    latest = check_finite("latest_fraction", latest_fraction, minimum=0.0)
    if latest > 1.0 or after > latest:
        raise InvalidParameterError(
            "need 0 <= after_fraction <= latest_fraction <= 1, got "
            f"after_fraction={after_fraction!r}, latest_fraction={latest_fraction!r}"
        )
    lo = check_finite("min_duration", min_duration, minimum=0.0)
    if check_finite("max_duration", max_duration) < lo:
        raise InvalidParameterError(
            f"max_duration must be >= min_duration={min_duration!r}, got {max_duration!r}"
        )
    start = rng.uniform(after_fraction * T, latest_fraction * T)
    return Outage(float(start), float(rng.uniform(min_duration, max_duration)))


def random_outages(
    rng: np.random.Generator,
    horizon: float,
    *,
    mean_up: float = 5.0,
    mean_down: float = 1.0,
    max_down: float = 5.0,
) -> list[Outage]:
    """Alternating up/down periods with exponential lengths (down capped at ``max_down``).

    Args:
        horizon: outages start before this time, seconds (finite, >= 0).
        mean_up: mean time between outages, seconds.
        mean_down: mean outage length, seconds.
        max_down: longest outage, seconds.

    The cost grows with the number of outages, about ``horizon / mean_up``: tiny means on
    a long horizon take long (there is no packet period here to bound them by).

    Raises:
        InvalidParameterError: ``mean_up``, ``mean_down`` or ``max_down`` is not finite and
            > 0 (zero lengths would never advance the clock), or ``horizon`` is not finite.
    """
    horizon = check_finite("horizon", horizon, minimum=0.0)
    check_positive("mean_up", mean_up)
    check_positive("mean_down", mean_down)
    check_positive("max_down", max_down)
    out: list[Outage] = []
    t = float(rng.exponential(mean_up))
    while t < horizon:
        d = float(min(rng.exponential(mean_down), max_down))
        out.append(Outage(t, d))
        t += d + float(rng.exponential(mean_up))
    return out
