"""Implicit viscosity in physical units: the Warp kernels and the per-step solve.

Method: Weiler, Koschier, Brand & Bender (2018), "A Physically Consistent Implicit Viscosity
Solver for SPH Fluids", Computer Graphics Forum 37(2). After the velocity filters, every world
with a dynamic viscosity μ > 0 (``LiquidProfile.viscosity_pa_s``) solves, per step of length
dt and with ν = μ / ρ,

    (I − dt ν ∇²) v' = v

by conjugate gradients with a 3 × 3 block-Jacobi preconditioner, warm-started from v. With
``SolverConfig.viscous_displacement`` (on) :func:`finish` also moves each particle by dt
times the velocity the solve changed: the step's positions were set before the solve, and so
its displacement becomes the solved velocity's. The SPH Laplacian of a velocity field
(Weiler et al., Eq. 11, after Monaghan) is

    ∇²v_i = 2 (d + 2) Σ_j V_j (v_ij · x_ij) / (|x_ij|² + 0.01 h²) ∇_i W_ij,  d = 3,

with the spiky kernel's gradient and V_j = spacing³ / ``SolverConfig.laplacian_packing`` (the
settled liquid's pair sums fall short of the continuum's). A pair's block is g_ij r̂ r̂ᵀ,
symmetric and positive, so the system is symmetric positive definite, and the pair terms are
antisymmetric: the liquid's momentum and angular momentum are kept, and a rigid motion is not
damped.

A liquid with a Herschel–Bulkley law (``LiquidProfile.consistency_pa_sn``,
:mod:`pourbench.fluids.rheology`) takes the same solve with a viscosity per particle: before
it, each particle's shear rate comes from the velocities (the SPH velocity gradient with the
kernel-gradient correction, :func:`shear_viscosity`) and its viscosity from the law, capped
at ``SolverConfig.plug_viscosity_pa_s``; a pair's block is scaled by the mean of its two
particles' viscosities over the world's reference (``viscosity_pa_s``), so the system stays
symmetric, and a particle's wall term by its own. The viscosities lag the solve by one pass,
a Picard iteration: ``SolverConfig.shear_passes`` solves a step, each taking the
viscosities from the velocities the last one returned (the first from the velocities to be
solved, which carry the density solve's jitter).

A wall is no-slip. Its solid, counted as the density constraint's wall term counts it (a
half-space beyond the particle's nearest wall, or beside a sphere or capsule the sphere of the
wall's curvature, :func:`wall_tensor`), carries the velocity that extends the particle's
linearly to zero relative velocity at the wall (Morris, Fox & Zhu 1997, J. Comput.
Phys. 136): a solid point z from the particle along the wall normal moves relative to the
wall at −(z − d)/d times the particle's, d the particle's distance from the wall. That adds
T_i (v_i − v_wall) to the Laplacian's negative, with

    T_n = (225 / (h⁶ d)) ∫_d^h (h − r)² (r² − d²)(r² + d²) / r² dr,
    T_t = (112.5 / (h⁶ d)) ∫_d^h (h − r)² (r² − d²)² / r² dr

along and across a plane wall's normal (evaluated by Gauss–Legendre quadrature, d at least a
quarter spacing). The wall's velocity is the collider's at the particle over the step, and the
wall term's momentum goes to the collider's body as its reaction, so a body moving through a
viscous liquid feels its drag; the reaction's derivative in the body's velocity goes with it
(:func:`body_drag`, run when the coupling asks), for the coupling to integrate that drag
implicitly.

No library solves this on Warp arrays with per-world isolation, so the kernels are written
here. Each world's conjugate-gradient scalars are its own: its dot products are summed in
fixed chunks of its own particles (deterministic, and the same whether the world runs alone
or batched), and a world stops when its residual falls below ``tolerance`` times its
right-hand side. docs/viscosity.md gives the measured accuracy and cost.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import warp as wp

from pourbench.fluids import kernels as K

CHUNK = 256
"""Particles per partial sum of a world's dot products."""


GAUSS_NODES = wp.constant(
    wp.vec4(0.1834346424956498, 0.525532409916329, 0.7966664774136267, 0.9602898564975362)
)
GAUSS_WEIGHTS = wp.constant(
    wp.vec4(0.36268378337836166, 0.3137066458778869, 0.22238103445337443, 0.10122853629037706)
)
"""8-point Gauss–Legendre rule on [−1, 1] (nodes ± these): the wall tensor's integrals to
4e-5 for d ≥ h/20 (their closed forms cancel catastrophically in float32 as d → h)."""


