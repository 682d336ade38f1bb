"""Container shapes as signed-distance fields: the liquid's view of a container.

Hand-written (no library gives thin-walled container SDFs). Two primitive families cover the
container family:

* :class:`RevolvedShell`: a wall of constant thickness around a polyline in the (ρ, z)
  half-plane, revolved about the local z axis. The polyline is the wall's *mid-surface*,
  starting on the axis at the bottom and ending at the rim. Cups, beakers, measuring
  cylinders, bowls, glasses and bottles with necks are all such profiles.
* :class:`BoxShell`: an open-topped box (tray) of constant wall thickness.

Both give ``sdf(points)`` in numpy (metres, negative inside the wall material), the analytic
interior volume up to the rim, and flat parameter arrays the Warp kernels read. Frames: the
local origin is the centre of the container's outer bottom; +z points out of the mouth.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_int, check_positive


@dataclass(frozen=True)
class RevolvedShell:
    """Thin wall revolved about local z.

    Attributes:
        profile: (ρ, z) points of the wall mid-surface, m; first point on the axis (ρ = 0) at
            the bottom, then strictly increasing z from the second point on (the side wall).
        wall: wall thickness, m.
    """

    profile: tuple[tuple[float, float], ...]
    wall: float

    def __post_init__(self) -> None:
        try:
            pts = np.asarray(self.profile, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InvalidParameterError(
                f"profile must be (rho, z) numbers, got {self.profile!r}"
            ) from exc
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
            raise InvalidParameterError(f"profile needs >= 3 (rho, z) points, got {self.profile!r}")
        # stored as tuples, so shapes stay hashable and comparable whatever the caller passed
        object.__setattr__(self, "profile", tuple((float(r), float(z)) for r, z in pts))
        object.__setattr__(self, "wall", check_positive("wall", self.wall))
        if not np.all(np.isfinite(pts)) or np.any(pts[:, 0] < 0):
            raise InvalidParameterError(f"profile points must be finite with rho >= 0: {pts}")
        if pts[0, 0] != 0.0:
            raise InvalidParameterError("profile must start on the axis (rho = 0)")
        if np.any(np.diff(pts[1:, 1]) <= 0):
            raise InvalidParameterError("side-wall z must strictly increase after the bottom")
        if np.any(pts[1:, 0] <= self.wall / 2):
            raise InvalidParameterError("side wall closer to the axis than half its thickness")

    @property
    def points(self) -> np.ndarray:
        return np.asarray(self.profile, dtype=float)

    @property
    def rim_height(self) -> float:
        """Height of the rim's mid-surface above the outer bottom, m."""
        return float(self.points[-1, 1])

    @property
    def bottom_z(self) -> float:
        """Height of the inside of the bottom, m."""
        return float(self.points[0, 1] + self.wall / 2)

    @property
    def outer_radius(self) -> float:
        """Largest outer radius, m."""
        return float(self.points[:, 0].max() + self.wall / 2)

    @property
    def mouth_radius(self) -> float:
        """Inner radius at the rim, m."""
        return float(self.points[-1, 0] - self.wall / 2)

    def inner_radius(self, z: np.ndarray | float) -> np.ndarray:
        """Radius of the cavity at height ``z`` (0 below the bottom or above the rim), m."""
        z = np.asarray(z, dtype=float)
        pts = self.points[1:]
        rho_mid = np.interp(z, pts[:, 1], pts[:, 0])
        seg = np.clip(np.searchsorted(pts[:, 1], z) - 1, 0, len(pts) - 2)
        d = pts[seg + 1] - pts[seg]
        secant = np.hypot(d[..., 0], d[..., 1]) / d[..., 1]  # 1/cos of the wall's slope
        r = rho_mid - 0.5 * self.wall * secant
        inside = (z >= self.bottom_z) & (z <= self.rim_height)
        return np.where(inside, np.maximum(r, 0.0), 0.0)

    def volume_below(self, z: float) -> float:
        """Cavity volume between the inner bottom and height ``z`` (capped at the rim), m^3.

        Exact for straight side segments: each is a frustum with radii offset inward.
        """
        z = min(z, self.rim_height)
        if z <= self.bottom_z:
            return 0.0
        knots = np.concatenate(([self.bottom_z], self.points[1:, 1], [z]))
        knots = np.unique(knots[(knots >= self.bottom_z) & (knots <= z)])
        total = 0.0
        for z0, z1 in itertools.pairwise(knots):
            eps = 1e-12 * (z1 - z0)
            r0 = float(self.inner_radius(z0 + eps))
            r1 = float(self.inner_radius(z1 - eps))
            total += math.pi * (z1 - z0) * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0
        return total

    @property
    def interior_volume(self) -> float:
        """Cavity volume up to the rim, m^3."""
        return self.volume_below(self.rim_height)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance to the wall material (negative inside the wall), m."""
        p = np.asarray(points, dtype=float)
        q = np.stack([np.hypot(p[..., 0], p[..., 1]), p[..., 2]], axis=-1)
        a, b = self.points[:-1], self.points[1:]
        ab = b - a
        t = np.einsum("...kj,kj->...k", q[..., None, :] - a, ab) / np.einsum("kj,kj->k", ab, ab)
        closest = a + np.clip(t, 0.0, 1.0)[..., None] * ab
        dist = np.linalg.norm(q[..., None, :] - closest, axis=-1).min(axis=-1)
        return dist - self.wall / 2

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether local points lie in the cavity (up to ``margin`` above the rim)."""
        p = np.asarray(points, dtype=float)
        z = np.clip(p[..., 2], self.bottom_z, self.rim_height)
        in_z = (p[..., 2] >= self.bottom_z - margin) & (p[..., 2] <= self.rim_height + margin)
        return in_z & (np.hypot(p[..., 0], p[..., 1]) <= self.inner_radius(z) + 1e-9)

    def kernel_params(self) -> np.ndarray:
        """Flat float32 parameters for the Warp kernels: [wall, (ρ, z) × n]."""
        return np.concatenate(([self.wall], self.points.ravel())).astype(np.float32)


