"""Signed distances between robot capsules and obstacles, with analytic gradients.

Written here by hand (numpy, vectorised over many capsules at once). A robot link is a capsule:
a segment [a, b] swept by a sphere of radius r. Obstacles are spheres, oriented boxes and
capsules (a capsule obstacle also stands for another arm's link). Every distance is
``sd = |p_r − p_o| − radii`` between the closest (or, in penetration, deepest) points; it is
positive apart and negative in penetration.

Gradient: with the closest points unique, the derivative of ``sd`` with respect to the robot's
joints is ``nᵀ J(p_r)`` (thesis Eq. 4.60), where ``n`` is the unit normal pointing from the
obstacle to the robot and ``J(p_r)`` the Jacobian of the robot's closest point held fixed to
its link; the motion of the closest point along the segment does not change ``sd`` to first
order (the segment parameter is a minimiser). :func:`capsule_obstacle_distances` returns ``sd``,
``n`` and ``p_r``; :mod:`pourbench.planners.nmpc` turns them into joint-space gradients.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pourbench.errors import InvalidParameterError, check_finite

_EPS = 1e-12


def _vec3(name: str, v: object) -> np.ndarray:
    """``v`` as a new (3,) float array (never the caller's array: obstacles are frozen)."""
    a = np.array(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidParameterError(f"{name} must be 3 finite numbers, got {v!r}")
    return a


@dataclass(frozen=True)
class Sphere:
    """Sphere obstacle: ``center`` (m), ``radius`` (m), constant ``velocity`` (m/s)."""

    center: np.ndarray
    radius: float
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3("sphere center", self.center))
        object.__setattr__(self, "velocity", _vec3("sphere velocity", self.velocity))
        # radius 0 (a point; for a capsule, a segment) is allowed: the distances handle it
        object.__setattr__(self, "radius", check_finite("sphere radius", self.radius, minimum=0.0))


@dataclass(frozen=True)
class Box:
    """Oriented box: ``center`` (m), ``half_extents`` (m), ``rotation`` box→world, ``velocity``."""

    center: np.ndarray
    half_extents: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3("box center", self.center))
        object.__setattr__(self, "velocity", _vec3("box velocity", self.velocity))
        h = _vec3("box half extents", self.half_extents)
        if np.any(h <= 0):
            raise InvalidParameterError(f"box half extents must be > 0, got {h}")
        object.__setattr__(self, "half_extents", h)
        R = np.array(self.rotation, dtype=float)  # a copy, as for the vectors
        if R.size != 9:
            raise InvalidParameterError(f"box rotation must be 3x3, got shape {R.shape}")
        R = R.reshape(3, 3)
        # orthonormal with det +1 (a reflection, det -1, is not a rotation)
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or not np.linalg.det(R) > 0.0:
            raise InvalidParameterError(
                f"box rotation must be a rotation matrix (orthonormal, det +1), got {R.tolist()}"
            )
        object.__setattr__(self, "rotation", R)


@dataclass(frozen=True)
class Capsule:
    """Capsule obstacle: axis end points ``a``, ``b`` (m), ``radius`` (m), ``velocity`` (m/s)."""

    a: np.ndarray
    b: np.ndarray
    radius: float
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "velocity", _vec3("capsule velocity", self.velocity))
        object.__setattr__(self, "a", _vec3("capsule end a", self.a))
        object.__setattr__(self, "b", _vec3("capsule end b", self.b))
        object.__setattr__(self, "radius", check_finite("capsule radius", self.radius, minimum=0.0))


Obstacle = Sphere | Box | Capsule

_KINDS = (Sphere, Box, Capsule)


def check_obstacles(obstacles: object, name: str = "obstacles") -> tuple[Obstacle, ...]:
    """``obstacles`` as a tuple, raising :class:`InvalidParameterError` that names the first
    entry that is not a :class:`Sphere`, :class:`Box` or :class:`Capsule`."""
    if isinstance(obstacles, str | bytes | Sphere | Box | Capsule):
        raise InvalidParameterError(f"{name} must be a sequence of obstacles, got {obstacles!r}")
    try:
        obs = tuple(obstacles)  # type: ignore[arg-type]
    except TypeError as exc:
        raise InvalidParameterError(
            f"{name} must be a sequence of obstacles, got {obstacles!r}"
        ) from exc
    for i, ob in enumerate(obs):
        if not isinstance(ob, _KINDS):
            raise InvalidParameterError(f"{name}[{i}] must be a Sphere, Box or Capsule, got {ob!r}")
    return obs


