"""Signed-distance colliders: their kinds, per-collider record and bounding radii."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from pourbench.errors import InvalidParameterError
from pourbench.fluids import kernels as K
from pourbench.geometry.shapes import BoxShell, ContainerShape, RevolvedShell

KIND_NAMES = {name: code for code, name in enumerate(K.KINDS)}
"""Collider kind codes by name (:data:`pourbench.fluids.kernels.KINDS`)."""


@dataclass
class Collider:
    """One signed-distance collider in one world.

    ``pose`` is a 7-vector (x, y, z, qw, qx, qy, qz) in the world frame and ``com`` the point
    (world frame, m) its reaction torque is taken about; once the collider is added to a
    solver both are views of a row of the solver's pose table, which
    :meth:`PBFSolver.set_collider_poses` writes. ``body`` is a slot in the solver's
    reaction-force table, or −1.
    """

    world: int
    kind: int
    params: np.ndarray
    body: int = -1
    mesh: wp.Mesh | None = None
    pose: np.ndarray = field(default_factory=lambda: np.array([0, 0, 0, 1.0, 0, 0, 0]))
    shape: ContainerShape | None = None
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))


def shape_kind(shape: ContainerShape) -> tuple[int, np.ndarray]:
    """Kernel kind and flat parameters of a container shape."""
    if isinstance(shape, RevolvedShell):
        return KIND_NAMES["revolved"], shape.kernel_params()
    if isinstance(shape, BoxShell):
        return KIND_NAMES["box_shell"], shape.kernel_params()
    raise InvalidParameterError(f"unsupported container shape {type(shape).__name__}")


PRIMITIVE_SIZES = {  # primitive kinds: how many sizes they take
    "plane": (0, 1),
    "mesh": (0, 1),
    "box": (3,),
    "sphere": (1,),
    "capsule": (2,),
    "cylinder": (2,),
}


def check_sizes(kind: str, params: np.ndarray) -> None:
    """The sizes a primitive collider needs: box half-extents, sphere radius, capsule and
    cylinder radius and half-length, all > 0 (a capsule's half-length may be 0); plane and
    mesh take none (or one ignored value)."""
    counts = PRIMITIVE_SIZES.get(kind)
    if counts is None:  # container shells: the shape's own checks hold
        return
    if len(params) not in counts:
        raise InvalidParameterError(
            f"a {kind!r} collider takes {' or '.join(map(str, counts))} size(s), got "
            f"{len(params)}: {params.tolist()}"
        )
    if kind in ("plane", "mesh"):
        return
    positive = params[:1] if kind == "capsule" else params
    if np.any(positive <= 0) or np.any(params < 0):
        raise InvalidParameterError(f"{kind!r} sizes must be > 0, got {params.tolist()}")


def collider_bound(c: Collider) -> float:
    """Radius about the collider's origin that holds all of it (particles farther out than
    this plus their radius cannot touch it, so the kernels skip its SDF); planes: unbounded."""
    p = c.params.astype(float)
    if c.kind == KIND_NAMES["plane"]:
        return 1.0e30
    if c.kind == KIND_NAMES["box"]:
        return float(np.linalg.norm(p[:3]))
    if c.kind == KIND_NAMES["sphere"]:
        return float(p[0])
    if c.kind == KIND_NAMES["capsule"]:
        return float(p[0] + p[1])
    if c.kind == KIND_NAMES["cylinder"]:
        return float(np.hypot(p[0], p[1]))
    if c.kind == KIND_NAMES["mesh"]:
        return float(np.linalg.norm(c.mesh.points.numpy(), axis=1).max())
    if c.kind == KIND_NAMES["revolved"]:  # wall, then (ρ, z) points
        pts = p[1:].reshape(-1, 2)
        return float(np.hypot(pts[:, 0], pts[:, 1]).max() + 0.5 * p[0])
    wall, hx, hy, depth = p[:4]  # box shell
    return float(np.linalg.norm([hx + wall, hy + wall, depth + 2.0 * wall]))


@dataclass(frozen=True)
class ColliderLayout:
    """The rows of a device collider table (:func:`collider_table`), grouped by world.

    Attributes:
        order: the solver's collider index of each row.
        bounds: each row's bounding radius (:func:`collider_bound`), m.
        worlds: each row's world.
        world_first: the first row of each world that has colliders.
    """

    order: np.ndarray
    bounds: np.ndarray
    worlds: np.ndarray
    world_first: np.ndarray


def collider_table(
    colliders: list[Collider], num_worlds: int, num_body_slots: int, device: wp.Device
) -> tuple[K.Colliders, ColliderLayout]:
    """The kernels' collider table, its rows grouped by world, and their layout. Poses are
    left to the caller; the reaction tables (one row per body slot) are summed in integer
    units of ``K.WRENCH_UNIT``, so their sums do not depend on the order of the atomics."""
    order = sorted(range(len(colliders)), key=lambda i: colliders[i].world)
    rows = [colliders[i] for i in order]
    counts = [len(c.params) for c in rows]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int) if rows else []
    bounds = np.array([collider_bound(c) for c in rows], float)
    worlds = np.array([c.world for c in rows], int)
    wstart = np.searchsorted(worlds, np.arange(num_worlds), side="left").astype(np.int32)
    wend = np.searchsorted(worlds, np.arange(num_worlds), side="right").astype(np.int32)

    def ints(values: object) -> wp.array:
        return wp.array(values, dtype=wp.int32, device=device)

    table = K.Colliders()
    table.world_start, table.world_end = ints(wstart), ints(wend)
    table.kind = ints([c.kind for c in rows])
    table.start, table.count = ints(starts), ints(counts)
    table.mesh = wp.array(
        [c.mesh.id if c.mesh is not None else 0 for c in rows], dtype=wp.uint64, device=device
    )
    flat = [c.params for c in rows]
    table.params = wp.array(
        np.concatenate(flat) if flat else np.zeros(1, np.float32), dtype=float, device=device
    )
    table.body = ints([c.body for c in rows])
    table.bound = wp.array(bounds, dtype=float, device=device)
    slots = max(num_body_slots, 1)
    table.force = wp.zeros((slots, 3), dtype=wp.int64, device=device)
    table.torque = wp.zeros((slots, 3), dtype=wp.int64, device=device)
    layout = ColliderLayout(
        order=np.array(order, dtype=np.intp),
        bounds=bounds,
        worlds=worlds,
        world_first=np.flatnonzero(np.diff(worlds, prepend=-1)),
    )
    return table, layout