@dataclass(frozen=True)
class BoxShell:
    """Box container: inner half-extents (x, y), inner depth, wall thickness (all m).

    Open-topped (a tray) unless ``closed``, which adds a lid of the wall's thickness.
    """

    half_x: float
    half_y: float
    depth: float
    wall: float
    closed: bool = False

    def __post_init__(self) -> None:
        for name in ("half_x", "half_y", "depth", "wall"):
            object.__setattr__(self, name, check_positive(f"BoxShell.{name}", getattr(self, name)))
        if not isinstance(self.closed, bool | np.bool_):
            raise InvalidParameterError(
                f"BoxShell.closed must be True or False, got {self.closed!r}"
            )
        object.__setattr__(self, "closed", bool(self.closed))

    @property
    def rim_height(self) -> float:
        return self.wall + self.depth

    @property
    def bottom_z(self) -> float:
        return self.wall

    @property
    def interior_volume(self) -> float:
        return 4.0 * self.half_x * self.half_y * self.depth

    def volume_below(self, z: float) -> float:
        return 4.0 * self.half_x * self.half_y * float(np.clip(z - self.wall, 0.0, self.depth))

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether local points lie in the cavity (up to ``margin`` above the rim)."""
        p = np.asarray(points, dtype=float)
        top = self.rim_height + (0.0 if self.closed else margin)
        return (
            (np.abs(p[..., 0]) <= self.half_x)
            & (np.abs(p[..., 1]) <= self.half_y)
            & (p[..., 2] >= self.bottom_z - margin)
            & (p[..., 2] <= top)
        )

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance to the wall material (outer box minus the cavity), m."""
        p = np.asarray(points, dtype=float)
        hw, lid = self.wall, float(self.closed)
        outer_half_z = 0.5 * self.depth + hw * (0.5 + 0.5 * lid)
        outer_c = np.array([0.0, 0.0, outer_half_z])
        outer_h = np.array([self.half_x + hw, self.half_y + hw, outer_half_z])
        cav_half = self.depth * (1.0 - 0.5 * lid)  # an open cavity extends above the rim
        cav_c = np.array([0.0, 0.0, hw + cav_half])
        cav_h = np.array([self.half_x, self.half_y, cav_half])
        return np.maximum(_box_sdf(p - outer_c, outer_h), -_box_sdf(p - cav_c, cav_h))

    def kernel_params(self) -> np.ndarray:
        """Flat float32 parameters for the Warp kernels: [wall, hx, hy, depth, closed]."""
        return np.array(
            [self.wall, self.half_x, self.half_y, self.depth, float(self.closed)], np.float32
        )