@wp.func
def wall_tensor(d: float, kappa: float, h: float, d_min: float) -> wp.vec2:
    """(T_n, T_t), 1/m²: the no-slip wall's share of the Laplacian at distance ``d`` (at
    least ``d_min``) from a wall of mean curvature ``kappa`` (1/m, > 0 where the solid is
    convex, 0 for a plane; in [−1/(2h), 2/h] as the density term's), zero beyond h.

    A plane (κ = 0) takes the module docstring's integrals. A curved wall is a sphere of
    radius 1/|κ| touching the wall's nearest point, and a solid point at depth δ below its
    surface carries the particle's relative velocity times −δ/d. The shell of radius r about
    the particle holds that solid where cos θ ≥ c₀ = (κ(r² + d²) + 2d) / (2r(1 + κd)) (θ from
    the wall normal), and the velocity factor there is (d + δ)/d with
    δ = (2r(1 + κd) cos θ − 2d − κ(r² + d²)) / (1 + |κ| ρ), ρ the point's distance from the
    sphere's centre (both forms cancel nothing in float32 as κ → 0, where δ = r cos θ − d).
    So T_n = (900/(h⁶d)) ∫_d^h r (h − r)² ∫_{c₀}^1 (d + δ) cos²θ, and T_t the same with
    (1 − cos²θ)/2, each by the 8-point rule in r and in cos θ. Beside a sphere of 1.5 cm and
    h = 1 cm that is 0.6–0.85 of the plane's T_n and 0.4–0.6 of its T_t: the plane counts
    solid a small sphere does not have."""
    if d >= h:
        return wp.vec2(0.0)
    dc = wp.max(d, d_min)
    d2 = dc * dc
    half = 0.5 * (h - dc)
    mid = 0.5 * (h + dc)
    tn = float(0.0)
    tt = float(0.0)
    h3 = h * h * h
    scale = half / (h3 * h3 * dc)
    if kappa == 0.0:
        for k in range(4):
            for sign in range(2):
                r = mid + half * GAUSS_NODES[k] * float(2 * sign - 1)
                r2 = r * r
                q = (h - r) * (h - r) * (r2 - d2) / r2
                tn += GAUSS_WEIGHTS[k] * q * (r2 + d2)
                tt += GAUSS_WEIGHTS[k] * q * (r2 - d2)
        return wp.vec2(225.0 * scale * tn, 112.5 * scale * tt)
    one = 1.0 + kappa * dc
    for k in range(4):
        for sign in range(2):
            r = mid + half * GAUSS_NODES[k] * float(2 * sign - 1)
            lo = wp.clamp((kappa * (r * r + d2) + 2.0 * dc) / (2.0 * r * one), -1.0, 1.0)
            c_half = 0.5 * (1.0 - lo)
            c_mid = 0.5 * (1.0 + lo)
            sn = float(0.0)
            st = float(0.0)
            for m in range(4):
                for side in range(2):
                    c = c_mid + c_half * GAUSS_NODES[m] * float(2 * side - 1)
                    a = one - kappa * r * c
                    kr = kappa * r
                    k_rho = wp.sqrt(a * a + kr * kr * (1.0 - c * c))
                    f = dc + (2.0 * r * one * c - 2.0 * dc - kappa * (r * r + d2)) / (1.0 + k_rho)
                    sn += GAUSS_WEIGHTS[m] * f * c * c
                    st += GAUSS_WEIGHTS[m] * f * (1.0 - c * c)
            q = GAUSS_WEIGHTS[k] * r * (h - r) * (h - r) * c_half
            tn += q * sn
            tt += q * st
    return wp.vec2(900.0 * scale * tn, 450.0 * scale * tt)


@wp.func
def apply_wall(t: wp.vec2, n: wp.vec3, x: wp.vec3) -> wp.vec3:
    """T x for the wall tensor T = T_n n nᵀ + T_t (I − n nᵀ)."""
    return x * t[1] + n * ((t[0] - t[1]) * wp.dot(n, x))


@wp.func
def wall_matrix(t: wp.vec2, n: wp.vec3) -> wp.mat33:
    """The wall tensor T = T_n n nᵀ + T_t (I − n nᵀ) as a matrix."""
    return t[1] * wp.identity(n=3, dtype=float) + (t[0] - t[1]) * wp.outer(n, n)


@wp.func
def pair_weight(r: wp.vec3, h: float, coef: float) -> wp.vec3:
    """u with u uᵀ = g r̂ r̂ᵀ, the pair's block of −∇² (``coef`` = 2(d+2) V · 45/(π h⁶))."""
    d2 = wp.dot(r, r)
    dist = wp.sqrt(d2)
    if dist >= h or dist < 1.0e-9:
        return wp.vec3(0.0)
    q = h - dist
    g = coef * q * q * dist / (d2 + 0.01 * h * h)
    return r * (wp.sqrt(g) / dist)


class ViscosityKernels(NamedTuple):
    setup: wp.Kernel
    matvec: wp.Kernel
    velocity_gradient: wp.Kernel


