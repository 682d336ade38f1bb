"""Warp kernels of the position-based-fluids solver (Macklin & Müller 2013), hand-written.

No library ships PBF kernels with FleX's parameter semantics and per-world isolation, so they
live here. Every kernel runs unchanged on ``device="cpu"`` and ``device="cuda"``.

Conventions: ``h`` is the smoothing radius (2 × particle spacing), ``w0`` the rest "density"
in kernel units (a particle's kernel sum in a full cubic lattice times
``SolverConfig.rest_packing``, the settled liquid's share of it), so the density constraint
is ``C_i = Σ_j W_ij / w0 − 1``. Particles of different worlds never interact:
the spatial hash includes the world, and candidates of other worlds are rejected.
Per-world liquid parameters are arrays indexed by ``world[i]``.

Neighbour lists come in two modes, chosen per device by the solver. Half lists (the CPU
default): each pair (i, j) within h is listed once, by the particle whose cell comes first
(or the lower index in the same cell), and pair sums add the pair's term to both particles
(``wp.atomic_add``, a plain add on the serial CPU path), so every square root and division
is done once per pair. Full lists (the CUDA default): each particle lists all its neighbours
and sums only its own side, with no atomics between threads, so CUDA runs stay bit-for-bit
reproducible; the pair terms are the same expressions in both modes (:func:`pair_kernels`).

Entry ``c`` of particle ``i``'s list sits at ``nbr[start[i] + c * stride]``. Half lists are
built with a fixed capacity per particle, then packed (``stride`` 1, ``start`` the exclusive
scan of the counts), which the CPU's serial loops stream through; the density pass caches each
pair's gradient factor and tensile term for the position pass. Full lists are interleaved
(``start[i] = i``, ``stride`` = particle count): the threads of a GPU warp read the c-th
entries of consecutive particles from consecutive addresses, the build writes them in place
(no packing), and the position pass recomputes the pair terms instead of reading a cache
(arithmetic is cheaper than memory there).
"""

from __future__ import annotations

from typing import NamedTuple

import warp as wp

from pourbench.fluids.warp_setup import init_warp

init_warp()  # before any kernel or array: quiet, and without the no-driver notice
wp.set_module_options({"enable_backward": False})

vec5 = wp.types.vector(length=5, dtype=wp.float32)
"""Density pair sums of a particle: Σ∇_i C (xyz), Σ W (w) and Σ|∇_j C|², added in one go."""

KINDS = ("plane", "box", "sphere", "capsule", "cylinder", "mesh", "revolved", "box_shell")
"""Collider kinds, one SDF routine each; a kind's code is its index here."""
PLANE = wp.constant(KINDS.index("plane"))
BOX = wp.constant(KINDS.index("box"))
SPHERE = wp.constant(KINDS.index("sphere"))
CAPSULE = wp.constant(KINDS.index("capsule"))
CYLINDER = wp.constant(KINDS.index("cylinder"))
MESH = wp.constant(KINDS.index("mesh"))
REVOLVED = wp.constant(KINDS.index("revolved"))
BOX_SHELL = wp.constant(KINDS.index("box_shell"))


@wp.func
def poly6(r2: float, h: float) -> float:
    """Poly6 kernel without its constant 315/(64π h⁹) (it cancels in W / w0)."""
    h2 = h * h
    if r2 >= h2:
        return 0.0
    d = h2 - r2
    return d * d * d


@wp.func
def spiky(dist: float, h: float) -> float:
    """Spiky kernel without its constant 15/(π h⁶): the density kernel whose exact gradient
    is ``spiky_grad``, so each Jacobi step follows the true constraint gradient."""
    if dist >= h:
        return 0.0
    d = h - dist
    return d * d * d


@wp.func
def spiky_factor(dist: float, h: float, coef: float) -> float:
    """Scalar of the spiky-kernel gradient: ``spiky_grad(r, ...) = r * spiky_factor(...)``."""
    if dist >= h or dist < 1.0e-9:
        return 0.0
    d = h - dist
    return coef * d * d / dist


@wp.func
def spiky_grad(r: wp.vec3, dist: float, h: float, coef: float) -> wp.vec3:
    """Spiky-kernel gradient; ``coef`` = −45/(π h⁶) / w0 (constant scaled by the rest sum)."""
    return r * spiky_factor(dist, h, coef)


@wp.func
def density_pair(d2: float, h: float, grad_c: float, scorr: wp.vec4) -> wp.vec3:
    """Terms of a pair at squared distance ``d2``: (gradient factor, tensile s_corr, W).

    ∇_i W_ij = factor · r_ij; s_corr = −k ((W_poly6(r)/W_poly6(Δq))^n − c) with ``scorr`` =
    (k, n, W_poly6(Δq), c): Macklin & Müller 2013's Eq. 13 less an offset c that makes the
    term exert no net force on a particle in a flat free surface (see
    :func:`pourbench.fluids.config.scorr_offset`); W is the spiky density kernel (without
    its constant)."""
    dist = wp.sqrt(d2)
    ratio = poly6(d2, h) / scorr[2]
    s_corr = float(0.0)
    if scorr[1] == 4.0:
        s_corr = -scorr[0] * ((ratio * ratio) * (ratio * ratio) - scorr[3])
    else:
        s_corr = -scorr[0] * (wp.pow(ratio, scorr[1]) - scorr[3])
    return wp.vec3(spiky_factor(dist, h, grad_c), s_corr, spiky(dist, h))


@wp.func
def density_term(r: wp.vec3, h: float, grad_c: float, scorr: wp.vec4) -> vec5:
    """A pair's share of the density sums: ∇_i W_ij (xyz), W_ij and |∇W_ij|²."""
    terms = density_pair(wp.dot(r, r), h, grad_c, scorr)
    g = r * terms[0]
    return vec5(g[0], g[1], g[2], terms[2], wp.dot(g, g))


@wp.func
def surface_share(di: float, dj: float, band: float) -> float:
    """A pair's share of a free surface from its sparser particle's ρ/ρ0 (``di``, ``dj``): 1
    at or below a flat surface's density (1 − ``band``), 0 at rest density, linear between."""
    return wp.clamp((1.0 - wp.min(di, dj)) / band, 0.0, 1.0)


@wp.func
def pair_lambda(li: float, lj: float, di: float, dj: float, koff: float, band: float) -> float:
    """λ_i + λ_j plus the part of s_corr's offset k c (:func:`density_pair`) a pair does not
    take: k c (s − 1), with s the pair's :func:`surface_share`. ``koff`` = k c."""
    return li + lj + koff * (surface_share(di, dj, band) - 1.0)


@wp.func
def bulk_spread(
    scorr_ij: float, mean_i: float, mean_j: float, di: float, dj: float, band: float, spread: float
) -> float:
    """What a pair's s_corr (``scorr_ij``) loses to ``SolverConfig.bulk_scorr_spread``: its
    difference from its particles' mean s_corr (``mean_i``, ``mean_j``) times 1 − ``spread``,
    weighted by the pair's share of the bulk, 1 − its :func:`surface_share`."""
    bulk = 1.0 - surface_share(di, dj, band)
    return bulk * (1.0 - spread) * (scorr_ij - 0.5 * (mean_i + mean_j))


@wp.func
def delta_term(r: wp.vec3, lam_sum: float, h: float, grad_c: float, scorr: wp.vec4) -> wp.vec3:
    """A pair's share of Δp_i: (λ_i + λ_j + s_corr) ∇_i W_ij, ``lam_sum`` from
    :func:`pair_lambda`."""
    terms = density_pair(wp.dot(r, r), h, grad_c, scorr)
    return r * ((lam_sum + terms[1]) * terms[0])


@wp.func
def filter_pair(
    r: wp.vec3,
    vi: wp.vec3,
    vj: wp.vec3,
    ni: wp.vec3,
    nj: wp.vec3,
    om_i: float,
    om_j: float,
    vort_on: bool,
    h: float,
    grad_c: float,
    spacing: float,
    kc: float,
    ks: float,
    kf: float,
):
    """A pair's velocity-filter terms for particle i (see ``filter_sums``): W_ij (v_j, 1),
    η's (|ω_j| − |ω_i|) ∇_i W_ij (zero without vorticity confinement; the same term for both
    particles), and the cohesion, curvature and friction velocity change (antisymmetric)."""
    d = wp.length(r)
    wij = poly6(d * d, h)
    e = wp.vec3(0.0)
    if vort_on:
        e = spiky_grad(r, d, h, grad_c) * (om_j - om_i)
    f = (nj - ni) * ks  # curvature
    if d > 1.0e-9:
        rh = r / d
        f -= rh * (cohesion_spline(d, h) * kc)
        if d < spacing:
            dv = vj - vi
            f += (dv - rh * wp.dot(dv, rh)) * ((1.0 - d / spacing) * kf)
    return wp.vec4(vj[0] * wij, vj[1] * wij, vj[2] * wij, wij), e, f


@wp.func
def cohesion_spline(r: float, h: float) -> float:
    """Akinci et al. (2013) cohesion spline, normalised to a peak of 1 at r = h/2."""
    if r >= h or r <= 0.0:
        return 0.0
    h3 = h * h * h
    a = (h - r) * (h - r) * (h - r) * r * r * r
    if 2.0 * r > h:
        return 64.0 * a / (h3 * h3)
    return 64.0 * (2.0 * a - h3 * h3 / 64.0) / (h3 * h3)


# Step 1, predict, is with the collider kernels below: it measures each particle's clearance.


# ------------------------------------------------------------------ step 2: neighbour lists
# A spatial hash of (world, cell) → bucket, filled by a stable radix sort of the bucket keys,
# so each bucket lists its particles in ascending index order. Queries compare the exact
# integer cell and world of every candidate, which removes hash collisions and duplicates:
# a world's neighbour lists (and its floating-point sums) are the same whatever other worlds
# share the solver, without offsets or sorting. The bucket function depends on the list mode
# (``pair_kernels``): a Morton code for full lists, a multiplicative hash for half lists; the
# lists come out the same with either. (``wp.HashGrid``, which the benchmark's baseline uses,
# knows no worlds: its queries would return other worlds' particles to be filtered.)


@wp.func
def cell_of(p: wp.vec3, inv_cell: float) -> wp.vec3i:
    return wp.vec3i(
        int(wp.floor(p[0] * inv_cell)),
        int(wp.floor(p[1] * inv_cell)),
        int(wp.floor(p[2] * inv_cell)),
    )


@wp.func
def spread10(v: wp.uint32) -> wp.uint32:
    """Interleave the low 10 bits of ``v`` with two zero bits each (for a Morton code)."""
    x = v & wp.uint32(0x3FF)
    x = (x | (x << wp.uint32(16))) & wp.uint32(0x030000FF)
    x = (x | (x << wp.uint32(8))) & wp.uint32(0x0300F00F)
    x = (x | (x << wp.uint32(4))) & wp.uint32(0x030C30C3)
    x = (x | (x << wp.uint32(2))) & wp.uint32(0x09249249)
    return x


WORLD_MIX = wp.constant(wp.uint32(2654435761))  # Knuth's multiplicative hash, 2^32 / φ


