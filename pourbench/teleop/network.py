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

from pourbench.errors import InvalidParameterError, check_finite

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
        self.dt = check_finite("dt", dt)
        if self.dt <= 0:
            raise InvalidParameterError(f"dt must be > 0, got {dt}")
        self.outages = tuple(outages)

    def delivered(self, t: float) -> bool:
        """Whether the packet sent at time ``t`` (s) arrives."""
        return not any(o.start <= t < o.start + o.duration for o in self.outages)


class DeadlineDetector:
    """Declares a disconnection when no packet arrived for more than ``deadline`` seconds."""

    def __init__(self, deadline: float = 0.050) -> None:
        self.deadline = check_finite("deadline", deadline)
        if self.deadline <= 0:
            raise InvalidParameterError(f"deadline must be > 0, got {deadline}")
        self.last_rx: float | None = None

    def packet(self, t: float) -> None:
        """Record a packet received at ``t`` seconds."""
        self.last_rx = float(t)

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
        rng: random generator.
        task_duration: seconds.
        after_fraction: earliest start as a fraction of the task (thesis: 40 %).
        latest_fraction: latest start as a fraction of the task.
        max_duration: longest outage, seconds (thesis: 5 s).
        min_duration: shortest outage, seconds.
    """
    T = check_finite("task_duration", task_duration, minimum=0.0)
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
    """Alternating up/down periods with exponential lengths (down capped at ``max_down``)."""
    horizon = check_finite("horizon", horizon, minimum=0.0)
    out: list[Outage] = []
    t = float(rng.exponential(mean_up))
    while t < horizon:
        d = float(min(rng.exponential(mean_down), max_down))
        out.append(Outage(t, d))
        t += d + float(rng.exponential(mean_up))
    return out