def viscosity_kernels(half: bool) -> ViscosityKernels:
    """The three pair passes for half lists (``half``) or full lists (see
    :mod:`pourbench.fluids.kernels` for the layouts)."""

    @wp.kernel
    def setup(
        x: wp.array(dtype=wp.vec3),
        nbr: wp.array(dtype=wp.int32),
        nbr_start: wp.array(dtype=wp.int32),
        nbr_count: wp.array(dtype=wp.int32),
        stride: int,
        world: wp.array(dtype=wp.int32),
        c_w: wp.array(dtype=float),
        shear_law: wp.array(dtype=wp.vec4),
        scale: wp.array(dtype=float),
        h: float,
        coef: float,
        u: wp.array(dtype=wp.vec3),
        diag: wp.array(dtype=wp.mat33),
    ):
        """Each listed pair's u (:func:`pair_weight`, times √((s_i + s_j) / 2) in a world
        with a shear law, s the particles' viscosities over the world's reference) and every
        particle's Σ_j u uᵀ (``diag``, zero on entry)."""
        i = wp.tid()
        w = world[i]
        if c_w[w] == 0.0:
            return
        scaled = shear_law[w][3] > 0.0
        xi = x[i]
        acc = wp.mat33(0.0)
        k = nbr_start[i]
        k_end = k + nbr_count[i] * stride
        while k < k_end:
            j = nbr[k]
            uk = pair_weight(xi - x[j], h, coef)
            if scaled:
                uk = uk * wp.sqrt(0.5 * (scale[i] + scale[j]))
            u[k] = uk
            m = wp.outer(uk, uk)
            acc += m
            if wp.static(half):
                wp.atomic_add(diag, j, m)
            k += stride
        if wp.static(half):
            wp.atomic_add(diag, i, acc)
        else:
            diag[i] = acc

    @wp.kernel
    def matvec(
        y: wp.array(dtype=wp.vec3),
        nbr: wp.array(dtype=wp.int32),
        nbr_start: wp.array(dtype=wp.int32),
        nbr_count: wp.array(dtype=wp.int32),
        stride: int,
        world: wp.array(dtype=wp.int32),
        active: wp.array(dtype=wp.int32),
        u: wp.array(dtype=wp.vec3),
        out: wp.array(dtype=wp.vec3),
    ):
        """out_i = Σ_j (y_ij · u) u over the pairs (zero on entry with half lists)."""
        i = wp.tid()
        if active[world[i]] == 0:
            return
        yi = y[i]
        acc = wp.vec3(0.0)
        k = nbr_start[i]
        k_end = k + nbr_count[i] * stride
        while k < k_end:
            j = nbr[k]
            uk = u[k]
            t = uk * wp.dot(yi - y[j], uk)
            acc += t
            if wp.static(half):
                wp.atomic_sub(out, j, t)
            k += stride
        if wp.static(half):
            wp.atomic_add(out, i, acc)
        else:
            out[i] = acc

    @wp.kernel
    def velocity_gradient(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        nbr: wp.array(dtype=wp.int32),
        nbr_start: wp.array(dtype=wp.int32),
        nbr_count: wp.array(dtype=wp.int32),
        stride: int,
        world: wp.array(dtype=wp.int32),
        shear_law: wp.array(dtype=wp.vec4),
        h: float,
        coef: float,
        grad: wp.array(dtype=wp.mat33),
        moment: wp.array(dtype=wp.mat33),
    ):
        """In a world with a shear law, every particle's Σ_j V (v_j − v_i) ⊗ ∇W_ij
        (``grad``) and Σ_j V (x_j − x_i) ⊗ ∇W_ij (``moment``, the identity in a full
        neighbourhood), both zero on entry with half lists. A pair adds the same tensors to
        both of its particles (both factors change sign)."""
        i = wp.tid()
        if shear_law[world[i]][3] == 0.0:
            return
        xi = x[i]
        vi = v[i]
        g = wp.mat33(0.0)
        m = wp.mat33(0.0)
        k = nbr_start[i]
        k_end = k + nbr_count[i] * stride
        while k < k_end:
            j = nbr[k]
            r = xi - x[j]
            gw = K.spiky_grad(r, wp.length(r), h, coef)  # V ∇_i W_ij, zero beyond h
            gp = wp.outer(v[j] - vi, gw)
            mp = wp.outer(-r, gw)
            g += gp
            m += mp
            if wp.static(half):
                wp.atomic_add(grad, j, gp)
                wp.atomic_add(moment, j, mp)
            k += stride
        if wp.static(half):
            wp.atomic_add(grad, i, g)
            wp.atomic_add(moment, i, m)
        else:
            grad[i] = g
            moment[i] = m

    return ViscosityKernels(setup, matvec, velocity_gradient)


HALF_LISTS = viscosity_kernels(True)
FULL_LISTS = viscosity_kernels(False)