FMIX_C1 = wp.constant(wp.uint32(0x85EBCA6B))  # module constants: inline literals above 2^31
FMIX_C2 = wp.constant(wp.uint32(0xC2B2AE35))  # compile as int32 with a C++ warning


@wp.func
def fmix32(x: wp.uint32) -> wp.uint32:
    """MurmurHash3's 32-bit finaliser: every input bit changes about half the output bits,
    the high ones included in the low ones; fmix32(0) = 0."""
    h = x ^ (x >> wp.uint32(16))
    h = h * FMIX_C1
    h = h ^ (h >> wp.uint32(13))
    h = h * FMIX_C2
    return h ^ (h >> wp.uint32(16))


@wp.func
def morton_bucket(w: int, c: wp.vec3i, mask: int) -> int:
    """Bucket of cell ``c`` of world ``w`` for full lists (the GPU's): the low bits of the
    cell's Morton code, offset per world and per block of space. Nearby cells get nearby
    buckets, so the particles sorted by bucket follow a space-filling curve and a warp's
    threads share cells and candidates (an H100 builds 1M particles' lists in 1.0 ms instead
    of 1.7 with :func:`mixed_bucket`).

    The low bits of a Morton code repeat every 2^(bits/3) cells along each axis (8 cells,
    8 cm, for a table of 1024 buckets), so on their own they put cells that far apart in the
    same bucket whenever a scene is wider than that: a pouring scene's stream or a spreading
    dam break then scans 1.7–3× the candidates of its own cells. The bits above the table's
    (which block of space the cell is in) are therefore hashed into an offset, like the
    world's. Cells may still share a bucket by chance; candidates are checked."""
    # unsigned arithmetic: wrap-around is defined (signed overflow is not, in C++)
    m = (
        spread10(wp.uint32(c[0]))
        | (spread10(wp.uint32(c[1])) << wp.uint32(1))
        | (spread10(wp.uint32(c[2])) << wp.uint32(2))
    )
    block = fmix32(m & ~wp.uint32(mask))
    return int((m + block + wp.uint32(w) * WORLD_MIX) & wp.uint32(mask))


@wp.func
def mixed_bucket(w: int, c: wp.vec3i, mask: int) -> int:
    """Bucket of cell ``c`` of world ``w`` for half lists (the CPU's): a multiplicative hash,
    cheaper to compute than the Morton code that a serial CPU loop has no use for."""
    h = (
        (wp.uint32(c[0]) * wp.uint32(73856093))
        ^ (wp.uint32(c[1]) * wp.uint32(19349663))
        ^ (wp.uint32(c[2]) * wp.uint32(83492791))
        ^ (wp.uint32(w) * wp.uint32(1640531527))
    )
    return int(h & wp.uint32(mask))


@wp.kernel
def bucket_ranges(
    keys: wp.array(dtype=wp.int32),
    sorted_idx: wp.array(dtype=wp.int32),
    p: wp.array(dtype=wp.vec3),
    world: wp.array(dtype=wp.int32),
    cell: wp.array(dtype=wp.vec3i),
    n: int,
    start: wp.array(dtype=wp.int32),
    end: wp.array(dtype=wp.int32),
    p_sorted: wp.array(dtype=wp.vec3),
    world_sorted: wp.array(dtype=wp.int32),
    cell_sorted: wp.array(dtype=wp.vec3i),
):
    """Bucket start/end in the sorted order; positions, worlds and cells copied into it."""
    k = wp.tid()
    j = sorted_idx[k]
    p_sorted[k] = p[j]
    world_sorted[k] = world[j]
    cell_sorted[k] = cell[j]
    b = keys[k]
    if k == 0 or keys[k - 1] != b:
        start[b] = k
    if k == n - 1 or keys[k + 1] != b:
        end[b] = k + 1


@wp.kernel
def pack_neighbours(
    nbr_build: wp.array(dtype=wp.int32),
    max_nb: int,
    count: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),
    nbr: wp.array(dtype=wp.int32),
):
    """Copy each particle's half list (``max_nb`` slots from ``nbr_build[i * max_nb]``) to
    ``nbr[start[i]:]`` (``start``: exclusive scan of count)."""
    i = wp.tid()
    s = start[i]
    b = i * max_nb
    for k in range(count[i]):
        nbr[s + k] = nbr_build[b + k]


@wp.func
def spread_bits(v: wp.uint64) -> wp.uint64:
    """Interleave the low 11 bits of ``v`` with two zero bits each (for a Morton code)."""
    x = v & wp.uint64(0x7FF)
    x = (x | (x << wp.uint64(16))) & wp.uint64(0x7F0000FF)
    x = (x | (x << wp.uint64(8))) & wp.uint64(0x700F00F00F)
    x = (x | (x << wp.uint64(4))) & wp.uint64(0x430C30C30C3)
    x = (x | (x << wp.uint64(2))) & wp.uint64(0x49249249249)
    return x


@wp.kernel
def order_keys(
    x: wp.array(dtype=wp.vec3),
    world: wp.array(dtype=wp.int32),
    inv_cell: float,
    keys: wp.array(dtype=wp.int64),
    values: wp.array(dtype=wp.int32),
):
    """Sort key (world, Morton code of the cell) that keeps worlds contiguous and neighbours
    close in memory."""
    i = wp.tid()
    c = cell_of(x[i], inv_cell)
    m = (
        spread_bits(wp.uint64(c[0]))
        | (spread_bits(wp.uint64(c[1])) << wp.uint64(1))
        | (spread_bits(wp.uint64(c[2])) << wp.uint64(2))
    )
    keys[i] = wp.int64((wp.uint64(world[i]) << wp.uint64(33)) | m)
    values[i] = i


