"""The benchmark's baseline: a straightforward PBF step without neighbour lists.

Every neighbour pass (λ, Δp) queries the hash grid again and tests every candidate of the
surrounding cells, the way a first PBF implementation is usually written. Collisions are a
clamp into the tank's box, and there is no viscosity, vorticity or cohesion pass: it does
less work per step than the solver it is compared with. It exists only to be timed beside
:class:`PBFSolver` in the same process (``pourbench bench fluids``) and shares the solver's
kernel functions.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from pourbench.fluids.config import SolverConfig, rest_sums
from pourbench.fluids.kernels import spiky, spiky_grad

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _predict(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    g: wp.vec3,
    dt: float,
    p: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    v[i] = v[i] + g * dt
    p[i] = x[i] + v[i] * dt


@wp.kernel
def _lambda(
    grid: wp.uint64,
    p: wp.array(dtype=wp.vec3),
    h: float,
    w0: float,
    grad_c: float,
    eps: float,
    lam: wp.array(dtype=float),
):
    i = wp.tid()
    pi = p[i]
    rho = spiky(0.0, h)
    grad_i = wp.vec3(0.0)
    sum_grad2 = float(0.0)
    j = int(0)
    query = wp.hash_grid_query(grid, pi, h)
    while wp.hash_grid_query_next(query, j):
        if j != i:
            r = pi - p[j]
            d = wp.length(r)
            if d < h:
                rho += spiky(d, h)
                gj = spiky_grad(r, d, h, grad_c)
                grad_i += gj
                sum_grad2 += wp.dot(gj, gj)
    c = wp.max(rho / w0 - 1.0, 0.0)
    lam[i] = -c / (sum_grad2 + wp.dot(grad_i, grad_i) + eps)


@wp.kernel
def _delta(
    grid: wp.uint64,
    p: wp.array(dtype=wp.vec3),
    lam: wp.array(dtype=float),
    h: float,
    grad_c: float,
    lo: wp.vec3,
    hi: wp.vec3,
    p_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    pi = p[i]
    dp = wp.vec3(0.0)
    j = int(0)
    query = wp.hash_grid_query(grid, pi, h)
    while wp.hash_grid_query_next(query, j):
        if j != i:
            r = pi - p[j]
            d = wp.length(r)
            if d < h:
                dp += (lam[i] + lam[j]) * spiky_grad(r, d, h, grad_c)
    q = pi + dp
    p_out[i] = wp.vec3(
        wp.clamp(q[0], lo[0], hi[0]), wp.clamp(q[1], lo[1], hi[1]), wp.clamp(q[2], lo[2], hi[2])
    )


@wp.kernel
def _velocity(
    x: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    dt: float,
    v: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    v[i] = (p[i] - x[i]) / dt
    x[i] = p[i]


class BaselinePBF:
    """All-cells-candidates PBF on one world of particles in an axis-aligned box."""

    def __init__(self, positions: np.ndarray, lo: np.ndarray, hi: np.ndarray, cfg: SolverConfig):
        dev = wp.get_device(cfg.device)
        self.cfg, self.dev = cfg, dev
        r = cfg.radius
        self.lo, self.hi = wp.vec3(*(np.asarray(lo) + r)), wp.vec3(*(np.asarray(hi) - r))
        self.x = wp.array(positions.astype(np.float32), dtype=wp.vec3, device=dev)
        n = len(positions)
        self.n = n
        self.v = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.p = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.p2 = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.lam = wp.zeros(n, dtype=float, device=dev)
        self.w0, self.grad_c, s2 = rest_sums(cfg)
        self.eps = cfg.relaxation * s2
        self.grid = wp.HashGrid(128, 128, 128, device=dev)

    def step(self) -> None:
        cfg, dev, n = self.cfg, self.dev, self.n
        wp.launch(
            _predict, n, inputs=[self.x, self.v, wp.vec3(*cfg.gravity), cfg.dt, self.p], device=dev
        )
        self.grid.build(self.p, cfg.h)
        for _ in range(cfg.iterations):
            wp.launch(
                _lambda,
                n,
                inputs=[self.grid.id, self.p, cfg.h, self.w0, self.grad_c, self.eps, self.lam],
                device=dev,
            )
            wp.launch(
                _delta,
                n,
                inputs=[
                    self.grid.id,
                    self.p,
                    self.lam,
                    cfg.h,
                    self.grad_c,
                    self.lo,
                    self.hi,
                    self.p2,
                ],
                device=dev,
            )
            self.p, self.p2 = self.p2, self.p
        wp.launch(_velocity, n, inputs=[self.x, self.p, cfg.dt, self.v], device=dev)