@wp.kernel
def shear_viscosity(
    world: wp.array(dtype=wp.int32),
    shear_law: wp.array(dtype=wp.vec4),
    plug_viscosity: float,
    grad: wp.array(dtype=wp.mat33),
    moment: wp.array(dtype=wp.mat33),
    rate: wp.array(dtype=float),
    scale: wp.array(dtype=float),
):
    """In a world with a shear law (τ_y, K, n, η_ref): the particle's shear rate
    γ̇ = √(2 D:D) of the deviatoric part of D = sym(∇v), with ∇v = grad · moment⁻¹ (the
    kernel-gradient correction, which keeps a particle at a wall or the surface first-order
    accurate; a particle whose neighbours lie too much to one side for it, moment's
    determinant under 0.05 of its mean diagonal cubed, takes grad over that mean), its
    viscosity η = min((τ_y + K γ̇ⁿ) / γ̇, ``plug_viscosity``) and ``scale`` =
    η / η_ref. Clears ``grad`` and ``moment``."""
    i = wp.tid()
    law = shear_law[world[i]]
    if law[3] == 0.0:
        return
    g = grad[i]
    m = moment[i]
    grad[i] = wp.mat33(0.0)
    moment[i] = wp.mat33(0.0)
    size = wp.trace(m) / 3.0
    if size < 1.0e-6:  # no neighbours: no gradient
        g = wp.mat33(0.0)
    elif wp.determinant(m) > 0.05 * size * size * size:
        g = g * wp.inverse(m)
    else:  # too one-sided to invert
        g = g / size
    d = 0.5 * (g + wp.transpose(g))
    d = d - wp.identity(n=3, dtype=float) * (wp.trace(d) / 3.0)
    gamma = wp.sqrt(2.0 * wp.ddot(d, d))
    rate[i] = gamma
    eta = plug_viscosity
    if gamma > 0.0:
        eta = wp.min((law[0] + law[1] * wp.pow(gamma, law[2])) / gamma, plug_viscosity)
    scale[i] = eta / law[3]


@wp.kernel
def start(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    world: wp.array(dtype=wp.int32),
    c_w: wp.array(dtype=float),
    wall: wp.array(dtype=K.vec5),
    wall_collider: wp.array(dtype=wp.int32),
    cols: K.Colliders,
    shear_law: wp.array(dtype=wp.vec4),
    scale: wp.array(dtype=float),
    h: float,
    d_min: float,
    dt: float,
    again: int,
    diag: wp.array(dtype=wp.mat33),
    wall_t: wp.array(dtype=wp.vec2),
    v_wall: wp.array(dtype=wp.vec3),
    rhs: wp.array(dtype=wp.vec3),
    sol: wp.array(dtype=wp.vec3),
    inv_m: wp.array(dtype=wp.mat33),
):
    """Per particle of a viscous world: the wall tensor (times the particle's s in a world
    with a shear law) and the wall's velocity there, the right-hand side v + c T v_wall, the
    start x = v, and the preconditioner's block (I + c (Σ u uᵀ + T))⁻¹, c = dt ν; clears
    ``diag``."""
    i = wp.tid()
    w = world[i]
    c = c_w[w]
    if c == 0.0:
        return
    xi = x[i]
    vi = v[i]
    wl = wall[i]
    n = wp.vec3(wl[0], wl[1], wl[2])
    t = wp.vec2(0.0)
    vb = wp.vec3(0.0)
    wc = wall_collider[i]
    if wc >= 0:
        t = wall_tensor(K.wall_distance(wl, xi), wl[4], h, d_min)
        if shear_law[w][3] > 0.0:  # the particle's own viscosity at its wall
            t = t * scale[i]
        if again != 0:  # a later pass: the poses have rolled over, the first pass's stands
            vb = v_wall[i]
        else:  # the point of the collider at the particle now, where it was at the step's start
            local = wp.transform_point(wp.transform_inverse(cols.pose[wc]), xi)
            vb = (xi - wp.transform_point(cols.pose_prev[wc], local)) / dt
    wall_t[i] = t
    v_wall[i] = vb
    rhs[i] = vi + apply_wall(t, n, vb) * c
    sol[i] = vi
    inv_m[i] = wp.inverse(wp.identity(n=3, dtype=float) + (diag[i] + wall_matrix(t, n)) * c)
    diag[i] = wp.mat33(0.0)


@wp.func
def apply_a(c: float, y: wp.vec3, lap: wp.vec3, t: wp.vec2, wl: K.vec5) -> wp.vec3:
    """(I + c (K + T)) y from the pair sum ``lap`` = K y."""
    return y + (lap + apply_wall(t, wp.vec3(wl[0], wl[1], wl[2]), y)) * c


@wp.kernel
def residual(
    chunk_start: wp.array(dtype=wp.int32),
    chunk_world: wp.array(dtype=wp.int32),
    c_w: wp.array(dtype=float),
    wall: wp.array(dtype=K.vec5),
    wall_t: wp.array(dtype=wp.vec2),
    inv_m: wp.array(dtype=wp.mat33),
    rhs: wp.array(dtype=wp.vec3),
    sol: wp.array(dtype=wp.vec3),
    lap: wp.array(dtype=wp.vec3),
    res: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    direction: wp.array(dtype=wp.vec3),
    partial: wp.array2d(dtype=float),
):
    """Per chunk: r = b − A x, z = M⁻¹ r, p = z, and the chunk's r·z, r·r, b·b; clears
    ``lap``."""
    k = wp.tid()
    c = c_w[chunk_world[k]]
    s0 = float(0.0)
    s1 = float(0.0)
    s2 = float(0.0)
    if c > 0.0:
        for i in range(chunk_start[k], chunk_start[k + 1]):
            r = rhs[i] - apply_a(c, sol[i], lap[i], wall_t[i], wall[i])
            zi = inv_m[i] * r
            res[i] = r
            z[i] = zi
            direction[i] = zi
            lap[i] = wp.vec3(0.0)
            s0 += wp.dot(r, zi)
            s1 += wp.dot(r, r)
            s2 += wp.dot(rhs[i], rhs[i])
    partial[k, 0] = s0
    partial[k, 1] = s1
    partial[k, 2] = s2