ContainerShape = RevolvedShell | BoxShell


def _box_sdf(p: np.ndarray, h: np.ndarray) -> np.ndarray:
    q = np.abs(p) - h
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


def _sizes(**sizes: float) -> list[float]:
    """The named sizes (m) as floats, each finite and > 0, or an error naming the size."""
    return [check_positive(name, value) for name, value in sizes.items()]


def cup(radius: float, depth: float, wall: float = 0.004) -> RevolvedShell:
    """Straight cylindrical cup: inner ``radius`` and inner ``depth`` (m)."""
    radius, depth, wall = _sizes(radius=radius, depth=depth, wall=wall)
    r, h = radius + wall / 2, wall / 2
    return RevolvedShell(((0.0, h), (r, h), (r, wall + depth)), wall)


def bowl(radius: float, depth: float, wall: float = 0.004, segments: int = 8) -> RevolvedShell:
    """Spherical-cap bowl: mouth inner ``radius`` and inner ``depth`` (m)."""
    radius, depth, wall = _sizes(radius=radius, depth=depth, wall=wall)
    segments = check_int("segments", segments, minimum=1)
    if not (0 < depth <= radius):
        raise InvalidParameterError(f"bowl depth must be in (0, radius], got {depth!r}")
    R = (radius**2 + depth**2) / (2 * depth)  # sphere through the mouth rim and the bottom
    zc = wall / 2 + R + wall / 2
    # mid-surface sphere of radius R + wall/2 about (0, zc); a flat foot of 0.4 mouth radius
    foot = 0.4 * radius
    phi0 = math.asin(min(foot / (R + wall / 2), 1.0))
    phi1 = math.acos((zc - (wall / 2 + depth + wall / 2)) / (R + wall / 2))
    pts = [(0.0, zc - (R + wall / 2) * math.cos(phi0))]
    for phi in np.linspace(phi0, phi1, segments + 1):
        pts.append(((R + wall / 2) * math.sin(phi), zc - (R + wall / 2) * math.cos(phi)))
    return RevolvedShell(tuple(pts), wall)


def bottle(
    radius: float,
    body_height: float,
    neck_radius: float,
    neck_height: float,
    shoulder_height: float = 0.03,
    wall: float = 0.003,
) -> RevolvedShell:
    """Bottle: cylindrical body, conical shoulder, cylindrical neck (inner dimensions, m)."""
    radius, body_height, neck_radius, neck_height, shoulder_height, wall = _sizes(**locals())
    r, n, h = radius + wall / 2, neck_radius + wall / 2, wall / 2
    pts = (
        (0.0, h),
        (r, h),
        (r, wall + body_height),
        (n, wall + body_height + shoulder_height),
        (n, wall + body_height + shoulder_height + neck_height),
    )
    return RevolvedShell(pts, wall)


def tray(radius: float = 0.10, depth: float = 0.03, wall: float = 0.004) -> RevolvedShell:
    """Round receiving tray (the thesis' radius-10 cm tray): a shallow cup."""
    return cup(radius, depth, wall)
