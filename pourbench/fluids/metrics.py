"""Where the liquid is: mass inside each container, spilled, in flight.

A particle is *inside* a container when it lies in the container's cavity (its local frame,
up to one particle spacing above the rim); *spilled* when it is in no container and below
the lowest container's rim (it can no longer fall into one: it runs down a wall, falls beside
the containers or lies on the table, however deep the puddle); *in flight* otherwise (a
stream above the rims, or drops on a rim). At rest after a pour, inside + spilled = total.
The rim heights are the containers' upright ones, at their poses' heights.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_index
from pourbench.fluids.accounting import LiquidCounter
from pourbench.fluids.solver import PBFSolver


@dataclass(frozen=True)
class LiquidMetrics:
    """Liquid accounting of one world, grams (particle count for ``particles``)."""

    total_g: float
    inside_g: tuple[float, ...]
    spilled_g: float
    in_flight_g: float
    particles: int


def liquid_metrics(solver: PBFSolver, world: int, containers: list[int]) -> LiquidMetrics:
    """Liquid inside each of ``containers`` (collider indices), spilled and in flight."""
    return liquid_metrics_all(solver, {world: containers})[0]


def liquid_metrics_all(
    solver: PBFSolver, containers: Mapping[int, Sequence[int]]
) -> list[LiquidMetrics]:
    """:func:`liquid_metrics` of each world ``w`` in ``containers`` (its container colliders
    ``containers[w]``, the same number for every world), in that order, counted on the
    solver's device in one pass (:class:`~pourbench.fluids.accounting.LiquidCounter`)."""
    if not isinstance(containers, Mapping):
        raise InvalidParameterError(
            f"containers must map each world to its container colliders, got {containers!r}"
        )
    worlds = [check_index("world", w, solver.num_worlds) for w in containers]
    cups = []
    for w in worlds:
        if isinstance(containers[w], str) or not isinstance(containers[w], Sequence):
            raise InvalidParameterError(
                f"world {w}'s containers must be a list of collider indices, got {containers[w]!r}"
            )
        cups.append([check_index("collider", c, len(solver.colliders)) for c in containers[w]])
        for c in cups[-1]:
            col = solver.colliders[c]
            if col.shape is None or col.world != w:
                raise InvalidParameterError(f"collider {c} is not a container of world {w}")
    if len({len(c) for c in cups}) > 1:
        raise InvalidParameterError("every world must list the same number of containers")
    k = len(cups[0]) if cups else 0
    cols = [[solver.colliders[c] for c in cs] for cs in cups]
    poses = np.array([[col.pose for col in cs] for cs in cols]).reshape(len(worlds), k, 7)
    index: dict = {}  # each distinct shape's place in the counter's list, in order of use
    indices = [[index.setdefault(col.shape, len(index)) for col in cs] for cs in cols]
    shape_index = np.array(indices, int).reshape(len(worlds), k)
    counter = LiquidCounter(solver, list(index), solver.config.spacing)
    inside, n_spilled, n_flight = counter.count(np.array(worlds, int), poses, shape_index)
    out = []
    for row, w in enumerate(worlds):
        m_g = solver.particle_mass(w) * 1e3
        n = int(inside[row].sum() + n_spilled[row] + n_flight[row])
        out.append(
            LiquidMetrics(
                total_g=n * m_g,
                inside_g=tuple(float(c) * m_g for c in inside[row]),
                spilled_g=float(n_spilled[row]) * m_g,
                in_flight_g=float(n_flight[row]) * m_g,
                particles=n,
            )
        )
    return out