@wp.func
def world_sum(
    partial: wp.array2d(dtype=float), world_chunks: wp.array(dtype=wp.int32), w: int, col: int
) -> float:
    """Column ``col`` of world ``w``'s chunk sums, added in chunk order."""
    s = float(0.0)
    for k in range(world_chunks[w], world_chunks[w + 1]):
        s += partial[k, col]
    return s


@wp.kernel
def begin_worlds(
    world_chunks: wp.array(dtype=wp.int32),
    partial: wp.array2d(dtype=float),
    c_w: wp.array(dtype=float),
    tolerance: float,
    rz: wp.array(dtype=float),
    bb: wp.array(dtype=float),
    active: wp.array(dtype=wp.int32),
    iterations: wp.array(dtype=wp.int32),
    any_active: wp.array(dtype=wp.int32),
):
    """Per world: r·z and b·b from its chunks; a viscous world goes on while |r| exceeds
    ``tolerance`` |b| (``any_active`` zero on entry)."""
    w = wp.tid()
    s0 = world_sum(partial, world_chunks, w, 0)
    s1 = world_sum(partial, world_chunks, w, 1)
    s2 = world_sum(partial, world_chunks, w, 2)
    rz[w] = s0
    bb[w] = s2
    iterations[w] = 0
    go = c_w[w] > 0.0 and s1 > tolerance * tolerance * s2
    active[w] = int(go)
    if go:
        any_active[0] = 1


@wp.kernel
def project(
    chunk_start: wp.array(dtype=wp.int32),
    chunk_world: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    c_w: wp.array(dtype=float),
    wall: wp.array(dtype=K.vec5),
    wall_t: wp.array(dtype=wp.vec2),
    direction: wp.array(dtype=wp.vec3),
    lap: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    partial: wp.array2d(dtype=float),
):
    """Per chunk of an active world: q = A p and the chunk's p·q; clears ``lap``."""
    k = wp.tid()
    w = chunk_world[k]
    s = float(0.0)
    if active[w] != 0:
        c = c_w[w]
        for i in range(chunk_start[k], chunk_start[k + 1]):
            qi = apply_a(c, direction[i], lap[i], wall_t[i], wall[i])
            q[i] = qi
            lap[i] = wp.vec3(0.0)
            s += wp.dot(direction[i], qi)
    partial[k, 0] = s


@wp.kernel
def step_length(
    world_chunks: wp.array(dtype=wp.int32),
    partial: wp.array2d(dtype=float),
    rz: wp.array(dtype=float),
    active: wp.array(dtype=wp.int32),
    alpha: wp.array(dtype=float),
):
    """Per active world: α = r·z / p·A p."""
    w = wp.tid()
    if active[w] == 0:
        return
    alpha[w] = rz[w] / wp.max(world_sum(partial, world_chunks, w, 0), 1.0e-30)


@wp.kernel
def descend(
    chunk_start: wp.array(dtype=wp.int32),
    chunk_world: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    alpha: wp.array(dtype=float),
    inv_m: wp.array(dtype=wp.mat33),
    direction: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    sol: wp.array(dtype=wp.vec3),
    res: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    partial: wp.array2d(dtype=float),
):
    """Per chunk of an active world: x += α p, r −= α q, z = M⁻¹ r, and the chunk's r·z and
    r·r."""
    k = wp.tid()
    w = chunk_world[k]
    s0 = float(0.0)
    s1 = float(0.0)
    if active[w] != 0:
        a = alpha[w]
        for i in range(chunk_start[k], chunk_start[k + 1]):
            sol[i] = sol[i] + direction[i] * a
            r = res[i] - q[i] * a
            zi = inv_m[i] * r
            res[i] = r
            z[i] = zi
            s0 += wp.dot(r, zi)
            s1 += wp.dot(r, r)
    partial[k, 0] = s0
    partial[k, 1] = s1


@wp.kernel
def next_direction_scale(
    world_chunks: wp.array(dtype=wp.int32),
    partial: wp.array2d(dtype=float),
    tolerance: float,
    max_iterations: int,
    bb: wp.array(dtype=float),
    rz: wp.array(dtype=float),
    beta: wp.array(dtype=float),
    active: wp.array(dtype=wp.int32),
    iterations: wp.array(dtype=wp.int32),
    any_active: wp.array(dtype=wp.int32),
):
    """Per active world: β = r·z (new) / r·z (old); the world stops once |r| ≤ ``tolerance``
    |b| or after ``max_iterations`` (``any_active`` zero on entry)."""
    w = wp.tid()
    if active[w] == 0:
        return
    s0 = world_sum(partial, world_chunks, w, 0)
    s1 = world_sum(partial, world_chunks, w, 1)
    beta[w] = s0 / wp.max(rz[w], 1.0e-30)
    rz[w] = s0
    iterations[w] = iterations[w] + 1
    if s1 > tolerance * tolerance * bb[w] and iterations[w] < max_iterations:
        any_active[0] = 1
    else:
        active[w] = 0
        beta[w] = 0.0


