"""Fill lattices: points covering a container's cavity at one particle per spacing³."""

from __future__ import annotations

import functools
import math

import numpy as np

from pourbench.geometry.shapes import ContainerShape, RevolvedShell

_FILL_SLACK = 1e-7
"""m: fill points may sit this much closer than a radius to a wall (float rounding)."""


def container_lattice(shape: ContainerShape, spacing: float) -> np.ndarray:
    """Fill points (local frame) covering a container's cavity at one per ``spacing``³.

    Layers ``spacing`` apart from the bottom up. In a revolved cavity each layer is a set of
    concentric rings ``spacing`` apart, the outer one half a spacing inside the wall, each
    holding round(2πρ / spacing) points: a layer then covers its disc at the liquid's number
    density, so the filled level is the level its volume reaches (a square lattice cut by
    a circle leaves a ragged empty rim — 12 % of a 4 cm cup's area at 5 mm — and the filled
    column would collapse into it); alternate layers turn their rings by half a step. A box
    cavity gets rows of points holding its area at the same density. Points are sorted
    lowest layer first, and within a layer in a golden-ratio order, so that a partial top
    layer is spread evenly. The array is cached per (shape, spacing) and read-only.
    """
    return _cached_lattice(shape, float(spacing))


@functools.lru_cache(maxsize=64)
def _cached_lattice(shape: ContainerShape, spacing: float) -> np.ndarray:
    r = 0.5 * spacing
    layers = []
    zs = np.arange(shape.bottom_z + r, shape.rim_height - r + 1e-9, spacing)
    if isinstance(shape, RevolvedShell):
        rings = _ring_radii(shape, zs, r)
        layer_xy = [_disc_points(rings[k], spacing, 0.5 * (k % 2)) for k in range(len(zs))]
    else:
        layer_xy = [_rect_points(shape.half_x, shape.half_y, spacing)] * len(zs)
    for z, xy in zip(zs, layer_xy, strict=True):
        if len(xy) == 0:
            continue
        pts = np.column_stack([xy, np.full(len(xy), z)])
        pts = pts[shape.sdf(pts) >= r - _FILL_SLACK]
        spread = np.argsort((np.arange(len(pts)) * 0.6180339887498949) % 1.0, kind="stable")
        layers.append(pts[spread])
    out = np.concatenate(layers) if layers else np.zeros((0, 3))
    out.flags.writeable = False  # shared by every caller through the cache
    return out


def _rect_points(half_x: float, half_y: float, spacing: float) -> np.ndarray:
    """Rows ``≈ spacing`` apart across a rectangle holding (area / spacing²) points in all:
    each row gets its share rounded with the error carried to the next row, its points
    spread evenly from half a spacing inside one wall to half a spacing inside the other."""
    rows = max(1, round(2.0 * half_y / spacing))
    per_row = 4.0 * half_x * half_y / spacing**2 / rows
    pts = []
    for j, y in enumerate(_inset(half_y, spacing, rows)):
        m = max(1, round((j + 1) * per_row) - round(j * per_row))
        pts.append(np.column_stack([_inset(half_x, spacing, m), np.full(m, y)]))
    return np.concatenate(pts)


def _inset(half: float, spacing: float, m: int) -> np.ndarray:
    """``m`` evenly spaced coordinates in [−half + spacing/2, half − spacing/2]."""
    if m == 1:
        return np.zeros(1)
    return np.linspace(-half + 0.5 * spacing, half - 0.5 * spacing, m)


def _ring_radii(shape: RevolvedShell, zs: np.ndarray, clearance: float) -> np.ndarray:
    """Largest radius at each height whose point is ``clearance`` from the wall (bisection on
    the SDF: on a sloped wall this is less than the cavity radius minus the clearance);
    −1 where even the axis is closer."""
    clearance -= _FILL_SLACK
    lo, hi = np.zeros(len(zs)), shape.inner_radius(zs).astype(float)
    zero = np.zeros(len(zs))
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        ok = shape.sdf(np.column_stack([mid, zero, zs])) >= clearance
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    axis_ok = shape.sdf(np.column_stack([zero, zero, zs])) >= clearance
    return np.where(axis_ok, lo, -1.0)


def _disc_points(rc: float, spacing: float, phase: float) -> np.ndarray:
    """Concentric rings of points ``spacing`` apart with centres within radius ``rc``; each
    ring at radius ρ holds round(2πρ / spacing) points, the central remainder one point when
    its area is at least half a cell. ``phase`` turns each ring by that fraction of a step."""
    pts = []
    rho = rc
    while rho >= 0.5 * spacing:
        m = max(1, round(2.0 * math.pi * rho / spacing))
        a = (np.arange(m) + phase) * (2.0 * math.pi / m)
        pts.append(np.column_stack([rho * np.cos(a), rho * np.sin(a)]))
        rho -= spacing
    if rho > -0.5 * spacing and math.pi * (rho + 0.5 * spacing) ** 2 >= 0.5 * spacing**2:
        pts.append(np.zeros((1, 2)))
    return np.concatenate(pts) if pts else np.zeros((0, 2))