@wp.kernel
def gather_state(
    order: wp.array(dtype=wp.int32),
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    x_out[k] = x[order[k]]
    v_out[k] = v[order[k]]


# ------------------------------------------------------------- step 3: density constraints


@wp.func
def wall_sum(d: float, kappa: float, h: float, coef: float) -> wp.vec2:
    """Kernel sum (spiky, without its constant) of the rest liquid a wall at distance ``d``
    replaces, and its derivative in ``d``.

    The solid beyond the wall is counted as liquid at the rest number density, over a sphere
    of the wall's mean curvature ``kappa`` (1/m, > 0 where the solid is convex, 0 for a
    plane) that touches the wall's nearest point. A shell of radius r about the particle
    holds π r (r − d)(2 − κ(r − d))/(1 + κd) of such a solid (2π r (r − d) of a half-space),
    so the sum is (2π/s³) [a⁵ (h/20 − a/30) − (κ/2) a⁶ (h/60 − a/105)] / (1 + κd) with
    a = h − d: exact for a sphere or a spherical cavity, to first order in κ for other
    smooth walls. ``kappa`` must lie in [−1/(2h), 2/h] (see :func:`wall_curvature`), where
    every shell's share stays within [0, 1] and 1 + κd at least 1/2. ``coef``
    (:func:`pourbench.fluids.config.wall_coef`) is 2π/s³ scaled so that at d = s/2 a plane
    wall's term equals what a cubic lattice's missing half holds, times ``rest_packing``: the
    continuum overcounts a lattice's nearest neighbours."""
    dc = wp.clamp(d, 0.0, h)
    a = h - dc
    a4 = a * a * a * a
    if kappa == 0.0:
        return wp.vec2(coef * a4 * a * (h / 20.0 - a / 30.0), -coef * (h * a4 / 4.0 - a4 * a / 5.0))
    half_k = 0.5 * kappa
    top = a4 * a * (h / 20.0 - a / 30.0) - half_k * a4 * a * a * (h / 60.0 - a / 105.0)
    dtop = -(a4 * (h / 4.0 - a / 5.0) - half_k * a4 * a * (h / 10.0 - a / 15.0))
    inv = 1.0 / (1.0 + kappa * dc)
    return wp.vec2(coef * top * inv, coef * (dtop - top * kappa * inv) * inv)


@wp.func
def wall_distance(wall: vec5, pi: wp.vec3) -> float:
    """Distance of ``pi`` from a particle's wall plane (n, offset, κ): n · p − offset."""
    return wp.dot(wp.vec3(wall[0], wall[1], wall[2]), pi) - wall[3]


@wp.func
def density_and_lambda(
    a: vec5, h: float, w0: float, eps: float, wall: vec5, pi: wp.vec3, wall_coef: float
) -> wp.vec2:
    """(ρ_i/ρ0, λ_i) from a particle's density sums ``a``: λ_i = −C_i / (Σ|∇C|² + ε) of the
    unilateral density constraint. The nearest wall (``wall``: its plane, see
    :func:`predict`) adds the kernel sum of the liquid its solid replaces (:func:`wall_sum`)
    and that sum's gradient to ∇_i C_i; the wall has no constraint of its own, so it adds no
    |∇_wall C|² term."""
    ws = wall_sum(wall_distance(wall, pi), wall[4], h, wall_coef)
    grad_i = wp.vec3(a[0], a[1], a[2]) + wp.vec3(wall[0], wall[1], wall[2]) * (ws[1] / w0)
    rho = (a[3] + spiky(0.0, h) + ws[0]) / w0
    c = wp.max(rho - 1.0, 0.0)  # unilateral: a free surface is not pulled together
    return wp.vec2(rho, -c / (a[4] + wp.dot(grad_i, grad_i) + eps))


@wp.func
def record_worst(worst: wp.array(dtype=float), w: int, rho: float):
    """Raise world ``w``'s largest density error ρ/ρ0 − 1 this iteration (the atomic runs
    only when the record is beaten, so threads seldom contend)."""
    if rho - 1.0 > worst[w]:
        wp.atomic_max(worst, w, rho - 1.0)


@wp.kernel
def compute_lambda(
    sums: wp.array(dtype=vec5),
    p: wp.array(dtype=wp.vec3),
    wall: wp.array(dtype=vec5),
    wall_coef: float,
    h: float,
    w0: float,
    eps: float,
    world: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    spread: float,
    lam: wp.array(dtype=float),
    density: wp.array(dtype=float),
    worst: wp.array(dtype=float),
    scorr_mean: wp.array(dtype=float),
):
    """λ of every particle of an active world from its density sums (half lists; full lists
    compute it at the end of their density pass); clears the sums and records each world's
    largest density error (:func:`record_worst`). With ``spread`` below 1
    (``SolverConfig.bulk_scorr_spread``) ``scorr_mean`` holds Σ_j W_ij s_corr_ij on entry and
    the mean Σ_j W_ij s_corr_ij / Σ_j W_ij on return."""
    i = wp.tid()
    w = world[i]
    if active[w] == 0:
        return
    sums_i = sums[i]
    d = density_and_lambda(sums_i, h, w0, eps, wall[i], p[i], wall_coef)
    density[i] = d[0]
    lam[i] = d[1]
    if spread < 1.0:
        scorr_mean[i] = scorr_mean[i] / wp.max(sums_i[3], 1.0e-12)
    sums[i] = vec5(0.0)
    record_worst(worst, w, d[0])


SHARE_SLOPE = wp.constant(2.0)
"""How steeply a world's share of an extra iteration grows with its density error over the
tolerance: all of it at 1.5 × the tolerance (:func:`update_active`)."""

MIN_SHARE = wp.constant(0.05)
"""The least share of an extra iteration a world takes: below it (its density error within
2.5 % of the tolerance) the world is done for the step. Shares shrink with the error's excess,
so without a floor a world's error creeps toward the tolerance without crossing it, and the
world runs every extra iteration the cap allows at near-zero shares."""


@wp.kernel
def start_worlds(
    active: wp.array(dtype=wp.int32),
    share: wp.array(dtype=float),
    extra: wp.array(dtype=float),
):
    """Every world takes the whole of a step's first ``iterations`` density iterations."""
    w = wp.tid()
    active[w] = 1
    share[w] = 1.0
    extra[w] = 0.0


@wp.kernel
def update_active(
    worst: wp.array(dtype=float),
    tolerance: float,
    active: wp.array(dtype=wp.int32),
    share: wp.array(dtype=float),
    extra: wp.array(dtype=float),
    any_active: wp.array(dtype=wp.int32),
):
    """After an iteration: a world takes part in one more while its largest density error
    exceeds ``tolerance``, with a share of its correction that grows from 0 at the tolerance
    to all of it at 1.5 × the tolerance, so that the work a step does varies smoothly with the
    error (a whole iteration more or less would jolt the liquid). A world within tolerance
    stays done for the step, as does one whose share would fall below :data:`MIN_SHARE`.
    ``any_active`` is set (zero on entry) if some world goes on; ``extra`` sums each world's
    shares."""
    w = wp.tid()
    f = SHARE_SLOPE * (worst[w] - tolerance) / tolerance
    if active[w] != 0 and f >= MIN_SHARE:
        f = wp.min(f, 1.0)
        share[w] = f
        extra[w] = extra[w] + f
        any_active[0] = 1
    else:
        active[w] = 0


# ------------------------------------------------------------ pair passes (both list modes)


class PairKernels(NamedTuple):
    """The kernels that hash particles and walk neighbour lists, compiled for one list mode."""

    hash_particles: wp.Kernel
    build_neighbours: wp.Kernel
    density_sums: wp.Kernel
    compute_delta: wp.Kernel
    compute_delta_corrected: wp.Kernel  # SolverConfig.corrected_pressure
    vorticity_and_normals: wp.Kernel
    filter_sums: wp.Kernel
    gradient_moments: wp.Kernel


@wp.func
def mirrored(collider: int, plane: vec5) -> bool:
    """Whether a particle with this wall (:func:`predict`'s ``wall_collider`` and
    ``wall``) counts mirror images: a wall within h that does not curve away (κ = 0)."""
    return collider >= 0 and plane[4] <= 0.0


@wp.func
def mirror_moments(pi: wp.vec3, pj: wp.vec3, plane: vec5, h: float, grad_c: float):
    """The gradient moments at ``pi`` of ``pj``'s mirror image across ``plane`` (n, n · x
    − distance): the liquid the wall hides, seen as the reflection of the liquid in
    front of it. Zero for a ``pj`` behind the plane, which is there itself."""
    n = wp.vec3(plane[0], plane[1], plane[2])
    dj = wp.dot(n, pj) - plane[3]
    m = wp.mat33(0.0)
    if dj > 0.0:
        r = pi - (pj - n * (2.0 * dj))
        m = wp.outer(r, r) * -spiky_factor(wp.length(r), h, grad_c)
    return m


def pair_kernels(half: bool) -> PairKernels:
    """The pair kernels for half lists (``half``) or full lists; the mode is a compile-time
    constant (``wp.static``) so neither variant pays for the other's branches."""

    @wp.func
    def bucket_of(w: int, c: wp.vec3i, mask: int) -> int:
        if wp.static(half):
            return mixed_bucket(w, c, mask)
        else:
            return morton_bucket(w, c, mask)

    @wp.kernel
    def hash_particles(
        p: wp.array(dtype=wp.vec3),
        world: wp.array(dtype=wp.int32),
        inv_cell: float,
        mask: int,
        cell: wp.array(dtype=wp.vec3i),
        keys: wp.array(dtype=wp.int32),
        values: wp.array(dtype=wp.int32),
    ):
        """Cell and bucket key of every particle (sorted next)."""
        i = wp.tid()
        c = cell_of(p[i], inv_cell)
        cell[i] = c
        keys[i] = bucket_of(world[i], c, mask)
        values[i] = i

    @wp.func
    def scan_cell(
        i: int,
        pi: wp.vec3,
        wi: int,
        c: wp.vec3i,
        offset: int,
        sorted_idx: wp.array(dtype=wp.int32),
        p_sorted: wp.array(dtype=wp.vec3),
        world_sorted: wp.array(dtype=wp.int32),
        cell_sorted: wp.array(dtype=wp.vec3i),
        start: wp.array(dtype=wp.int32),
        end: wp.array(dtype=wp.int32),
        mask: int,
        h: float,
        max_nb: int,
        row_stride: int,
        col_stride: int,
        nbr: wp.array(dtype=wp.int32),
        count: int,
    ) -> int:
        """List particle i's neighbours in cell ``c`` (``offset`` from its own cell, > 0 for a
        forward cell); returns the new list length.

        A cell whose box lies farther than h from the particle is skipped without a look-up
        (about 6 of the 27 cells around a particle: corners and edges); the box is widened by
        0.1 % of h, so float rounding of the cell bounds never skips a neighbour."""
        n = count
        h2 = h * h
        lo = wp.vec3(float(c[0]), float(c[1]), float(c[2])) * h
        ex = wp.max(wp.max(lo[0] - pi[0], pi[0] - lo[0] - h), 0.0)
        ey = wp.max(wp.max(lo[1] - pi[1], pi[1] - lo[1] - h), 0.0)
        ez = wp.max(wp.max(lo[2] - pi[2], pi[2] - lo[2] - h), 0.0)
        if ex * ex + ey * ey + ez * ez >= h2 * 1.002:
            return n
        b = bucket_of(wi, c, mask)
        # while-loops compile to tighter CPU code than range() loops in Warp
        k = int(start[b])
        k_end = end[b]
        while k < k_end:
            r = pi - p_sorted[k]
            if wp.dot(r, r) < h2:
                j = sorted_idx[k]
                ck = cell_sorted[k]
                same_cell = ck[0] == c[0] and ck[1] == c[1] and ck[2] == c[2]
                forward = offset > 0 or j > i or (wp.static(not half) and j != i)
                if same_cell and forward and world_sorted[k] == wi:
                    if n < max_nb:
                        nbr[i * row_stride + n * col_stride] = j
                        n += 1
            k += 1
        return n

    @wp.kernel
    def build_neighbours(
        p: wp.array(dtype=wp.vec3),
        world: wp.array(dtype=wp.int32),
        cell: wp.array(dtype=wp.vec3i),
        sorted_idx: wp.array(dtype=wp.int32),
        p_sorted: wp.array(dtype=wp.vec3),
        world_sorted: wp.array(dtype=wp.int32),
        cell_sorted: wp.array(dtype=wp.vec3i),
        start: wp.array(dtype=wp.int32),
        end: wp.array(dtype=wp.int32),
        mask: int,
        h: float,
        max_nb: int,
        row_stride: int,
        first_cell: int,
        nbr: wp.array(dtype=wp.int32),
        nbr_count: wp.array(dtype=wp.int32),
    ):
        """Neighbour list of every particle, in a fixed (cell, index) order.

        ``half = 1``: only the 13 forward cells of the 27 around a particle's cell are scanned
        (and, in its own cell, higher indices), so each pair within h is found once.
        ``half = 0``: all 27 cells from ``first_cell`` (0; an argument, so that the loop is not
        unrolled), every neighbour. A candidate's cell and world are checked against the
        scanned ones (a bucket may hold several cells). A list longer than ``max_nb`` is cut.
        Entry c of particle i goes to ``nbr[i * row_stride + c * col_stride]``: (max_nb, 1)
        for half lists (packed afterwards), (1, particle count) for interleaved full lists.
        """
        col_stride = int(1)
        if wp.static(not half):
            col_stride = nbr_count.shape[0]
        if wp.static(half):
            # particles in their own (Morton, see order_keys) order: a CPU thread walks space
            # and its caches keep the cells it just scanned (bucket order is random here)
            i = wp.tid()
            pi = p[i]
            wi = world[i]
            ci = cell[i]
        else:
            # particles in bucket order: a GPU warp's particles share cells (the same loops, no
            # divergence between them) and their cells are neighbours (the same candidates)
            k = wp.tid()
            i = sorted_idx[k]
            pi = p_sorted[k]
            wi = world_sorted[k]
            ci = cell_sorted[k]
        count = int(0)
        if wp.static(half):
            # the 13 forward cells, unrolled: the tightest CPU code
            for dz in range(0, 2):
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        offset = dz * 9 + dy * 3 + dx
                        if offset >= 0:
                            count = scan_cell(
                                i, pi, wi, wp.vec3i(ci[0] + dx, ci[1] + dy, ci[2] + dz), offset,
                                sorted_idx, p_sorted, world_sorted, cell_sorted, start, end,
                                mask, h, max_nb, row_stride, col_stride, nbr, count,
                            )  # fmt: skip
        else:
            # all 27 cells, o = 9 (dz + 1) + 3 (dy + 1) + dx + 1, in a loop with a run-time
            # bound: unrolled, the kernel needs 93 registers a thread and a GPU runs it at a
            # quarter of its occupancy
            for o in range(first_cell, 27):
                c = wp.vec3i(ci[0] + o % 3 - 1, ci[1] + (o // 3) % 3 - 1, ci[2] + o // 9 - 1)
                count = scan_cell(
                    i, pi, wi, c, o - 13, sorted_idx, p_sorted, world_sorted, cell_sorted,
                    start, end, mask, h, max_nb, row_stride, col_stride, nbr, count,
                )  # fmt: skip
        nbr_count[i] = count

    @wp.kernel
    def density_sums(
        p: wp.array(dtype=wp.vec3),
        nbr: wp.array(dtype=wp.int32),
        nbr_start: wp.array(dtype=wp.int32),
        nbr_count: wp.array(dtype=wp.int32),
        stride: int,
        h: float,
        grad_c: float,
        scorr: wp.vec4,
        w0: float,
        eps: float,
        wall: wp.array(dtype=vec5),
        wall_coef: float,
        world: wp.array(dtype=wp.int32),
        active: wp.array(dtype=wp.int32),
        spread: float,
        sums: wp.array(dtype=vec5),
        pair: wp.array(dtype=wp.vec2),
        lam: wp.array(dtype=float),
        density: wp.array(dtype=float),
        worst: wp.array(dtype=float),
        scorr_mean: wp.array(dtype=float),
    ):
        """Pair sums of the density constraint: Σ_j ∇_i C, Σ_j W_ij and Σ_j |∇_j C|². Half lists
        add them to ``sums`` (zero on entry; :func:`compute_lambda` turns them into λ and clears
        them); full lists have each particle's whole sum in one thread and write its density
        and λ directly.

        With half lists each pair's gradient factor (∇W_ij = factor · r_ij) and tensile term
        s_corr (:func:`density_pair`) go to ``pair`` for :func:`compute_delta`. Particles of
        worlds no longer ``active`` (see :func:`update_active`) are skipped.

        With ``spread`` below 1 (``SolverConfig.bulk_scorr_spread``) the kernel-weighted sum of
        the particle's s_corr, Σ_j W_ij s_corr_ij, goes to ``scorr_mean`` (zero on entry with
        half lists; :func:`compute_lambda` divides it by Σ_j W_ij), full lists writing the mean.
        """
        i = wp.tid()
        if active[world[i]] == 0:
            return
        pi = p[i]
        acc = vec5(0.0)
        ws = float(0.0)  # Σ_j W_ij s_corr_ij, with spread below 1
        # while-loops compile to tighter CPU code than range() loops in Warp
        k = nbr_start[i]
        k_end = k + nbr_count[i] * stride
        if wp.static(not half):
            # four neighbours an iteration: their loads are independent, so a GPU thread has
            # four in flight instead of waiting for each (the tail is left to the loop below)
            while spread == 1.0 and k + 3 * stride < k_end:
                j0, j1 = nbr[k], nbr[k + stride]
                j2, j3 = nbr[k + 2 * stride], nbr[k + 3 * stride]
                r0, r1, r2, r3 = pi - p[j0], pi - p[j1], pi - p[j2], pi - p[j3]
                acc += density_term(r0, h, grad_c, scorr)
                acc += density_term(r1, h, grad_c, scorr)
                acc += density_term(r2, h, grad_c, scorr)
                acc += density_term(r3, h, grad_c, scorr)
                k += 4 * stride
        while k < k_end:
            j = nbr[k]
            r = pi - p[j]
            terms = density_pair(wp.dot(r, r), h, grad_c, scorr)
            w = terms[2]
            g = r * terms[0]  # ∇_i W_ij = −∇_j W_ij
            g2 = wp.dot(g, g)
            if wp.static(half):  # cached for compute_delta (full lists recompute them)
                pair[k] = wp.vec2(terms[0], terms[1])
            acc += vec5(g[0], g[1], g[2], w, g2)
            if wp.static(half):
                wp.atomic_add(sums, j, vec5(-g[0], -g[1], -g[2], w, g2))
            if spread < 1.0:
                ws += w * terms[1]
                if wp.static(half):
                    wp.atomic_add(scorr_mean, j, w * terms[1])
            k += stride
        if wp.static(half):
            wp.atomic_add(sums, i, acc)
            if spread < 1.0:
                wp.atomic_add(scorr_mean, i, ws)
        else:  # full lists: the sums are complete, so λ follows here (no compute_lambda)
            if spread < 1.0:
                scorr_mean[i] = ws / wp.max(acc[3], 1.0e-12)
            d = density_and_lambda(acc, h, w0, eps, wall[i], pi, wall_coef)
            density[i] = d[0]
            lam[i] = d[1]
            record_worst(worst, world[i], d[0])

    def delta_kernel(corrected: bool) -> wp.Kernel:
        """:func:`compute_delta`, with the pair terms corrected (``corrected``, a compile-time
        constant: the plain solve pays nothing for the option) or not."""

        @wp.kernel
        def compute_delta(
            p: wp.array(dtype=wp.vec3),
            nbr: wp.array(dtype=wp.int32),
            nbr_start: wp.array(dtype=wp.int32),
            nbr_count: wp.array(dtype=wp.int32),
            stride: int,
            lam: wp.array(dtype=float),
            density: wp.array(dtype=float),
            pair: wp.array(dtype=wp.vec2),
            h: float,
            grad_c: float,
            scorr: wp.vec4,
            band: float,
            world: wp.array(dtype=wp.int32),
            active: wp.array(dtype=wp.int32),
            corr: wp.array(dtype=wp.mat33),
            spread: float,
            scorr_mean: wp.array(dtype=float),
            delta: wp.array(dtype=wp.vec3),
        ):
            """Δp_i = Σ_j (λ_i + λ_j + s_corr) ∇W_ij (Jacobi), s_corr's offset weighted by the
            pair's share of a free surface (:func:`pair_lambda`, from ``density``: ρ/ρ0 of the
            same iteration); half lists read the pair terms cached by :func:`density_sums` and
            add each pair to both particles, full lists recompute them (``delta`` is zero on
            entry; :func:`apply_delta` clears it). Worlds no longer ``active`` are skipped.

            Corrected (``SolverConfig.corrected_pressure``), a pair's term is multiplied by the
            mean of its particles' matrices in ``corr`` (:func:`correction_matrices`), which
            keeps the two particles' terms opposite; the plain kernel does not read ``corr``.

            With ``spread`` below 1 (``SolverConfig.bulk_scorr_spread``) a pair's s_corr in the
            bulk keeps that share of its difference from its particles' means in
            ``scorr_mean`` (:func:`bulk_spread`)."""
            i = wp.tid()
            if active[world[i]] == 0:
                return
            pi = p[i]
            li = lam[i]
            di = density[i]
            koff = scorr[0] * scorr[3]
            dp = wp.vec3(0.0)
            k = nbr_start[i]
            k_end = k + nbr_count[i] * stride
            if wp.static(corrected):
                ci = corr[i]
            if wp.static(not half and not corrected):
                # four neighbours an iteration, as in density_sums
                while spread == 1.0 and k + 3 * stride < k_end:
                    j0, j1 = nbr[k], nbr[k + stride]
                    j2, j3 = nbr[k + 2 * stride], nbr[k + 3 * stride]
                    r0, r1, r2, r3 = pi - p[j0], pi - p[j1], pi - p[j2], pi - p[j3]
                    l0 = pair_lambda(li, lam[j0], di, density[j0], koff, band)
                    l1 = pair_lambda(li, lam[j1], di, density[j1], koff, band)
                    l2 = pair_lambda(li, lam[j2], di, density[j2], koff, band)
                    l3 = pair_lambda(li, lam[j3], di, density[j3], koff, band)
                    dp += delta_term(r0, l0, h, grad_c, scorr)
                    dp += delta_term(r1, l1, h, grad_c, scorr)
                    dp += delta_term(r2, l2, h, grad_c, scorr)
                    dp += delta_term(r3, l3, h, grad_c, scorr)
                    k += 4 * stride
            while k < k_end:
                j = nbr[k]
                r = pi - p[j]
                dj = density[j]
                lam_sum = pair_lambda(li, lam[j], di, dj, koff, band)
                t = wp.vec3(0.0)
                e = wp.vec2(0.0)
                if wp.static(half):
                    e = pair[k]
                else:
                    terms = density_pair(wp.dot(r, r), h, grad_c, scorr)
                    e = wp.vec2(terms[0], terms[1])
                if spread < 1.0:
                    mi, mj = scorr_mean[i], scorr_mean[j]
                    lam_sum -= bulk_spread(e[1], mi, mj, di, dj, band, spread)
                t = r * ((lam_sum + e[1]) * e[0])
                if wp.static(corrected):
                    t = 0.5 * ((ci + corr[j]) * t)
                dp += t
                if wp.static(half):
                    wp.atomic_sub(delta, j, t)
                k += stride
            if wp.static(half):
                wp.atomic_add(delta, i, dp)
            else:  # full lists: only this thread writes particle i
                delta[i] = dp

        return compute_delta

    @wp.kernel
    def vorticity_and_normals(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        nbr: wp.array(dtype=wp.int32),
        nbr_start: wp.array(dtype=wp.int32),
        nbr_count: wp.array(dtype=wp.int32),
        stride: int,
        h: float,
        grad_c: float,
        curl: int,
        omega: wp.array(dtype=wp.vec3),
        normal: wp.array(dtype=wp.vec3),
    ):
        """Curl of velocity ω_i = Σ_j (v_j − v_i) × ∇_j W_ij = Σ_j ∇_i W_ij × (v_j − v_i)
        (Macklin & Müller 2013, Eq. 15; only if ``curl``: it feeds vorticity confinement
        alone) and colour-field normal n_i = h Σ_j ∇_i W_ij / w0 (Akinci 2013), as pair sums
        (zero on entry; cleared by :func:`apply_filters`). A pair adds the same curl term to
        both of its particles."""
        i = wp.tid()
        xi = x[i]
        vi = v[i]
        om = wp.vec3(0.0)
        nn = wp.vec3(0.0)
        # while-loops compile to tighter CPU code than range() loops in Warp
        k = nbr_start[i]
        k_end = k + nbr_count[i] * stride
        while k < k_end:
            j = nbr[k]
            r = xi - x[j]
            g = spiky_grad(r, wp.length(r), h, grad_c)  # ∇_i W_ij
            nn += g
            if wp.static(half):
                wp.atomic_sub(normal, j, g * h)
            if curl != 0:
                c = wp.cross(g, v[j] - vi)
                om += c
                if wp.static(half):
                    wp.atomic_add(omega, j, c)
            k += stride
        if wp.static(half):
            wp.atomic_add(omega, i, om)
            wp.atomic_add(normal, i, nn * h)
        else:  # full lists: only this thread writes particle i
            omega[i] = om
            normal[i] = nn * h

    @wp.kernel
    def filter_sums(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        omega: wp.array(dtype=wp.vec3),
        normal: wp.array(dtype=wp.vec3),
        nbr: wp.array(dtype=wp.int32),
        nbr_start: wp.array(dtype=wp.int32),
        nbr_count: wp.array(dtype=wp.int32),
        stride: int,
        world: wp.array(dtype=wp.int32),
        vorticity: wp.array(dtype=float),
        cohesion: wp.array(dtype=float),
        surface_tension: wp.array(dtype=float),
        friction_frac: wp.array(dtype=float),
        h: float,
        grad_c: float,
        spacing: float,
        dt: float,
        coh_accel: float,
        st_accel: float,
        coh_norm: float,
        curv_norm: float,
        vsum: wp.array(dtype=wp.vec4),
        eta: wp.array(dtype=wp.vec3),
        dv_sum: wp.array(dtype=wp.vec3),
    ):
        """Pair sums of the velocity filters (zero on entry; cleared by :func:`apply_filters`).

        ``vsum``: Σ_j W_ij v_j (xyz) and Σ_j W_ij (w) for XSPH viscosity; ``eta``: ∇|ω| for
        vorticity confinement; ``dv_sum``: the velocity change of cohesion, surface tension
        (curvature) and particle friction, whose pair terms are antisymmetric.

        FleX's coefficients are dimensionless; pourbench maps them onto rates as documented in
        :mod:`pourbench.fluids.solver` (``SolverConfig.viscosity_rate`` etc.), the same for every
        world.
        """
        i = wp.tid()
        w = world[i]
        vort_on = vorticity[w] > 0.0
        kc = cohesion[w] * coh_accel * dt / coh_norm
        ks = surface_tension[w] * st_accel * dt / curv_norm
        kf = friction_frac[w]
        xi = x[i]
        vi = v[i]
        ni = normal[i]
        om_i = wp.length(omega[i])
        acc_v = wp.vec4(0.0)
        acc_eta = wp.vec3(0.0)
        acc_dv = wp.vec3(0.0)
        # while-loops compile to tighter CPU code than range() loops in Warp
        k = nbr_start[i]
        k_end = k + nbr_count[i] * stride
        if wp.static(not half):  # four neighbours an iteration, as in density_sums
            while k + 3 * stride < k_end:
                j0, j1 = nbr[k], nbr[k + stride]
                j2, j3 = nbr[k + 2 * stride], nbr[k + 3 * stride]
                x0, x1, x2, x3 = x[j0], x[j1], x[j2], x[j3]
                v0, v1, v2, v3 = v[j0], v[j1], v[j2], v[j3]
                n0, n1, n2, n3 = normal[j0], normal[j1], normal[j2], normal[j3]
                o0, o1, o2, o3 = float(0.0), float(0.0), float(0.0), float(0.0)
                if vort_on:
                    o0, o1 = wp.length(omega[j0]), wp.length(omega[j1])
                    o2, o3 = wp.length(omega[j2]), wp.length(omega[j3])
                a0, e0, f0 = filter_pair(
                    xi - x0, vi, v0, ni, n0, om_i, o0, vort_on, h, grad_c, spacing, kc, ks, kf
                )
                a1, e1, f1 = filter_pair(
                    xi - x1, vi, v1, ni, n1, om_i, o1, vort_on, h, grad_c, spacing, kc, ks, kf
                )
                a2, e2, f2 = filter_pair(
                    xi - x2, vi, v2, ni, n2, om_i, o2, vort_on, h, grad_c, spacing, kc, ks, kf
                )
                a3, e3, f3 = filter_pair(
                    xi - x3, vi, v3, ni, n3, om_i, o3, vort_on, h, grad_c, spacing, kc, ks, kf
                )
                # left to right: the same order of additions as one neighbour at a time
                acc_v = acc_v + a0 + a1 + a2 + a3
                acc_eta = acc_eta + e0 + e1 + e2 + e3
                acc_dv = acc_dv + f0 + f1 + f2 + f3
                k += 4 * stride
        while k < k_end:
            j = nbr[k]
            om_j = float(0.0)
            if vort_on:
                om_j = wp.length(omega[j])
            a, e, f = filter_pair(
                xi - x[j], vi, v[j], ni, normal[j], om_i, om_j, vort_on, h, grad_c, spacing,
                kc, ks, kf,
            )  # fmt: skip
            acc_v += a
            acc_dv += f
            if vort_on:
                acc_eta += e
                if wp.static(half):
                    wp.atomic_add(eta, j, e)  # η's pair term is the same for both particles
            if wp.static(half):  # j's side: W_ij v_i and the opposite dv
                wp.atomic_add(vsum, j, wp.vec4(vi[0] * a[3], vi[1] * a[3], vi[2] * a[3], a[3]))
                wp.atomic_sub(dv_sum, j, f)
            k += stride
        if wp.static(half):
            wp.atomic_add(vsum, i, acc_v)
            wp.atomic_add(eta, i, acc_eta)
            wp.atomic_add(dv_sum, i, acc_dv)
        else:  # full lists: only this thread writes particle i
            vsum[i] = acc_v
            eta[i] = acc_eta
            dv_sum[i] = acc_dv

    @wp.kernel
    def gradient_moments(
        p: wp.array(dtype=wp.vec3),
        nbr: wp.array(dtype=wp.int32),
        nbr_start: wp.array(dtype=wp.int32),
        nbr_count: wp.array(dtype=wp.int32),
        stride: int,
        wall: wp.array(dtype=vec5),
        wall_collider: wp.array(dtype=wp.int32),
        h: float,
        grad_c: float,
        corr: wp.array(dtype=wp.mat33),
    ):
        """Second moment of each particle's kernel gradients, M_i = −Σ_j ∇_i W_ij ⊗ r_ij
        (r_ij = p_i − p_j; symmetric, positive definite with three or more neighbours out of
        a plane), in the units of the density constraint's gradients.

        A particle with a container's wall or a box within h (``wall_collider`` ≥ 0, the
        wall's mean curvature κ = 0) also counts the mirror images of itself and of its
        neighbours across its wall's plane (``wall``): ghost particles that fill the
        half-space behind the plane as the liquid in front of it is packed, so a wall reads
        as liquid continued in the same layers. Where the solid is not that half-space (an
        inner corner, a second collider) and beside spheres and capsules (κ > 0),
        :func:`solid_moments` adds the solid after. A pair's term is the same for both
        particles; half lists add it, and the other particle's mirror term, to both
        (``corr`` zero on entry)."""
        i = wp.tid()
        pi = p[i]
        plane_i = wall[i]
        walled_i = mirrored(wall_collider[i], plane_i)
        acc = wp.mat33(0.0)
        if walled_i:
            acc += mirror_moments(pi, pi, plane_i, h, grad_c)
        k = nbr_start[i]
        k_end = k + nbr_count[i] * stride
        while k < k_end:
            j = nbr[k]
            pj = p[j]
            r = pi - pj
            m = wp.outer(r, r) * -spiky_factor(wp.length(r), h, grad_c)
            acc += m
            if walled_i:
                acc += mirror_moments(pi, pj, plane_i, h, grad_c)
            if wp.static(half):
                plane_j = wall[j]
                if mirrored(wall_collider[j], plane_j):
                    m += mirror_moments(pj, pi, plane_j, h, grad_c)
                wp.atomic_add(corr, j, m)
            k += stride
        if wp.static(half):
            wp.atomic_add(corr, i, acc)
        else:  # full lists: only this thread writes particle i
            corr[i] = acc

    return PairKernels(
        hash_particles,
        build_neighbours,
        density_sums,
        delta_kernel(False),
        delta_kernel(True),
        vorticity_and_normals,
        filter_sums,
        gradient_moments,
    )


HALF_LISTS = pair_kernels(True)
FULL_LISTS = pair_kernels(False)

CORRECTION_MIN_RATIO = wp.constant(0.3)
"""det(M) / (tr(M)/3)³ below which a particle's gradient moments are too one-sided to invert
(a particle of a thin sheet or a drop): its correction matrix is the identity."""


@wp.kernel
def correction_matrices(corr: wp.array(dtype=wp.mat33)):
    """Each particle's gradient moments M (:func:`gradient_moments`) become its correction
    matrix tr(M)/3 · M⁻¹: the inverse that makes Σ_j (M⁻¹ ∇_i W_ij) ⊗ r_ji the identity
    (Bonet & Lok 1999), scaled to unit mean eigenvalue so that it corrects the direction of a
    particle's constraint gradients and leaves their size (and the Jacobi step) as it was.
    The identity where M is nearly singular (:data:`CORRECTION_MIN_RATIO`)."""
    i = wp.tid()
    m = corr[i]
    t = (m[0, 0] + m[1, 1] + m[2, 2]) / 3.0
    if t <= 0.0 or wp.determinant(m) < CORRECTION_MIN_RATIO * t * t * t:
        corr[i] = wp.identity(n=3, dtype=float)
    else:
        corr[i] = wp.inverse(m) * t


# ------------------------------------------------------------------------ collider SDFs


@wp.func
def sd_box(q: wp.vec3, he: wp.vec3) -> wp.vec4:
    """Signed distance and outward normal of a box of half-extents ``he``."""
    d = wp.vec3(wp.abs(q[0]) - he[0], wp.abs(q[1]) - he[1], wp.abs(q[2]) - he[2])
    outside = wp.vec3(wp.max(d[0], 0.0), wp.max(d[1], 0.0), wp.max(d[2], 0.0))
    lo = wp.length(outside)
    if lo > 0.0:
        n = wp.vec3(
            wp.sign(q[0]) * outside[0], wp.sign(q[1]) * outside[1], wp.sign(q[2]) * outside[2]
        )
        n = n / lo
        return wp.vec4(lo, n[0], n[1], n[2])
    # inside: nearest face
    if d[0] >= d[1] and d[0] >= d[2]:
        return wp.vec4(d[0], wp.sign(q[0]), 0.0, 0.0)
    if d[1] >= d[2]:
        return wp.vec4(d[1], 0.0, wp.sign(q[1]), 0.0)
    return wp.vec4(d[2], 0.0, 0.0, wp.sign(q[2]))


@wp.func
def sd_segment(q: wp.vec3, a: wp.vec3, b: wp.vec3, radius: float) -> wp.vec4:
    ab = b - a
    t = wp.clamp(wp.dot(q - a, ab) / wp.max(wp.dot(ab, ab), 1.0e-12), 0.0, 1.0)
    r = q - (a + ab * t)
    d = wp.length(r)
    n = wp.vec3(0.0, 0.0, 1.0)
    if d > 1.0e-9:
        n = r / d
    return wp.vec4(d - radius, n[0], n[1], n[2])


@wp.func
def sd_revolved(q: wp.vec3, params: wp.array(dtype=float), start: int, count: int) -> wp.vec4:
    """Thin wall of thickness params[start] around a revolved (ρ, z) polyline."""
    wall = params[start]
    rho = wp.sqrt(q[0] * q[0] + q[1] * q[1])
    best = float(1.0e10)
    best_dr = float(0.0)
    best_dz = float(1.0)
    npts = (count - 1) / 2
    for k in range(npts - 1):
        ar = params[start + 1 + 2 * k]
        az = params[start + 2 + 2 * k]
        br = params[start + 3 + 2 * k]
        bz = params[start + 4 + 2 * k]
        er = br - ar
        ez = bz - az
        t = wp.clamp(((rho - ar) * er + (q[2] - az) * ez) / (er * er + ez * ez), 0.0, 1.0)
        dr = rho - (ar + t * er)
        dz = q[2] - (az + t * ez)
        dd = dr * dr + dz * dz
        if dd < best:
            best = dd
            best_dr = dr
            best_dz = dz
    d = wp.sqrt(best)
    nr = float(0.0)
    nz = float(1.0)
    if d > 1.0e-9:
        nr = best_dr / d
        nz = best_dz / d
    ux = float(1.0)
    uy = float(0.0)
    if rho > 1.0e-9:
        ux = q[0] / rho
        uy = q[1] / rho
    return wp.vec4(d - 0.5 * wall, nr * ux, nr * uy, nz)


@wp.func
def sd_box_shell(q: wp.vec3, params: wp.array(dtype=float), start: int) -> wp.vec4:
    """Open (params[start+4] = 0) or closed box with walls of params[start]."""
    wall = params[start]
    hx = params[start + 1]
    hy = params[start + 2]
    depth = params[start + 3]
    closed = params[start + 4]
    outer = sd_box(
        q - wp.vec3(0.0, 0.0, 0.5 * depth + wall * (0.5 + 0.5 * closed)),
        wp.vec3(hx + wall, hy + wall, 0.5 * depth + wall * (0.5 + 0.5 * closed)),
    )
    cav_half = depth * (1.0 - 0.5 * closed)
    cav = sd_box(q - wp.vec3(0.0, 0.0, wall + cav_half), wp.vec3(hx, hy, cav_half))
    if outer[0] >= -cav[0]:
        return outer
    return wp.vec4(-cav[0], -cav[1], -cav[2], -cav[3])


@wp.func
def collider_sdf(
    kind: int,
    params: wp.array(dtype=float),
    start: int,
    count: int,
    mesh: wp.uint64,
    q: wp.vec3,
) -> wp.vec4:
    """(signed distance, outward normal) of collider ``kind`` at local point ``q``."""
    if kind == PLANE:
        return wp.vec4(q[2], 0.0, 0.0, 1.0)
    if kind == BOX:
        return sd_box(q, wp.vec3(params[start], params[start + 1], params[start + 2]))
    if kind == SPHERE:
        d = wp.length(q)
        n = wp.vec3(0.0, 0.0, 1.0)
        if d > 1.0e-9:
            n = q / d
        return wp.vec4(d - params[start], n[0], n[1], n[2])
    if kind == CAPSULE:
        hl = params[start + 1]
        return sd_segment(q, wp.vec3(0.0, 0.0, -hl), wp.vec3(0.0, 0.0, hl), params[start])
    if kind == CYLINDER:
        rad = params[start]
        hl = params[start + 1]
        rho = wp.sqrt(q[0] * q[0] + q[1] * q[1])
        ux = float(1.0)
        uy = float(0.0)
        if rho > 1.0e-9:
            ux = q[0] / rho
            uy = q[1] / rho
        dr = rho - rad
        dz = wp.abs(q[2]) - hl
        if dr > 0.0 and dz > 0.0:
            l = wp.sqrt(dr * dr + dz * dz)
            return wp.vec4(l, ux * dr / l, uy * dr / l, wp.sign(q[2]) * dz / l)
        if dr > dz:
            return wp.vec4(dr, ux, uy, 0.0)
        return wp.vec4(dz, 0.0, 0.0, wp.sign(q[2]))
    if kind == MESH:
        # winding-number sign: robust at edges and corners, where the nearest face's normal
        # (wp.mesh_query_point_sign_normal) can put an outside point inside
        query = wp.mesh_query_point_sign_winding_number(mesh, q, 1.0e6)
        if query.result:
            cp = wp.mesh_eval_position(mesh, query.face, query.u, query.v)
            r = q - cp
            d = wp.length(r)
            n = wp.mesh_eval_face_normal(mesh, query.face)
            if d > 1.0e-9:
                n = r * (query.sign / d)
            return wp.vec4(d * query.sign, n[0], n[1], n[2])
        return wp.vec4(1.0e10, 0.0, 0.0, 1.0)
    if kind == REVOLVED:
        return sd_revolved(q, params, start, count)
    return sd_box_shell(q, params, start)


# --------------------------------------------------------------------------- collisions


@wp.struct
class Colliders:
    """Every world's colliders, grouped by world (world w owns ``world_start[w]`` up to
    ``world_end[w]``), and the liquid's reaction summed per body slot."""

    world_start: wp.array(dtype=wp.int32)
    world_end: wp.array(dtype=wp.int32)
    kind: wp.array(dtype=wp.int32)
    start: wp.array(dtype=wp.int32)  # first of its parameters in ``params``
    count: wp.array(dtype=wp.int32)
    mesh: wp.array(dtype=wp.uint64)
    params: wp.array(dtype=float)
    pose_prev: wp.array(dtype=wp.transform)  # at the start of the step
    pose: wp.array(dtype=wp.transform)  # at its end
    body: wp.array(dtype=wp.int32)  # reaction slot, or −1
    com: wp.array(dtype=wp.vec3)  # the body's centre of mass, world frame
    bound: wp.array(dtype=float)  # radius about the local origin that holds the shape
    force: wp.array2d(dtype=wp.int64)  # per slot, in WRENCH_UNIT
    torque: wp.array2d(dtype=wp.int64)


@wp.func
def sdf_of(cols: Colliders, c: int, q: wp.vec3) -> wp.vec4:
    """(signed distance, outward normal) of collider ``c`` at its local point ``q``."""
    return collider_sdf(cols.kind[c], cols.params, cols.start[c], cols.count[c], cols.mesh[c], q)


CLEAR_MARGIN = wp.constant(1.0e-6)
"""m kept between a particle's clearance bound and a skipped collider test, far above the
float rounding of a local point (~1e-8 m a metre from the origin)."""


NO_WALL = wp.constant(vec5(0.0, 0.0, 1.0, -1.0e6, 0.0))
"""Wall plane of a particle with no collider within h: a million metres away."""


CURVATURE_STEP = wp.constant(0.05)
"""Finite-difference step of :func:`wall_curvature`, in kernel radii h."""


@wp.func
def wall_curvature(cols: Colliders, c: int, q: wp.vec3, d: float, h: float) -> float:
    """Mean curvature κ (1/m, > 0 convex) of a smooth collider ``c`` (a sphere or a capsule)
    at the point nearest to its local point ``q``, ``d`` from it (the SDF there), for
    :func:`wall_sum`.

    The SDF's Laplacian L (the divergence of its normal, by central differences over
    :data:`CURVATURE_STEP` · h) is 2κ/(1 + κd) at distance d from a sphere of curvature κ,
    so κ = L/(2 − L d): exact beside a sphere, within κd of the mean curvature beside a
    capsule's cylinder. A step across the SDF's medial axis (a particle pushed deep inside)
    reads no curvature, and κ is clamped to [−1/(2h), 2/h], the range of :func:`wall_sum`."""
    e = CURVATURE_STEP * h
    ex = wp.vec3(e, 0.0, 0.0)
    ey = wp.vec3(0.0, e, 0.0)
    ez = wp.vec3(0.0, 0.0, e)
    lap = sdf_of(cols, c, q + ex)[1] - sdf_of(cols, c, q - ex)[1]
    lap += sdf_of(cols, c, q + ey)[2] - sdf_of(cols, c, q - ey)[2]
    lap += sdf_of(cols, c, q + ez)[3] - sdf_of(cols, c, q - ez)[3]
    lap = lap / (2.0 * e)
    hi = 2.0 / h
    if lap < -2.0 / h:  # the normal flipped: a step crossed a medial axis, not a cavity
        return 0.0
    den = 2.0 - lap * wp.max(d, 0.0)
    if den <= 0.0:  # beyond the sphere of curvature hi at this distance
        return hi
    return wp.clamp(lap / den, -0.5 / h, hi)


# --------------------------------------------------------------------------- step 1: predict


@wp.kernel
def predict(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    world: wp.array(dtype=wp.int32),
    damping: wp.array(dtype=float),
    gravity: wp.vec3,
    dt: float,
    cols: Colliders,
    radius: float,
    h: float,
    x_prev: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    clear: wp.array(dtype=float),
    wall: wp.array(dtype=vec5),
    wall_collider: wp.array(dtype=wp.int32),
):
    """Velocity and predicted position x* under gravity and damping, and at x*:

    - ``clear``: how far the particle can move before it comes within ``radius`` of a
      collider of its world (end-of-step poses): the least signed distance minus ``radius``,
      or the distance to the bounding sphere of a collider out of reach. Every collider SDF
      here is 1-Lipschitz (exact distances, or the maximum of two for box shells), so after
      moves of total length L the particle is still at least ``clear`` − L clear: while that
      stays above :data:`CLEAR_MARGIN` the collider passes skip its SDFs without changing
      any result.
    - ``wall``, ``wall_collider``: the nearest collider surface within h, as the plane
      (n, n · x* − distance) tangent to it with the surface's mean curvature κ there, and its
      index (−1 and :data:`NO_WALL` if none): the wall term of the density constraint
      (:func:`density_and_lambda`). κ is read for spheres and capsules
      (:func:`wall_curvature`); shapes with edges (boxes, cylinders, meshes, container
      shells) keep κ = 0, the half-space, since a sphere does not describe the solid at an
      edge (docs/contact.md)."""
    i = wp.tid()
    w = world[i]
    vi = (v[i] + gravity * dt) * (1.0 / (1.0 + damping[w] * dt))
    v[i] = vi
    x_prev[i] = x[i]
    pi = x[i] + vi * dt
    p[i] = pi
    room = float(1.0e10)
    nearest = float(h)
    plane = NO_WALL
    index = int(-1)
    q_near = wp.vec3(0.0)
    sd_near = wp.vec4(0.0)
    for c in range(cols.world_start[w], cols.world_end[w]):
        q = wp.transform_point(wp.transform_inverse(cols.pose[c]), pi)
        gap = wp.length(q) - cols.bound[c]
        if gap < h:
            sd = sdf_of(cols, c, q)
            room = wp.min(room, sd[0] - radius)
            if sd[0] < nearest:
                nearest = sd[0]
                index = c
                q_near = q
                sd_near = sd
        else:
            room = wp.min(room, gap - radius)
    if index >= 0:
        n = wp.transform_vector(cols.pose[index], wp.vec3(sd_near[1], sd_near[2], sd_near[3]))
        kappa = float(0.0)
        kind = cols.kind[index]
        if kind == SPHERE or kind == CAPSULE:
            kappa = wall_curvature(cols, index, q_near, sd_near[0], h)
        plane = vec5(n[0], n[1], n[2], wp.dot(n, pi) - sd_near[0], kappa)
    clear[i] = room
    wall[i] = plane
    wall_collider[i] = index


@wp.func
def site_share(cols: Colliders, w: int, site: wp.vec3, spacing: float) -> float:
    """The solid's share of a lattice site at ``site``: clamp(1/2 − sd/s, 0, 1), sd the least
    signed distance of world ``w``'s colliders (a collider whose bounding sphere lies a
    spacing or more away is skipped: it adds nothing)."""
    sd = float(1.0e10)
    for k in range(cols.world_start[w], cols.world_end[w]):
        q = wp.transform_point(wp.transform_inverse(cols.pose[k]), site)
        if wp.length(q) - cols.bound[k] < spacing:
            sd = wp.min(sd, sdf_of(cols, k, q)[0])
    return wp.clamp(0.5 - sd / spacing, 0.0, 1.0)


@wp.kernel
def solid_moments(
    p: wp.array(dtype=wp.vec3),
    world: wp.array(dtype=wp.int32),
    wall: wp.array(dtype=vec5),
    wall_collider: wp.array(dtype=wp.int32),
    cols: Colliders,
    sites: wp.array(dtype=vec5),
    reach: float,
    spacing: float,
    h: float,
    grad_c: float,
    corr: wp.array(dtype=wp.mat33),
):
    """Add to the gradient moments of each particle with a collider within h
    (:func:`gradient_moments`) those of the solid its wall's mirror images miss, counted as
    rest liquid on a cubic lattice of the liquid's spacing s.

    The lattice is centred on the particle and turned to its wall's plane (normal n, the
    particle a distance d in front of it); each site within h has a solid share φ =
    clamp(1/2 − sd/s, 0, 1) (:func:`site_share`) and a plane share φₙ, the same with the
    site's distance to the plane, so each share changes continuously as the particle moves.
    Beside a container wall or a box (κ = 0), where the mirror images stand for the
    half-space behind the plane, a site with φ > φₙ is solid in front of the plane, an inner
    corner's second wall or a second collider: it counts φ − φₙ, at itself and at its mirror
    image across the plane (whose ghost the liquid there cannot supply). A flat wall adds
    nothing here, and behind the plane the half-space stands: container walls are shells
    thinner than h whose signed distance grows again past their mid-surface, where no liquid
    reaches (at a box's outer edge the half-space counts too much). Beside a sphere or a
    capsule (κ > 0), which curves away from its tangent plane within h, no mirror images
    are counted and each site counts φ. Why mirror images, and not the lattice sites or the
    density constraint's continuous half-space (:func:`wall_sum`), for container walls:
    docs/viscosity.md, "Shear cell".

    Only colliders whose signed distance at the particle is under ``reach`` (the farthest
    site's distance plus s/2) can give a site a share (a signed distance is 1-Lipschitz), and
    a site farther than its collider's distance at the particle less s/2 has none, so each
    particle evaluates the colliders it borders once, and at a site only those: up to two,
    in their own frames (more than two fall back to :func:`site_share` over the world's
    colliders). ``sites``: :func:`pourbench.fluids.step.lattice_sites`."""
    i = wp.tid()
    if wall_collider[i] < 0:
        return
    pi = p[i]
    w = world[i]
    # the colliders this particle borders: index, its local point, its rotation, sd there
    k1 = int(-1)
    k2 = int(-1)
    near = int(0)
    q1 = wp.vec3(0.0)
    q2 = wp.vec3(0.0)
    rot1 = wp.quat_identity()
    rot2 = wp.quat_identity()
    sd_near = float(1.0e10)
    for k in range(cols.world_start[w], cols.world_end[w]):
        q = wp.transform_point(wp.transform_inverse(cols.pose[k]), pi)
        if wp.length(q) - cols.bound[k] < reach:
            sd = sdf_of(cols, k, q)[0]
            if sd < reach:
                near += 1
                sd_near = wp.min(sd_near, sd)
                if k1 < 0:
                    k1 = k
                    q1 = q
                    rot1 = wp.transform_get_rotation(cols.pose[k])
                else:
                    k2 = k
                    q2 = q
                    rot2 = wp.transform_get_rotation(cols.pose[k])
    if near == 0:
        return
    n = wp.vec3(wall[i][0], wall[i][1], wall[i][2])
    axis = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(n[0]) > 0.6:
        axis = wp.vec3(0.0, 1.0, 0.0)
    t1 = wp.normalize(wp.cross(n, axis))
    t2 = wp.cross(n, t1)
    # the lattice's axes, times s, in each near collider's frame
    a1 = wp.quat_rotate_inv(rot1, t1) * spacing
    b1 = wp.quat_rotate_inv(rot1, t2) * spacing
    c1 = wp.quat_rotate_inv(rot1, n) * spacing
    a2 = wp.quat_rotate_inv(rot2, t1) * spacing
    b2 = wp.quat_rotate_inv(rot2, t2) * spacing
    c2 = wp.quat_rotate_inv(rot2, n) * spacing
    d = wp.dot(n, pi) - wall[i][3]  # the particle's distance to its wall's plane
    convex = not mirrored(wall_collider[i], wall[i])  # a sphere's or capsule's surface
    acc = wp.mat33(0.0)  # in the lattice's frame (t1, t2, n)
    for j in range(sites.shape[0]):
        site = sites[j]
        e = wp.vec3(site[0], site[1], site[2])
        plane_share = wp.clamp(0.5 - (d - e[2] * spacing) / spacing, 0.0, 1.0)
        # a site with a share lies within sd_near + s/2 (1-Lipschitz); one wholly behind a
        # container wall's plane adds nothing to its mirror images
        if sd_near - site[3] < 0.5 * spacing and (convex or plane_share < 1.0):
            share = float(0.0)
            if near > 2:
                r = (t1 * e[0] + t2 * e[1] + n * e[2]) * spacing
                share = site_share(cols, w, pi - r, spacing)
            else:
                sd = sdf_of(cols, k1, q1 - (a1 * e[0] + b1 * e[1] + c1 * e[2]))[0]
                if k2 >= 0:
                    sd = wp.min(sd, sdf_of(cols, k2, q2 - (a2 * e[0] + b2 * e[1] + c2 * e[2]))[0])
                share = wp.clamp(0.5 - sd / spacing, 0.0, 1.0)
            extra = share
            if not convex:
                extra = wp.max(share - plane_share, 0.0)
            if extra > 0.0:
                acc += wp.outer(e, e) * (site[4] * extra)
                if not convex:  # and at the site's mirror image across the plane
                    m = wp.vec3(e[0], e[1], 2.0 * d / spacing - e[2])
                    weight = -spiky_factor(wp.length(m) * spacing, h, grad_c) * spacing * spacing
                    acc += wp.outer(m, m) * (weight * extra)
    frame = wp.matrix_from_cols(t1, t2, n)
    acc = frame * acc * wp.transpose(frame)
    corr[i] = corr[i] + acc


WRENCH_UNIT = wp.constant(1.0e-9)
"""Body reactions are summed as integers of this many N (and N·m): integer sums do not
depend on the order in which threads add, so coupled runs are reproducible on CUDA too."""


@wp.func
def add_fixed(total: wp.array2d(dtype=wp.int64), body: int, value: wp.vec3):
    for k in range(3):
        wp.atomic_add(total, body, k, wp.int64(wp.round(value[k] / WRENCH_UNIT)))


@wp.func
def add_reaction(cols: Colliders, c: int, corr: wp.vec3, point: wp.vec3, m: float, dt: float):
    """Sum the reaction of collider ``c``'s correction ``corr`` (m) of a particle now at
    ``point`` on its body: −m Δx / dt², with its torque about the body's centre of mass, in
    units of ``WRENCH_UNIT``. Bodies with slot −1 take no reaction."""
    body = cols.body[c]
    if body >= 0:
        f = corr * (-m / (dt * dt))
        add_fixed(cols.force, body, f)
        add_fixed(cols.torque, body, wp.cross(point - cols.com[c], f))


@wp.func
def sweep(cols: Colliders, c: int, a: wp.vec3, b: wp.vec3, radius: float):
    """A particle's move from ``a`` to ``b`` (collider ``c``'s frame), stopped where it first
    comes near a surface; the sliding part of the rest of the move is swept the same way (up
    to three contacts, then the particle stays at the last). Returns the end point and 1 if
    the move touched (0: ``b`` unchanged).

    Sphere tracing against the level min(``radius``, start distance) / 2: a particle that
    starts in contact with one wall and slides along it still stops at the next wall, and a
    wall of any thickness is never crossed. A start deeper inside than ``radius`` is not
    traced (the projection pushes it out). A move shorter than its start's distance to the
    level costs one SDF evaluation."""
    hit = int(0)
    q = b
    start = a
    end = b
    for _contact in range(3):
        seg = end - start
        seg_len = wp.length(seg)
        s = sdf_of(cols, c, start)
        if s[0] <= -radius or seg_len <= 1.0e-9:
            q = end
            break
        level = 0.5 * wp.min(radius, wp.abs(s[0]))
        t = float(0.0)
        touched = int(0)
        for _it in range(24):
            gap = s[0] - level
            if gap <= 1.0e-5:
                touched = 1
                pt = start + seg * t
                na = wp.vec3(s[1], s[2], s[3])
                rest = end - pt  # only the sliding part of the remaining motion goes on
                start = pt
                end = pt + rest - na * wp.min(wp.dot(rest, na), 0.0)
                q = pt
                break
            t = t + gap / seg_len
            if t >= 1.0:
                break
            s = sdf_of(cols, c, start + seg * t)
        if touched == 0:
            q = end
            break
        hit = 1
    return q, hit


@wp.kernel
def apply_delta(
    p: wp.array(dtype=wp.vec3),
    delta: wp.array(dtype=wp.vec3),
    sor: float,
    world: wp.array(dtype=wp.int32),
    cols: Colliders,
    mass: wp.array(dtype=float),
    radius: float,
    dt: float,
    lam: wp.array(dtype=float),
    wall: wp.array(dtype=vec5),
    wall_collider: wp.array(dtype=wp.int32),
    wall_coef: float,
    h: float,
    w0: float,
    active: wp.array(dtype=wp.int32),
    share: wp.array(dtype=float),
    push: wp.array(dtype=float),
    clear: wp.array(dtype=float),
):
    """End of a Jacobi iteration: p += sor · (Δp + λ_i ∇_i C_wall), the wall's share of the
    density constraint (:func:`density_and_lambda`) pushing the particle off its nearest
    collider, whose body takes the reaction (``delta`` cleared for the next one); then
    projection out of colliders, reactions summed per body.

    The normal push-out distance is accumulated in ``push``: it is the normal impulse (times
    dt/m) that Coulomb friction in :func:`collide` scales with. A particle whose clearance
    (``clear``, see :func:`predict`) outlasts its move skips the colliders; otherwise the
    clearance is measured again (negative after a projection, so the next pass looks again).
    Worlds no longer ``active`` are skipped; in an extra iteration a world moves by its
    ``share`` of the correction (see :func:`update_active`).
    """
    i = wp.tid()
    w = world[i]
    if active[w] == 0:  # the world's density is within tolerance (see update_active)
        return
    sor = sor * share[w]
    p0 = p[i]
    pi = p0 + delta[i] * sor
    delta[i] = wp.vec3(0.0)
    wc = wall_collider[i]
    li = lam[i]
    if wc >= 0 and li < 0.0:  # λ = 0 (not compressed): no push, and no reaction to sum
        wl = wall[i]
        ws = wall_sum(wall_distance(wl, p0), wl[4], h, wall_coef)
        push_off = wp.vec3(wl[0], wl[1], wl[2]) * (sor * li * ws[1] / w0)
        pi = pi + push_off
        add_reaction(cols, wc, push_off, pi, mass[w], dt)
    clear0 = clear[i]
    move = wp.length(pi - p0)
    room = clear0 - move
    if room > CLEAR_MARGIN:  # no collider within reach
        clear[i] = room
        p[i] = pi
        return
    room = float(1.0e10)
    for c in range(cols.world_start[w], cols.world_end[w]):
        tf = cols.pose[c]
        tf_inv = wp.transform_inverse(tf)
        b = wp.transform_point(tf_inv, pi)
        lq = wp.length(b)
        if lq > cols.bound[c] + radius + move:
            room = wp.min(room, lq - cols.bound[c] - radius)
            continue  # the move stays out of the collider's bounding sphere: no contact
        # swept from the iteration's start, so that a large correction never crosses a wall;
        # a move shorter than the clearance (at p0, a lower bound on every collider's distance
        # less the radius) plus half a radius cannot reach the sweep's level: not traced
        q = b
        hit = int(0)
        if move > clear0 + 0.5 * radius - 2.0e-5:
            q, hit = sweep(cols, c, wp.transform_point(tf_inv, p0), b, radius)
        s = sdf_of(cols, c, q)
        room = wp.min(room, s[0] - radius)
        if s[0] < radius or hit == 1:
            pen = wp.max(radius - s[0], 0.0)
            push[i] = push[i] + pen
            q = q + wp.vec3(s[1], s[2], s[3]) * pen
            # the correction, not the position, goes back to the world frame (see collide)
            new_p = pi + wp.transform_vector(tf, q - b)
            add_reaction(cols, c, new_p - pi, new_p, mass[w], dt)
            pi = new_p
    clear[i] = room
    p[i] = pi


@wp.func
def hold(
    q: wp.vec3,
    a: wp.vec3,
    n: wp.vec3,
    pen: float,
    push: float,
    adhesive_grip: float,
    static_friction: float,
    dynamic_friction: float,
    pull: float,
) -> wp.vec3:
    """A surface's hold on a particle at ``q`` (moved from ``a`` this step; collider frame,
    outward normal ``n``): Coulomb friction on the motion relative to the collider (Macklin
    et al. 2014, Eq. 24) with grip ``pen`` + the density push + adhesion's, then ``pull``
    (m) toward the surface (adhesion)."""
    dx = q - a
    dt_tan = dx - n * wp.dot(dx, n)
    lt = wp.length(dt_tan)
    grip = pen + push + adhesive_grip
    if lt > 0.0:
        if lt < static_friction * grip:
            q = q - dt_tan
        else:
            q = q - dt_tan * wp.min(dynamic_friction * grip / lt, 1.0)
    return q - n * pull


@wp.kernel
def collide(
    p: wp.array(dtype=wp.vec3),
    x_prev: wp.array(dtype=wp.vec3),
    world: wp.array(dtype=wp.int32),
    cols: Colliders,
    mass: wp.array(dtype=float),
    static_friction: wp.array(dtype=float),
    dynamic_friction: wp.array(dtype=float),
    adhesion_grip: wp.array(dtype=float),
    radius: float,
    adhesion_range: float,
    adhesion_frac: wp.array(dtype=float),
    dt: float,
    clear: wp.array(dtype=float),
    push: wp.array(dtype=float),
    contacts: wp.array(dtype=wp.int32),
):
    """Swept collision against every collider of the particle's world, with friction.

    The particle's motion is followed in each collider's own frame, from its start-of-step
    position (collider at its start-of-step pose) to its predicted position (collider at its
    end pose), by sphere tracing; the first touch stops the normal motion. So a thin wall is
    never crossed, whatever the speeds. Position corrections, converted to forces
    (m Δx / dt²), are summed per body as the liquid's reaction on it.

    ``clear`` bounds the end point's distance to every collider (:func:`predict`): where
    it exceeds the local path's length plus the adhesion band, nothing on the path comes
    near the collider, and its SDFs are skipped.

    A particle in contact gets friction from each collider it touches. A particle within
    the adhesion band of a surface without touching it is held (adhesion, and the grip it
    adds to friction) only by its nearest collider, as the density constraint's wall term
    counts only the nearest wall: a solid behind the wall it rests on (the table under a
    tray's bottom) does not reach through that wall.
    """
    i = wp.tid()
    w = world[i]
    pi = p[i]
    m = mass[w]
    n_contacts = int(0)
    band = wp.max(adhesion_range, 2.0e-5)  # > the trace's tolerance
    room = clear[i]
    pressed = int(0)  # in contact with some collider
    band_c = int(-1)  # the nearest collider whose band holds the particle without contact
    band_s = float(1.0e30)
    for c in range(cols.world_start[w], cols.world_end[w]):
        tf = cols.pose[c]
        tf_inv = wp.transform_inverse(tf)
        a = wp.transform_point(wp.transform_inverse(cols.pose_prev[c]), x_prev[i])
        b = wp.transform_point(tf_inv, pi)
        seg = b - a
        seg_len = wp.length(seg)
        if room - seg_len > band + CLEAR_MARGIN:
            continue  # 1-Lipschitz SDF: every point of the path is clear of the band
        # the swept motion stays out of the collider's bounding sphere (and adhesion band):
        # no contact possible, skip its SDF
        t_near = wp.clamp(-wp.dot(a, seg) / wp.max(wp.dot(seg, seg), 1.0e-20), 0.0, 1.0)
        if wp.length(a + seg * t_near) > cols.bound[c] + radius + band:
            continue
        q, hit = sweep(cols, c, a, b, radius)
        touched = hit
        s = sdf_of(cols, c, q)
        if s[0] < radius + adhesion_range:
            pen = radius - s[0]
            if pen > -1.0e-6:
                n_contacts += 1
            if pen > 0.0:
                touched = 1
                pressed = 1
                n = wp.vec3(s[1], s[2], s[3])
                q = hold(q + n * pen, a, n, pen, push[i], adhesion_grip[w],
                         static_friction[w], dynamic_friction[w], 0.0)  # fmt: skip
            elif s[0] < band_s:
                band_c = c
                band_s = s[0]
        if touched == 1:
            # only the correction q − b goes back to the world frame: a position's round
            # trip through a rotated frame is scaled by |quat|⁴ (1 ± ~1e-7 in float32), and
            # with v = Δx / dt that bias, repeated every projection, accelerated a particle
            # resting on a tilted plane 1 m from the plane's origin at 0.04 m/s² toward it
            new_p = pi + wp.transform_vector(tf, q - b)
            add_reaction(cols, c, new_p - pi, new_p, m, dt)
            pi = new_p
            room = -1.0  # the particle moved: its clearance no longer holds
    if band_c >= 0 and pressed == 0:
        # in the band of its nearest collider and touching none: friction with adhesion's
        # grip, and adhesion pulls it back toward the surface
        tf = cols.pose[band_c]
        a = wp.transform_point(wp.transform_inverse(cols.pose_prev[band_c]), x_prev[i])
        b = wp.transform_point(wp.transform_inverse(tf), pi)
        s = sdf_of(cols, band_c, b)
        gap = s[0] - radius  # ≥ 0 but for the rounding of the frame change
        if gap < adhesion_range:
            q = hold(b, a, wp.vec3(s[1], s[2], s[3]), wp.max(-gap, 0.0), push[i],
                     adhesion_grip[w], static_friction[w], dynamic_friction[w],
                     wp.max(gap, 0.0) * adhesion_frac[w])  # fmt: skip
            new_p = pi + wp.transform_vector(tf, q - b)
            add_reaction(cols, band_c, new_p - pi, new_p, m, dt)
            pi = new_p
    p[i] = pi
    contacts[i] = n_contacts


# ----------------------------------------------------- step 4: velocity and its filters


@wp.kernel
def update_velocity(
    p: wp.array(dtype=wp.vec3),
    x_prev: wp.array(dtype=wp.vec3),
    contacts: wp.array(dtype=wp.int32),
    world: wp.array(dtype=wp.int32),
    dissipation: wp.array(dtype=float),
    sleep: float,
    dt: float,
    up: wp.vec3,
    v: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    top: wp.array(dtype=float),
    bottom: wp.array(dtype=float),
):
    """v = (x* − x)/dt, damped by shape contacts (``dissipation``), then x = x*; a particle
    slower than ``sleep`` (FleX's sleepThreshold, 0: off) stays where it started, at rest.
    ``top`` and ``bottom`` keep the greatest and least height (along ``up``) each world's
    liquid has reached."""
    i = wp.tid()
    w = world[i]
    vi = (p[i] - x_prev[i]) / dt
    vi = vi / (1.0 + dissipation[w] * float(contacts[i]) * dt)
    if sleep > 0.0 and wp.length(vi) < sleep:
        v[i] = wp.vec3(0.0)
        x[i] = x_prev[i]
    else:
        v[i] = vi
        x[i] = p[i]
    height = wp.dot(up, x[i])
    if height > top[w]:  # rarely true: the atomics are seldom reached
        wp.atomic_max(top, w, height)
    if height < bottom[w]:
        wp.atomic_min(bottom, w, height)


@wp.kernel
def apply_filters(
    world: wp.array(dtype=wp.int32),
    viscosity_frac: wp.array(dtype=float),
    vorticity: wp.array(dtype=float),
    dt: float,
    h: float,
    vsum: wp.array(dtype=wp.vec4),
    eta: wp.array(dtype=wp.vec3),
    dv_sum: wp.array(dtype=wp.vec3),
    omega: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
):
    """XSPH viscosity, vorticity confinement, cohesion, surface tension and particle friction
    from the pair sums; clears the sums for the next step."""
    i = wp.tid()
    w = world[i]
    vi = v[i]
    dv = dv_sum[i]
    a = vsum[i]
    if a[3] > 0.0:
        # XSPH: relax toward the kernel-weighted neighbour mean (PBFSolver.step_fractions)
        dv += (wp.vec3(a[0], a[1], a[2]) / a[3] - vi) * viscosity_frac[w]
    e = eta[i]
    if vorticity[w] > 0.0:
        # confinement force along N × ω, N = η / |η|; where |η| is below 1 % of |ω|/h (the
        # vortex's core, or a symmetric neighbourhood) N is scaled down instead, so that
        # rounding noise in a vanishing gradient cannot choose the force's direction
        om = omega[i]
        scale = wp.max(wp.length(e), wp.max(0.01 * wp.length(om) / h, 1.0e-20))
        dv += wp.cross(e / scale, om) * (vorticity[w] * dt)
    v[i] = vi + dv
    vsum[i] = wp.vec4(0.0)
    eta[i] = wp.vec3(0.0)
    dv_sum[i] = wp.vec3(0.0)
    omega[i] = wp.vec3(0.0)
    normal[i] = wp.vec3(0.0)


@wp.kernel
def query_sdf(
    kind: int,
    params: wp.array(dtype=float),
    count: int,
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec4),
):
    """Signed distance and normal of one collider at local points (for checks and tools)."""
    i = wp.tid()
    out[i] = collider_sdf(kind, params, 0, count, mesh, points[i])


@wp.kernel
def copy_state(
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    x_dst[i] = x_src[i]
    v_dst[i] = v_src[i]


@wp.kernel
def flag_diverged(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    from_start: int,
    inv_dt: float,
    world: wp.array(dtype=wp.int32),
    up: wp.vec3,
    g: float,
    top: wp.array(dtype=float),
    bottom: wp.array(dtype=float),
    wall_speed: wp.array(dtype=float),
    runaway: float,
    rest_energy: float,
    max_speed: float,
    flags: wp.array(dtype=wp.int32),
):
    """Flag the world of a particle that is not finite, 100 m out, faster than ``max_speed``
    or carrying more energy per unit mass than its scene can give
    (:meth:`~pourbench.fluids.solver.PBFSolver.diverged`). ``v`` holds the velocities, or
    with ``from_start`` the step's start positions (velocity = (x − v) · inv_dt)."""
    i = wp.tid()
    p = x[i]
    u = v[i]
    if from_start != 0:
        u = (p - u) * inv_dt
    w = world[i]
    finite = bool(True)
    for k in range(3):
        if not wp.isfinite(p[k]) or not wp.isfinite(u[k]):
            finite = False
    speed2 = wp.dot(u, u)
    scene = g * (top[w] - bottom[w]) + 2.0 * wall_speed[w] * wall_speed[w]
    energy = 0.5 * speed2 + g * (wp.dot(p, up) - bottom[w])
    far = wp.max(wp.max(wp.abs(p[0]), wp.abs(p[1])), wp.abs(p[2])) > 100.0
    fast = speed2 > max_speed * max_speed
    if not finite or fast or energy > runaway * scene + rest_energy or far:
        wp.atomic_max(flags, w, 1)