@wp.kernel
def turn(
    world: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    beta: wp.array(dtype=float),
    z: wp.array(dtype=wp.vec3),
    direction: wp.array(dtype=wp.vec3),
):
    """p = z + β p in the worlds still active."""
    i = wp.tid()
    w = world[i]
    if active[w] != 0:
        direction[i] = z[i] + direction[i] * beta[w]


@wp.func
def skew(r: wp.vec3) -> wp.mat33:
    """[r]×: [r]× a = r × a."""
    return wp.mat33(0.0, -r[2], r[1], r[2], 0.0, -r[0], -r[1], r[0], 0.0)


DRAG_ENTRIES = 21
"""Upper triangle, row by row, of a body's symmetric 6 × 6 viscous drag matrix (force and
torque about the centre of mass against velocity and angular velocity)."""


@wp.kernel
def body_drag(
    world: wp.array(dtype=wp.int32),
    c_w: wp.array(dtype=float),
    mass: wp.array(dtype=float),
    dt: float,
    x: wp.array(dtype=wp.vec3),
    wall: wp.array(dtype=K.vec5),
    wall_collider: wp.array(dtype=wp.int32),
    wall_t: wp.array(dtype=wp.vec2),
    inv_m: wp.array(dtype=wp.mat33),
    cols: K.Colliders,
    drag: wp.array2d(dtype=wp.int64),
):
    """Each body's drag matrix after a solve (``drag`` zero on entry, in K.WRENCH_UNIT):
    the derivative of the wall's viscous reaction in the wall's velocity, each wall particle
    answering through its preconditioner block M = (I + c(Σ u uᵀ + T))⁻¹ (its neighbours
    held), is −(m/dt)(cT − cT M cT) = −k; at ``r`` from the body's CoM the body's wrench then
    falls by [[k, −k[r]×], [[r]×k, −[r]×k[r]×]] times its velocity and angular velocity."""
    i = wp.tid()
    w = world[i]
    c = c_w[w]
    wc = wall_collider[i]
    if c == 0.0 or wc < 0:
        return
    b = cols.body[wc]
    if b < 0:
        return
    t = wall_t[i]
    wl = wall[i]
    n = wp.vec3(wl[0], wl[1], wl[2])
    ct = wall_matrix(t, n) * c
    k = (ct - ct * inv_m[i] * ct) * (mass[w] / dt)
    r = x[i] - cols.com[wc]
    s = skew(r)
    off = -k * s
    rot = -(s * k * s)
    e = int(0)
    for row in range(6):
        for col in range(row, 6):
            val = float(0.0)
            if row < 3 and col < 3:
                val = k[row, col]
            elif row < 3:
                val = off[row, col - 3]
            else:
                val = rot[row - 3, col - 3]
            wp.atomic_add(drag, b, e, wp.int64(wp.round(val / K.WRENCH_UNIT)))
            e += 1


@wp.kernel
def finish(
    world: wp.array(dtype=wp.int32),
    c_w: wp.array(dtype=float),
    mass: wp.array(dtype=float),
    dt: float,
    wall: wp.array(dtype=K.vec5),
    wall_collider: wp.array(dtype=wp.int32),
    wall_t: wp.array(dtype=wp.vec2),
    v_wall: wp.array(dtype=wp.vec3),
    sol: wp.array(dtype=wp.vec3),
    cols: K.Colliders,
    move: int,
    v: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
):
    """v = the solution; with ``move``, the particle also moves by dt times the velocity
    the solve took off or added, so that its step's displacement is the solved velocity's;
    the wall's viscous force on the particle, m c T (v_wall − v) / dt, goes to the
    collider's body as its reaction."""
    i = wp.tid()
    w = world[i]
    c = c_w[w]
    if c == 0.0:
        return
    vi = sol[i]
    xi = x[i]
    wc = wall_collider[i]
    if wc >= 0:
        wl = wall[i]
        dv = apply_wall(wall_t[i], wp.vec3(wl[0], wl[1], wl[2]), v_wall[i] - vi) * c
        K.add_reaction(cols, wc, dv * dt, xi, mass[w], dt)
    if move != 0:
        x[i] = xi + (vi - v[i]) * dt
    v[i] = vi


