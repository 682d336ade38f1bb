"""Where the liquid is: mass inside each container, spilled, in flight.

A particle is *inside* a container when it lies in the container's cavity (its local frame,
up to one particle spacing above the rim); *spilled* when it is in no container and below
the lowest container's inner bottom (on the table or the floor); *in flight* otherwise
(a stream, or drops on a rim). At rest after a pour, inside + spilled = total.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pourbench.fluids.solver import PBFSolver, inverse_transform_points


@dataclass(frozen=True)
class LiquidMetrics:
    """Liquid accounting of one world, grams (particle count for ``particles``)."""

    total_g: float
    inside_g: tuple[float, ...]
    spilled_g: float
    in_flight_g: float
    particles: int


def liquid_metrics(
    solver: PBFSolver, world: int, containers: list[int], positions: np.ndarray | None = None
) -> LiquidMetrics:
    """Liquid inside each of ``containers`` (collider indices), spilled and in flight.

    ``positions``: every particle's position as :meth:`PBFSolver.positions` returns them, when
    the caller measures several worlds from one read (each read copies all worlds' particles
    from the device)."""
    x = (solver.positions() if positions is None else positions)[solver.world_slice(world)]
    m_g = solver.particle_mass(world) * 1e3
    free = np.ones(len(x), bool)
    inside = []
    spill_level = np.inf
    margin = solver.config.spacing
    for c in containers:
        col = solver.colliders[c]
        if col.shape is None or col.world != world:
            raise ValueError(f"collider {c} is not a container of world {world}")
        local = inverse_transform_points(col.pose, x)
        mask = col.shape.contains(local, margin=margin) & free
        free &= ~mask
        inside.append(float(mask.sum()) * m_g)
        bottom = col.pose[2] + col.shape.bottom_z
        spill_level = min(spill_level, bottom)
    spilled = free & (x[:, 2] < spill_level)
    return LiquidMetrics(
        total_g=len(x) * m_g,
        inside_g=tuple(inside),
        spilled_g=float(spilled.sum()) * m_g,
        in_flight_g=float((free & ~spilled).sum()) * m_g,
        particles=len(x),
    )
