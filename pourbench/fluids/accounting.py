"""Liquid accounting on the solver's device: how many particles each container's cavity
holds, how many are spilled and how many are in flight, per world, from one kernel.

Only the per-world counts come back to the host (one read of ``rows × (k + 2)`` integers),
so an environment step on CUDA reads no particle data back to measure where its liquid is.
The rules are :mod:`pourbench.fluids.metrics`': a particle counts in the first container (in
``k`` order) whose cavity holds it, up to ``margin`` above the rim; otherwise it is spilled
below the lowest rim of its world's containers and in flight above it. The cavity
tests are :meth:`RevolvedShell.contains` and :meth:`BoxShell.contains` written as Warp
functions; they run in float32 on the particles' float32 positions, so a particle within
about a micrometre of a cavity's boundary may count on the other side of it than the float64
tests put it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import numpy as np
import warp as wp

from pourbench.fluids import kernels as K
from pourbench.fluids.colliders import shape_kind
from pourbench.fluids.solver import PBFSolver
from pourbench.fluids.warp_setup import load_kernels
from pourbench.geometry.rotation import warp_transforms
from pourbench.geometry.shapes import ContainerShape


@wp.func
def revolved_contains(
    q: wp.vec3, params: wp.array(dtype=float), start: int, count: int, margin: float
) -> bool:
    """Local point ``q`` in a revolved shell's cavity (params: wall, then (ρ, z) points)."""
    wall = params[start]
    npts = (count - 1) // 2
    bottom = params[start + 2] + 0.5 * wall  # the first point's z plus half the wall
    rim = params[start + 2 * npts]  # the last point's z
    if q[2] < bottom - margin or q[2] > rim + margin:
        return False
    z = wp.clamp(q[2], bottom, rim)
    # the side wall's segment at z (points 1 … npts − 1), clamped at its ends
    seg = int(1)
    for k in range(2, npts - 1):
        if params[start + 2 + 2 * k] < z:
            seg = k
    ar = params[start + 1 + 2 * seg]
    az = params[start + 2 + 2 * seg]
    dr = params[start + 3 + 2 * seg] - ar
    dz = params[start + 4 + 2 * seg] - az
    rho_mid = ar + wp.clamp((z - az) / dz, 0.0, 1.0) * dr
    radius = wp.max(rho_mid - 0.5 * wall * wp.sqrt(dr * dr + dz * dz) / dz, 0.0)
    return wp.sqrt(q[0] * q[0] + q[1] * q[1]) <= radius + 1.0e-9


@wp.func
def box_shell_contains(
    q: wp.vec3, params: wp.array(dtype=float), start: int, margin: float
) -> bool:
    """Local point ``q`` in a box shell's cavity (params: wall, hx, hy, depth, closed)."""
    wall = params[start]
    top = wall + params[start + 3]
    if params[start + 4] == 0.0:  # open: up to margin above the rim
        top = top + margin
    return (
        wp.abs(q[0]) <= params[start + 1]
        and wp.abs(q[1]) <= params[start + 2]
        and q[2] >= wall - margin
        and q[2] <= top
    )


@wp.kernel
def count_particles(
    x: wp.array(dtype=wp.vec3),
    world: wp.array(dtype=wp.int32),
    row_of: wp.array(dtype=wp.int32),
    poses: wp.array2d(dtype=wp.transform),
    shape_of: wp.array2d(dtype=wp.int32),
    kinds: wp.array(dtype=wp.int32),
    starts: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32),
    params: wp.array(dtype=float),
    spill_level: wp.array(dtype=float),
    margin: float,
    out: wp.array2d(dtype=wp.int32),
):
    """``out[r]``: particles inside each of row r's k containers, then spilled, in flight."""
    i = wp.tid()
    r = row_of[world[i]]
    if r < 0:
        return
    p = x[i]
    k = shape_of.shape[1]
    for j in range(k):
        s = shape_of[r, j]
        q = wp.transform_point(wp.transform_inverse(poses[r, j]), p)
        held = bool(False)
        if kinds[s] == K.REVOLVED:
            held = revolved_contains(q, params, starts[s], counts[s], margin)
        else:
            held = box_shell_contains(q, params, starts[s], margin)
        if held:
            wp.atomic_add(out, r, j, 1)
            return
    if p[2] < spill_level[r]:
        wp.atomic_add(out, r, k, 1)
    else:
        wp.atomic_add(out, r, k + 1, 1)


class LiquidCounter:
    """Counts a solver's particles in containers of the distinct ``shapes`` (the counts refer
    to them by index), on its device; ``margin`` (m): how far above an open rim a particle
    still counts as inside.
    """

    def __init__(self, solver: PBFSolver, shapes: Sequence[ContainerShape], margin: float) -> None:
        self.solver, self.margin = solver, float(margin)
        load_kernels([sys.modules[__name__]], solver.device)
        kinds = [shape_kind(s) for s in shapes]
        sizes = np.array([len(p) for _, p in kinds], np.int32)
        dev = solver.device
        self._kinds = wp.array(np.array([c for c, _ in kinds], np.int32), device=dev)
        self._starts = wp.array(np.cumsum(sizes) - sizes, dtype=wp.int32, device=dev)
        self._counts = wp.array(sizes, dtype=wp.int32, device=dev)
        flat = np.concatenate([p for _, p in kinds] + [np.zeros(1, np.float32)])
        self._params = wp.array(flat, dtype=float, device=dev)
        self._rim_z = np.array([s.rim_height for s in shapes], float)
        self._buffers: dict[tuple[int, int], tuple[wp.array, ...]] = {}

    def count(
        self, worlds: np.ndarray, poses: np.ndarray, shape_index: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Counts for the worlds ``worlds`` (rows, distinct), whose containers have the
        world poses ``poses`` (rows, k, 7: x y z qw qx qy qz) and the shapes ``shape_index``
        (rows, k) of this counter's list.

        Returns:
            inside (rows, k), spilled (rows,), in flight (rows,) particle counts.
        """
        s = self.solver
        rows, k = np.shape(shape_index)
        dev = s.device
        key = (rows, k)
        if key not in self._buffers:
            self._buffers[key] = (
                wp.empty(s.num_worlds, dtype=wp.int32, device=dev),
                wp.empty((rows, k), dtype=wp.transform, device=dev),
                wp.empty((rows, k), dtype=wp.int32, device=dev),
                wp.empty(rows, dtype=float, device=dev),
                wp.empty((rows, k + 2), dtype=wp.int32, device=dev),
            )
        row_of, pose_arr, shape_arr, spill, out = self._buffers[key]
        table = np.full(s.num_worlds, -1, np.int32)
        table[np.asarray(worlds)] = np.arange(rows, dtype=np.int32)
        row_of.assign(table)
        pose_arr.assign(warp_transforms(poses).reshape(rows, k, 7))
        shape_arr.assign(np.asarray(shape_index, np.int32))
        level = np.full(rows, np.inf)
        if k:
            level = (np.asarray(poses)[:, :, 2] + self._rim_z[shape_index]).min(1)
        spill.assign(level.astype(np.float32))
        out.zero_()
        x, world = s.particle_arrays()
        if len(x):
            wp.launch(
                count_particles,
                len(x),
                inputs=[
                    *(x, world, row_of, pose_arr, shape_arr),
                    *(self._kinds, self._starts, self._counts, self._params),
                    *(spill, self.margin, out),
                ],
                device=dev,
            )
        got = out.numpy().astype(np.int64)
        return got[:, :k], got[:, k], got[:, k + 1]