def chunks(world_sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed chunks of each world's particles (worlds are contiguous, in order): chunk k
    spans ``start[k]`` to ``start[k + 1]`` and belongs to world ``owner[k]``; world w's chunks
    are ``first[w]`` to ``first[w + 1]``. A world's chunks depend only on its own size."""
    starts, owner, first = [], [], [0]
    off = 0
    for w, size in enumerate(world_sizes):
        k = max(1, -(-int(size) // CHUNK))
        starts.extend(off + CHUNK * np.arange(k))
        owner.extend([w] * k)
        first.append(first[-1] + k)
        off += int(size)
    starts.append(off)
    return (
        np.minimum(np.array(starts, np.int32), off),
        np.array(owner, np.int32),
        np.array(first, np.int32),
    )


class ImplicitViscosity:
    """The viscosity solve's buffers and launches for one upload of a
    :class:`~pourbench.fluids.solver.PBFSolver` (built by its ``_upload`` when some world has
    a dynamic viscosity). A step runs :meth:`start` at the end of the solver's step (before
    the colliders' poses roll over), :meth:`iteration` while :attr:`any_active` reads 1,
    then for each further pass of :attr:`passes` :meth:`refine` and the iterations again,
    then :meth:`finish`."""

    def __init__(
        self, solver, c_w: np.ndarray, world_sizes: np.ndarray, shear_law: np.ndarray
    ) -> None:
        """``c_w``: dt ν of each world's reference viscosity (0: no solve); ``shear_law``:
        (worlds, 4) τ_y (Pa), K (Pa·sⁿ), n and the reference viscosity η_ref (Pa·s) of each
        world with a Herschel–Bulkley law, zeros for a Newtonian world."""
        dev, n = solver.device, solver.buf.n
        self.solver = solver
        self.kernels = HALF_LISTS if solver.half_lists else FULL_LISTS
        cfg = solver.config
        # 2(d+2) V · 45/(π h⁶) over the packing: V = spacing³, 45/(π h⁶) the spiky gradient's
        self.coef = 10.0 * cfg.spacing**3 * 45.0 / (math.pi * cfg.h**6) / cfg.laplacian_packing
        self.coef_gradient = -(cfg.spacing**3) * 45.0 / (math.pi * cfg.h**6)  # V × the spiky's
        self.c_w = wp.array(c_w, dtype=float, device=dev)
        self.shear_law = wp.array(np.asarray(shear_law, np.float32), dtype=wp.vec4, device=dev)
        self.has_law = bool(np.any(np.asarray(shear_law)[:, 3] > 0))
        size = n if self.has_law else 1
        self.rate = wp.zeros(size, dtype=float, device=dev)
        self.scale = wp.ones(size, dtype=float, device=dev)
        self.grad = wp.zeros(size, dtype=wp.mat33, device=dev)
        self.moment = wp.zeros(size, dtype=wp.mat33, device=dev)
        start, owner, first = chunks(world_sizes)
        self.chunk_start = wp.array(start, dtype=wp.int32, device=dev)
        self.chunk_world = wp.array(owner, dtype=wp.int32, device=dev)
        self.world_chunks = wp.array(first, dtype=wp.int32, device=dev)
        self.num_chunks = len(owner)
        self.u = wp.zeros(len(solver.buf.nbr), dtype=wp.vec3, device=dev)
        self.diag = wp.zeros(n, dtype=wp.mat33, device=dev)
        self.inv_m = wp.zeros(n, dtype=wp.mat33, device=dev)
        self.wall_t = wp.zeros(n, dtype=wp.vec2, device=dev)
        self.drag = wp.zeros((max(solver.num_body_slots, 1), DRAG_ENTRIES), wp.int64, device=dev)
        for name in ("v_wall", "rhs", "sol", "res", "z", "direction", "q", "lap"):
            setattr(self, name, wp.zeros(n, dtype=wp.vec3, device=dev))
        self.partial = wp.zeros((self.num_chunks, 3), dtype=float, device=dev)
        nw = solver.num_worlds
        for name in ("rz", "bb", "alpha", "beta"):
            setattr(self, name, wp.zeros(nw, dtype=float, device=dev))
        self.active = wp.zeros(nw, dtype=wp.int32, device=dev)
        self.iterations = wp.zeros(nw, dtype=wp.int32, device=dev)
        self.any_active = wp.zeros(1, dtype=wp.int32, device=dev)

    def _matvec(self, key: str, y: wp.array, active: wp.array) -> None:
        s = self.solver
        b = s.buf
        s.launches.launch(
            key,
            self.kernels.matvec,
            [y, *b.lists, b.world, active, self.u],
            [self.lap],
        )

    @property
    def passes(self) -> int:
        """Solves a step takes: ``SolverConfig.shear_passes`` with a shear law, else one."""
        return self.solver.config.shear_passes if self.has_law else 1

    def start(self) -> None:
        """Pair weights, preconditioner, right-hand side, and the first residual; with a
        shear law the particles' viscosities first, from the velocities to be solved."""
        if self.has_law:
            self._shear_viscosities("", self.solver.buf.v)
        self._begin(again=False)

    def refine(self) -> None:
        """The next Picard pass: the particles' viscosities from the last pass's solution,
        and the solve set up again from the same velocities and walls (:meth:`start`; the
        colliders' poses have rolled over since, so the walls' velocities are kept)."""
        self._shear_viscosities("_refine", self.sol)
        self._begin(again=True)

    def _shear_viscosities(self, key: str, velocities: wp.array) -> None:
        s, cfg = self.solver, self.solver.config
        b = s.buf
        s.launches.launch(
            "visc_gradient" + key,
            self.kernels.velocity_gradient,
            [b.x, velocities, *b.lists, b.world, self.shear_law, cfg.h, self.coef_gradient],
            [self.grad, self.moment],
        )
        s.launches.launch(
            "visc_shear" + key,
            shear_viscosity,
            [b.world, self.shear_law, cfg.plug_viscosity_pa_s],
            [self.grad, self.moment, self.rate, self.scale],
        )

    def _begin(self, again: bool) -> None:
        s, cfg = self.solver, self.solver.config
        b = s.buf
        d_min = 0.5 * cfg.radius  # a particle is never nearer a wall than its radius less a bit
        s.launches.launch(
            "visc_setup",
            self.kernels.setup,
            [b.x, *b.lists, b.world, self.c_w, self.shear_law, self.scale, cfg.h, self.coef],
            [self.u, self.diag],
        )
        s.launches.launch(
            "visc_start_refine" if again else "visc_start",
            start,
            [
                *(b.x, b.v, b.world, self.c_w, b.wall, b.wall_collider, b.cols),
                *(self.shear_law, self.scale, cfg.h, d_min, cfg.dt, int(again)),
            ],
            [self.diag, self.wall_t, self.v_wall, self.rhs, self.sol, self.inv_m],
        )
        # every viscous world takes part in the first product (c_w > 0 marks them)
        s.launches.launch("visc_mark", mark_viscous, [self.c_w], [self.active], s.num_worlds)
        self._matvec("visc_matvec0", self.sol, self.active)
        s.launches.launch(
            "visc_residual",
            residual,
            [self.chunk_start, self.chunk_world, self.c_w, b.wall, self.wall_t, self.inv_m],
            [self.rhs, self.sol, self.lap, self.res, self.z, self.direction, self.partial],
            self.num_chunks,
        )
        self.any_active.zero_()
        s.launches.launch(
            "visc_begin",
            begin_worlds,
            [self.world_chunks, self.partial, self.c_w, cfg.viscosity_tolerance],
            [self.rz, self.bb, self.active, self.iterations, self.any_active],
            s.num_worlds,
        )

    def iteration(self) -> None:
        """One conjugate-gradient iteration of the worlds still active."""
        s, cfg = self.solver, self.solver.config
        self._matvec("visc_matvec", self.direction, self.active)
        s.launches.launch(
            "visc_project",
            project,
            [self.chunk_start, self.chunk_world, self.active, self.c_w, s.buf.wall, self.wall_t],
            [self.direction, self.lap, self.q, self.partial],
            self.num_chunks,
        )
        s.launches.launch(
            "visc_alpha",
            step_length,
            [self.world_chunks, self.partial, self.rz, self.active],
            [self.alpha],
            s.num_worlds,
        )
        s.launches.launch(
            "visc_descend",
            descend,
            [self.chunk_start, self.chunk_world, self.active, self.alpha, self.inv_m],
            [self.direction, self.q, self.sol, self.res, self.z, self.partial],
            self.num_chunks,
        )
        self.any_active.zero_()
        s.launches.launch(
            "visc_beta",
            next_direction_scale,
            [
                self.world_chunks,
                self.partial,
                cfg.viscosity_tolerance,
                cfg.viscosity_max_iterations,
                self.bb,
            ],
            [self.rz, self.beta, self.active, self.iterations, self.any_active],
            s.num_worlds,
        )
        turn_inputs = [s.buf.world, self.active, self.beta, self.z]
        s.launches.launch("visc_turn", turn, turn_inputs, [self.direction])

    def finish(self) -> None:
        """The solved velocities, and the walls' viscous reactions on their bodies."""
        s, cfg = self.solver, self.solver.config
        b = s.buf
        s.launches.launch(
            "visc_finish",
            finish,
            [
                *(b.world, self.c_w, b.mass, cfg.dt, b.wall, b.wall_collider),
                *(self.wall_t, self.v_wall, self.sol, b.cols, int(cfg.viscous_displacement)),
            ],
            [b.v, b.x],
        )

    def body_drag(self) -> np.ndarray:
        """(slots, DRAG_ENTRIES) of the last solve (:func:`body_drag`), N·s/m and kin: run on
        demand, so a step whose caller never asks pays nothing for it."""
        s, cfg = self.solver, self.solver.config
        b = s.buf
        self.drag.zero_()
        s.launches.launch(
            "visc_drag",
            body_drag,
            [
                *(b.world, self.c_w, b.mass, cfg.dt, b.x, b.wall, b.wall_collider),
                *(self.wall_t, self.inv_m, b.cols),
            ],
            [self.drag],
        )
        return self.drag.numpy()[: s.num_body_slots] * float(K.WRENCH_UNIT)


@wp.kernel
def mark_viscous(c_w: wp.array(dtype=float), active: wp.array(dtype=wp.int32)):
    w = wp.tid()
    active[w] = int(c_w[w] > 0.0)
