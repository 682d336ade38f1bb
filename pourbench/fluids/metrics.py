"""Where the liquid is: mass inside each container, spilled, in flight.

A particle is *inside* a container when it lies in the container's cavity (its local frame,
up to one particle spacing above the rim); *spilled* when it is in no container and below
the lowest container's inner bottom (on the table or the floor); *in flight* otherwise
(a stream, or drops on a rim). At rest after a pour, inside + spilled = total.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_index
from pourbench.fluids.solver import PBFSolver, inverse_transform_points
from pourbench.geometry.shapes import ContainerShape


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

    ``positions``: every particle's position as :meth:`PBFSolver.positions` returns them (else
    they are read; each read copies all worlds' particles from the device)."""
    return liquid_metrics_all(solver, {world: containers}, positions)[0]


def liquid_metrics_all(
    solver: PBFSolver,
    containers: Mapping[int, Sequence[int]],
    positions: np.ndarray | None = None,
) -> list[LiquidMetrics]:
    """:func:`liquid_metrics` of each world ``w`` in ``containers`` (its container colliders
    ``containers[w]``, the same number for every world), in that order, from one read of the
    particles. The worlds' k-th containers that share a shape are tested in one pass."""
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
    x_all = solver.positions() if positions is None else positions
    if np.shape(x_all) != (solver.num_particles, 3):
        raise InvalidParameterError(
            f"positions must be ({solver.num_particles}, 3), every particle's, got "
            f"{np.shape(x_all)}"
        )
    slices = [solver.world_slice(w) for w in worlds]
    counts = np.array([s.stop - s.start for s in slices], int)
    x = np.concatenate([x_all[s] for s in slices]) if worlds else np.zeros((0, 3))
    owner = np.repeat(np.arange(len(worlds)), counts)  # row of each particle's world
    k = len(cups[0]) if cups else 0
    cols = [[solver.colliders[c] for c in cs] for cs in cups]
    poses = np.array([[col.pose for col in cs] for cs in cols]).reshape(len(worlds), k, 7)
    shapes: list = []
    index: dict[int, int] = {}
    shape_index = np.zeros((len(worlds), k), int)
    for row, cs in enumerate(cols):
        for j, col in enumerate(cs):
            shape_index[row, j] = index.setdefault(id(col.shape), len(shapes))
            if shape_index[row, j] == len(shapes):
                shapes.append(col.shape)
    inside, n_spilled, n_flight = count_liquid(
        x, owner, len(worlds), poses, shape_index, shapes, solver.config.spacing
    )
    out = []
    for row, w in enumerate(worlds):
        m_g = solver.particle_mass(w) * 1e3
        out.append(
            LiquidMetrics(
                total_g=int(counts[row]) * m_g,
                inside_g=tuple(float(n) * m_g for n in inside[row]),
                spilled_g=float(n_spilled[row]) * m_g,
                in_flight_g=float(n_flight[row]) * m_g,
                particles=int(counts[row]),
            )
        )
    return out


def count_liquid(
    x: np.ndarray,
    owner: np.ndarray,
    num_worlds: int,
    poses: np.ndarray,
    shape_index: np.ndarray,
    shapes: Sequence[ContainerShape],
    margin: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Particle counts inside each container, spilled and in flight, for every world at once.

    Args:
        x: (P, 3) particle positions, m.
        owner: (P,) world (row) of each particle, in [0, num_worlds).
        poses: (num_worlds, k, 7) container poses (x y z qx qy qz qw).
        shape_index: (num_worlds, k) index of each container's shape in ``shapes``.
        shapes: the distinct shapes; each is tested once for all the containers using it.
        margin: how far above the rim a particle still counts as inside, m.

    Returns:
        inside (num_worlds, k), spilled (num_worlds,), in flight (num_worlds,) counts; a
        particle counts in the first container (in ``k`` order) that holds it.
    """
    free = np.ones(len(x), bool)
    k = shape_index.shape[1]
    inside = np.zeros((num_worlds, k), int)
    spill_level = np.full(num_worlds, np.inf)
    bottom_z = np.array([s.bottom_z for s in shapes], float)
    for j in range(k):
        used = shape_index[:, j]
        for s in np.unique(used):
            rows = np.flatnonzero(used == s)
            sel = np.flatnonzero(np.isin(owner, rows))
            local = inverse_transform_points(poses[owner[sel], j], x[sel])
            mask = shapes[s].contains(local, margin=margin) & free[sel]
            free[sel[mask]] = False
            inside[:, j] += np.bincount(owner[sel[mask]], minlength=num_worlds)
        spill_level = np.minimum(spill_level, poses[:, j, 2] + bottom_z[used])
    spilled = free & (x[:, 2] < spill_level[owner])
    n_spilled = np.bincount(owner[spilled], minlength=num_worlds)
    n_flight = np.bincount(owner[free & ~spilled], minlength=num_worlds)
    return inside, n_spilled, n_flight