def closest_t_point(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Parameter t ∈ [0, 1] of the point of segment(s) [a, b] closest to p; shapes (..., 3)."""
    ab = b - a
    den = np.maximum(np.einsum("...i,...i->...", ab, ab), _EPS)
    return np.clip(np.einsum("...i,...i->...", p - a, ab) / den, 0.0, 1.0)


def closest_st_segments(
    a1: np.ndarray, b1: np.ndarray, a2: np.ndarray, b2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Parameters (s, t) of the closest points of segments [a1, b1] and [a2, b2].

    Vectorised over leading axes; parallel segments get one valid closest pair.
    """
    d1, d2, r = b1 - a1, b2 - a2, a1 - a2
    dot = lambda x, y: np.einsum("...i,...i->...", x, y)  # noqa: E731
    A, E, F = dot(d1, d1), dot(d2, d2), dot(d2, r)
    C, B = dot(d1, r), dot(d1, d2)
    safeA, safeE = np.maximum(A, _EPS), np.maximum(E, _EPS)
    den = A * E - B * B
    general = den > 1e-12 * np.maximum(A * E, _EPS)
    s = np.where(general, np.clip((B * F - C * E) / np.where(general, den, 1.0), 0.0, 1.0), 0.0)
    t = (B * s + F) / safeE
    s = np.where(t < 0.0, np.clip(-C / safeA, 0.0, 1.0), s)
    s = np.where(t > 1.0, np.clip((B - C) / safeA, 0.0, 1.0), s)
    t = np.clip(t, 0.0, 1.0)
    # Degenerate segments (points).
    point2 = E <= _EPS
    s = np.where(point2, np.clip(-C / safeA, 0.0, 1.0), s)
    t = np.where(point2, 0.0, t)
    point1 = A <= _EPS
    s = np.where(point1, 0.0, s)
    t = np.where(point1, np.where(point2, 0.0, np.clip(F / safeE, 0.0, 1.0)), t)
    return s, t


def point_box_signed_distance(
    p: np.ndarray, center: np.ndarray, half: np.ndarray, rotation: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed distance from points p (..., 3) to a box, its unit gradient and the box point.

    ``center`` (..., 3), ``half`` (..., 3) and ``rotation`` (..., 3, 3, box → world) broadcast
    against ``p``, so many boxes can be handled at once.

    Returns:
        (sd, normal, surface point): sd (...) in m, negative inside; normal (..., 3) the unit
        gradient of sd with respect to p (world frame); the closest point on the box surface.
    """
    local = np.einsum("...i,...ij->...j", p - center, rotation)  # world → box frame
    q = np.abs(local) - half
    outside = np.maximum(q, 0.0)
    out_norm = np.sqrt(np.einsum("...i,...i->...", outside, outside))
    inside = np.minimum(q.max(axis=-1), 0.0)
    sd = out_norm + inside
    sign = np.where(local >= 0.0, 1.0, -1.0)
    n_out = sign * outside / np.maximum(out_norm, _EPS)[..., None]
    axis = np.argmax(q, axis=-1)
    n_in = np.where(np.arange(3) == axis[..., None], sign, 0.0)
    is_out = (out_norm > 0.0)[..., None]
    n_local = np.where(is_out, n_out, n_in)
    surface_local = np.where(is_out, np.clip(local, -half, half), local - n_local * sd[..., None])
    to_world = lambda v: np.einsum("...ij,...j->...i", rotation, v)  # noqa: E731
    return sd, to_world(n_local), to_world(surface_local) + center


def _box_sd_only(local: np.ndarray, half: np.ndarray) -> np.ndarray:
    q = np.abs(local) - half
    outside = np.maximum(q, 0.0)
    return np.sqrt(np.einsum("...i,...i->...", outside, outside)) + np.minimum(q.max(-1), 0.0)


def segment_box_closest_t(
    a: np.ndarray, b: np.ndarray, center: np.ndarray, half: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """Segment parameter t ∈ [0, 1] minimising the signed point-box distance along [a, b].

    Exact: the signed distance is convex along the segment; outside the box its square is
    piecewise quadratic between the parameters where a coordinate crosses a face plane, and
    inside it is the maximum of six linear functions. The minimiser is therefore one of: the
    segment ends, the face-plane crossings, the minimiser of each quadratic piece, or a
    crossing of two of the linear functions. All candidates are evaluated at once.

    Args:
        a: segment start points, (..., 3) in m.
        b: segment end points, (..., 3) in m.
        center: box centres, (..., 3) in m (broadcast against ``a``).
        half: box half extents, (..., 3) in m.
        rotation: box → world rotations, (..., 3, 3).

    Returns:
        (...) parameters t.
    """
    al = np.einsum("...i,...ij->...j", a - center, rotation)  # box frame
    dl = np.einsum("...i,...ij->...j", b - a, rotation)
    h = np.broadcast_to(half, al.shape)
    safe_d = np.where(np.abs(dl) > 1e-12, dl, 1e-12)
    bp = np.concatenate([(h - al) / safe_d, (-h - al) / safe_d], axis=-1)  # (..., 6)
    bp = np.clip(np.nan_to_num(bp, nan=0.0), 0.0, 1.0)
    shape = a.shape[:-1]
    ends = np.stack([np.zeros(shape), np.ones(shape)], axis=-1)
    knots = np.sort(np.concatenate([ends, bp], axis=-1), axis=-1)  # (..., 8)
    lo, hi = knots[..., :-1], knots[..., 1:]
    mid = 0.5 * (lo + hi)
    pm = al[..., None, :] + mid[..., None] * dl[..., None, :]  # (..., 7, 3)
    sgn = np.where(pm >= 0.0, 1.0, -1.0)
    h7 = h[..., None, :]
    act = np.abs(pm) > h7
    dd = dl[..., None, :]
    num = np.where(act, dd * (al[..., None, :] - sgn * h7), 0.0).sum(-1)
    den = np.where(act, dd * dd, 0.0).sum(-1)
    tq = np.clip(-num / np.maximum(den, 1e-18), lo, hi)  # (..., 7)
    cand = np.concatenate([knots, tq], axis=-1)  # (..., 15)
    pts = al[..., None, :] + cand[..., None] * dl[..., None, :]
    vals = _box_sd_only(pts, h[..., None, :])
    best = np.argmin(vals, axis=-1)
    t_best = np.take_along_axis(cand, best[..., None], -1)[..., 0]
    inside = np.take_along_axis(vals, best[..., None], -1)[..., 0] <= 1e-9  # touches or enters
    if np.any(inside):
        # Penetrating segments: the minimiser may be a crossing of two of the six linear
        # functions σ(a_i + t d_i) − h_i that make up the distance inside the box.
        ai, di, hi_ = al[inside], dl[inside], h[inside]
        slope = np.concatenate([di, -di], axis=-1)
        icpt = np.concatenate([ai - hi_, -ai - hi_], axis=-1)
        iu, ju = np.triu_indices(6, k=1)
        dm = slope[..., iu] - slope[..., ju]
        tx = (icpt[..., ju] - icpt[..., iu]) / np.where(np.abs(dm) > 1e-12, dm, 1e-12)
        tx = np.clip(np.nan_to_num(tx, nan=0.0), 0.0, 1.0)
        c2 = np.concatenate([cand[inside], tx], axis=-1)
        v2 = _box_sd_only(ai[:, None, :] + c2[..., None] * di[:, None, :], hi_[:, None, :])
        t_best[inside] = np.take_along_axis(c2, np.argmin(v2, axis=-1)[:, None], -1)[:, 0]
    return t_best


@dataclass(frozen=True)
class DistanceResult:
    """Signed distances of robot capsules to obstacles; leading shape (..., K, L).

    Attributes:
        sd: signed distances in m.
        normal: unit normals (..., K, L, 3) from the obstacle towards the robot.
        point_robot: closest point on the robot capsule's axis (..., K, L, 3) in m.
        point_obstacle: closest point on the obstacle's surface (..., K, L, 3) in m.
    """

    sd: np.ndarray
    normal: np.ndarray
    point_robot: np.ndarray
    point_obstacle: np.ndarray


def _finish(pa: np.ndarray, po: np.ndarray, ra: np.ndarray, ro: np.ndarray):
    """Sphere-swept distance between points pa (robot axis) and po (obstacle core)."""
    diff = pa - po
    dist = np.sqrt(np.einsum("...i,...i->...", diff, diff))
    fallback = np.array([0.0, 0.0, 1.0])
    normal = np.where((dist > 1e-9)[..., None], diff / np.maximum(dist, 1e-9)[..., None], fallback)
    return dist - ra - ro, normal, po + ro[..., None] * normal


def capsule_obstacle_distances(
    seg_a: np.ndarray,
    seg_b: np.ndarray,
    radius: np.ndarray,
    obstacles: Sequence[Obstacle],
    times: np.ndarray | None = None,
) -> DistanceResult:
    """Signed distances between capsules (..., K) and every obstacle (L of them).

    Obstacles of one kind are handled together in one vectorised pass.

    Args:
        seg_a: capsule axis start points, (..., K, 3) in m.
        seg_b: capsule axis end points, (..., K, 3) in m.
        radius: capsule radii, (K,) in m.
        obstacles: spheres, boxes and capsules.
        times: optional times (s), shape ``seg_a.shape[:-2]``: obstacles with a velocity are
            placed at ``position + velocity · time`` for each leading index.

    Returns:
        A :class:`DistanceResult` with arrays of shape (..., K, L[, 3]).

    Raises:
        InvalidParameterError: an entry of ``obstacles`` is not a Sphere, Box or Capsule.
    """
    L = len(obstacles)
    groups = [
        (kind, [j for j, ob in enumerate(obstacles) if isinstance(ob, kind)])
        for kind in (Sphere, Capsule, Box)
    ]
    if sum(len(idx) for _, idx in groups) != L:  # something else among them: name it
        check_obstacles(obstacles)
    seg_a = np.asarray(seg_a, dtype=float)
    seg_b = np.asarray(seg_b, dtype=float)
    lead = seg_a.shape[:-1]
    rad = np.broadcast_to(np.asarray(radius, dtype=float), lead)[..., None]  # (..., K, 1)
    sd = np.empty((*lead, L))
    normal = np.empty((*lead, L, 3))
    pr = np.empty((*lead, L, 3))
    po = np.empty((*lead, L, 3))
    for kind, idx in groups:
        if not idx:
            continue
        obs = [obstacles[j] for j in idx]
        vel = np.array([ob.velocity for ob in obs])  # (X, 3)
        # A moving obstacle is handled in its own frame: shift the capsules by −v·t.
        if times is not None and np.any(vel != 0.0):
            shift = np.asarray(times, dtype=float)[..., None, None, None] * vel
        else:
            shift = np.zeros((len(obs), 3))
        sa = seg_a[..., None, :] - shift  # (..., K, X, 3)
        sb = seg_b[..., None, :] - shift
        axis = sb - sa
        if kind is Sphere:
            c = np.array([ob.center for ob in obs])
            t = closest_t_point(sa, sb, c)
            p = sa + t[..., None] * axis
            r_ob = np.array([ob.radius for ob in obs])
            s, nrm, q = _finish(p, np.broadcast_to(c, p.shape), rad, r_ob)
        elif kind is Capsule:
            A = np.array([ob.a for ob in obs])
            B = np.array([ob.b for ob in obs])
            s_, t_ = closest_st_segments(sa, sb, A, B)
            p = sa + s_[..., None] * axis
            c = A + t_[..., None] * (B - A)
            r_ob = np.array([ob.radius for ob in obs])
            s, nrm, q = _finish(p, c, rad, r_ob)
        else:
            ctr = np.array([ob.center for ob in obs])
            half = np.array([ob.half_extents for ob in obs])
            rot = np.array([ob.rotation for ob in obs])
            t = segment_box_closest_t(sa, sb, ctr, half, rot)
            p = sa + t[..., None] * axis
            sbox, nrm, q = point_box_signed_distance(p, ctr, half, rot)
            s = sbox - rad
        sd[..., idx] = s
        normal[..., idx, :] = nrm
        pr[..., idx, :] = p + shift
        po[..., idx, :] = q + shift
    return DistanceResult(sd=sd, normal=normal, point_robot=pr, point_obstacle=po)


def obstacle_from_mujoco_geom(
    geom_type: int, pos: np.ndarray, xmat: np.ndarray, size: np.ndarray
) -> Obstacle:
    """Obstacle primitive from a MuJoCo geom's type, world pose and ``geom_size``.

    Cylinders become capsules (a conservative cover).

    Raises:
        InvalidParameterError: the geom type is not sphere, box, capsule or cylinder.
    """
    import mujoco

    R = np.asarray(xmat, dtype=float).reshape(3, 3)
    if geom_type == mujoco.mjtGeom.mjGEOM_SPHERE:
        return Sphere(pos, size[0])
    if geom_type == mujoco.mjtGeom.mjGEOM_BOX:
        return Box(pos, size[:3], R)
    if geom_type in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
        return Capsule(pos - size[1] * R[:, 2], pos + size[1] * R[:, 2], size[0])
    raise InvalidParameterError(f"geom type {geom_type} cannot be a planner obstacle")
