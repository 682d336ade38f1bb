"""Solver settings (:class:`SolverConfig`) and the constants the density constraint derives
from them: rest sums, the wall term's coefficient, the s_corr offset, surface-force norms."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_finite, check_int


@dataclass(frozen=True)
class SolverConfig:
    """Solver settings (SI units). Defaults suit cups of a few cm holding 50–300 g.

    Attributes:
        spacing: particle rest spacing, m (particle mass = density × spacing³).
        dt: time step, s.
        iterations: Jacobi density iterations every world takes each step.
        max_density_error: after those, a world iterates on while its largest density error
            (ρ/ρ0 − 1 of any particle, measured in the last iteration) exceeds this, up to
            ``max_iterations`` in all. A fixed count leaves a column compressed in proportion
            to its depth (Jacobi spreads a correction a kernel radius an iteration), so deep
            liquid takes more iterations and a shallow cup none (docs/contact.md).
        max_iterations: cap on a world's density iterations in a step (``iterations`` turns the
            extra iterations off).
        smoothing: kernel radius h as a multiple of ``spacing``.
        relaxation: constraint-force mixing ε as a fraction of a full neighbourhood's Σ|∇C|².
        rest_packing: the kernel sum of a particle in the settled liquid at number density
            1/spacing³, as a fraction of the sum in a cubic lattice of ``spacing``; the rest
            "density" of the constraint is the lattice sum times this. A settled liquid is
            disordered, and a disordered packing reaches the lattice's kernel sum only when
            it is denser, so this is below 1, set so that settled water holds its density in
            the bulk (:func:`pourbench.fluids.validation.rest_in_cup`, docs/rest.md).
        scorr_k, scorr_n, scorr_dq: tensile-instability term s_corr = −k (W(r)/W(Δq))^n,
            with Δq = scorr_dq × h, offset at free surfaces so that it does not push a flat
            surface outward (:func:`scorr_offset`, docs/contact.md).
        bulk_scorr_spread: the share of s_corr's pair-to-pair variation kept in the bulk
            (at rest density or denser): a pair's term there is its two particles'
            kernel-weighted mean s_corr plus this share of the pair's own difference from it.
            1 (the default) is Macklin & Müller's term. The steep variation is what calms a
            settled packing and also what makes it resist shear like a packed solid: lower,
            a sheared liquid carries less stress at zero rate and a settling sphere falls
            faster, and a settled liquid jitters more (docs/viscosity.md, "The bulk's
            tensile term").
        max_neighbours: capacity of a particle's neighbour list (full lists: all its
            neighbours; half lists: the pairs it owns). At rest density a particle has about
            33 neighbours within h, at the foot of a collapsing 25 cm column (the bench's dam
            break at 128k particles) up to 71; 96 leaves headroom. Pairs beyond the capacity
            are dropped with a warning. Memory only: 96 costs no time on the CPU.
        pair_lists: ``"half"`` (each pair listed once, its terms added to both particles:
            half the work, the CPU default) or ``"full"`` (every particle lists all its
            neighbours and sums its own side: no atomics between threads, so CUDA runs are
            reproducible; the CUDA default); ``"auto"`` picks by device.
        sor: over/under-relaxation factor applied to each Jacobi position correction. Jacobi
            overshoots: at 1.0 a settled liquid keeps a jitter of a few cm/s that never
            decays; at 0.7 it comes to rest at the price of slightly more compression.
        reorder_every: steps between spatial re-sorts of the particle arrays (0: never).
            Particle order inside a world therefore changes over time.
        graph: record each part of a step (:mod:`pourbench.fluids.step`) once as a graph (CUDA
            graphs, or Warp's CPU capture) and replay it, re-recorded when the scene changes: no
            Python and no argument packing per launch, the same kernels in the same order. On a
            CUDA device without Warp's memory pool the step is launched kernel by kernel.
        viscosity_tolerance: the implicit viscosity solve of a world with a dynamic viscosity
            (``LiquidProfile.viscosity_pa_s``) stops when its residual is at most this
            fraction of its right-hand side (:mod:`pourbench.fluids.viscosity`).
        viscosity_max_iterations: cap on that solve's conjugate-gradient iterations a step.
        min_viscous_diffusion: a world whose liquid's viscous diffusion number ν dt / h² (ν
            = μ / ρ, h the kernel radius) is below this takes no implicit viscosity solve:
            at that resolution the liquid's viscous layer over a step is far thinner than a
            particle, so the liquid is inviscid on the particles and XSPH alone smooths it.
            0 (the default) solves every liquid with a physical viscosity; Pour-v0 sets 1e-3,
            which leaves water, ink and milk (3–7e-5 at its resolution) to XSPH and solves
            oil (2e-3) and the thicker liquids (docs/performance.md).
        plug_viscosity_pa_s: the most viscous a liquid with a Herschel–Bulkley law gets, Pa·s:
            where its shear rate is too low to yield, the law's τ / γ̇ is capped at this, so
            an unyielded region is a very viscous liquid that creeps at τ / this
            (:mod:`pourbench.fluids.rheology`).
        viscous_displacement: the implicit viscosity solve also moves each particle by dt
            times the velocity it changed, so that a step's displacement is the solved
            velocity's: the viscous force enters the position update implicitly, as gravity
            does. Off, the position update precedes the solve and a liquid that its viscosity
            holds still moves by g dt² a step: viscous pours then depend on the step and a
            resting viscous liquid keeps a jitter of mm/s (docs/viscosity.md).
        corrected_pressure: multiply each pair's density correction by the mean of its two
            particles' gradient-correction matrices (tr(M)/3 M⁻¹, M the second moment of the
            particle's kernel gradients, the solid behind its nearest wall counted as the
            mirror image of the liquid in front of it; Bonet & Lok 1999), so that a
            correction that pushes every particle alike is isotropic whatever the
            arrangement of its neighbours. A
            packing sheared under pressure then no longer resists with a stress in
            proportion to the pressure (docs/viscosity.md, "Shear cell"). The mean keeps a
            pair's two terms opposite, so momentum is kept.
        shear_passes: solves a step takes for a liquid with a Herschel–Bulkley law, each
            taking the particles' viscosities from the velocities the last returned (Picard
            passes; the first takes them from the velocities to be solved).
        laplacian_packing: the settled liquid's pair sum of the viscous Laplacian's kernel
            second moment (Σ_j V g_ij r_ij², :mod:`pourbench.fluids.viscosity`) as a fraction of
            the continuum's; the pair terms are divided by it (measured on settled water,
            docs/viscosity.md).
        viscosity_rate: κ of the XSPH mapping (dimensionless, per unit FleX viscosity): each
            step of ``calibration_dt`` relaxes a velocity toward its neighbours' kernel mean by
            a = κν / (1 + κν); other steps use 1 − (1 − a)^(dt / calibration_dt), the same
            relaxation per second.
        xsph_viscosity: the FleX viscosity coefficient XSPH uses for a liquid with a physical
            viscosity (``LiquidProfile.viscosity_pa_s``): a light smoothing of particle noise,
            Table 6.2 water's 0.01, the same for every such liquid, while the implicit solve
            applies the viscosity itself. A liquid without one is smoothed by its own FleX
            coefficient, as in FleX.
        calibration_dt: the step at which the per-step fractions (XSPH viscosity, particle
            friction, adhesion) were calibrated against the validation experiments; they are
            rescaled to other steps so that a liquid behaves the same at any dt
            (:meth:`PBFSolver.step_fractions`).
        cohesion_accel, surface_tension_accel: acceleration per unit coefficient, m/s².
        adhesion_gain: fraction of the gap closed per step of ``calibration_dt`` per unit
            FleX adhesion (the spring it makes is kept at other steps, see
            :meth:`PBFSolver.step_fractions`).
        max_speed: speed above which a world is flagged as diverged in any scene, m/s
            (:meth:`PBFSolver.diverged` flags slower runaways by a bound from the scene).
        sleep_threshold: FleX's ``sleepThreshold``, m/s: a particle whose step ends slower
            than this does not move that step (it keeps its start position, its velocity is
            zeroed before the velocity filters). 0 (FleX's default) turns it off; what it does
            to settling and to the viscous pours is measured in docs/rest.md.
        gravity: m/s².
        device: ``"cpu"`` or ``"cuda"`` (or ``"cuda:N"``).
    """

    spacing: float = 0.005
    dt: float = 1.0 / 240.0
    iterations: int = 4
    max_density_error: float = 0.015
    max_iterations: int = 64
    smoothing: float = 2.0
    relaxation: float = 0.01
    rest_packing: float = 0.99
    scorr_k: float = 0.1
    scorr_n: float = 4.0
    scorr_dq: float = 0.2
    bulk_scorr_spread: float = 1.0
    max_neighbours: int = 96
    pair_lists: str = "auto"
    sor: float = 0.7
    reorder_every: int = 16
    graph: bool = True
    viscosity_tolerance: float = 1.0e-3
    viscosity_max_iterations: int = 100
    min_viscous_diffusion: float = 0.0
    plug_viscosity_pa_s: float = 1000.0
    shear_passes: int = 2
    viscous_displacement: bool = True
    corrected_pressure: bool = False
    laplacian_packing: float = 0.897
    viscosity_rate: float = 1.0
    xsph_viscosity: float = 0.01
    calibration_dt: float = 1.0 / 240.0
    cohesion_accel: float = 100.0
    surface_tension_accel: float = 100.0
    adhesion_gain: float = 10.0
    max_speed: float = 20.0
    sleep_threshold: float = 0.0
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    device: str = "cpu"

    def __post_init__(self) -> None:
        for name in (
            *("spacing", "dt", "smoothing", "max_speed", "calibration_dt", "rest_packing"),
            *("laplacian_packing", "sor", "viscosity_tolerance", "plug_viscosity_pa_s"),
        ):
            check_finite(name, getattr(self, name), minimum=1e-9)
        if self.smoothing <= 1.0:
            raise InvalidParameterError(
                f"smoothing must be > 1 (h wider than a spacing), got {self.smoothing!r}"
            )
        if not 0.0 <= check_finite("scorr_dq", self.scorr_dq) < 1.0:
            raise InvalidParameterError(f"scorr_dq must be in [0, 1) (of h), got {self.scorr_dq!r}")
        if not 0.0 <= check_finite("bulk_scorr_spread", self.bulk_scorr_spread) <= 1.0:
            raise InvalidParameterError(
                f"bulk_scorr_spread must be in [0, 1], got {self.bulk_scorr_spread!r}"
            )
        for name in (
            *("relaxation", "scorr_k", "scorr_n", "viscosity_rate", "xsph_viscosity"),
            *("sleep_threshold", "cohesion_accel", "surface_tension_accel", "adhesion_gain"),
            "max_density_error",
            "min_viscous_diffusion",
        ):
            check_finite(name, getattr(self, name), minimum=0.0)
        check_int("viscosity_max_iterations", self.viscosity_max_iterations, minimum=1)
        check_int("shear_passes", self.shear_passes, minimum=1)
        for name, minimum in (("iterations", 1), ("max_neighbours", 1), ("reorder_every", 0)):
            check_int(name, getattr(self, name), minimum=minimum)
        check_int("max_iterations", self.max_iterations, minimum=self.iterations)
        if self.pair_lists not in ("auto", "half", "full"):
            raise InvalidParameterError(
                f"pair_lists must be 'auto', 'half' or 'full', got {self.pair_lists!r}"
            )
        for name in ("graph", "viscous_displacement", "corrected_pressure"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidParameterError(
                    f"{name} must be True or False, got {getattr(self, name)!r}"
                )
        try:
            gravity = tuple(self.gravity)
        except TypeError:
            gravity = ()
        if len(gravity) != 3:
            raise InvalidParameterError(f"gravity must be 3 numbers (m/s²), got {self.gravity!r}")
        for axis, value in zip("xyz", gravity, strict=True):
            check_finite(f"gravity {axis}", value)
        if not isinstance(self.device, str) or not re.fullmatch(r"cpu|cuda(:\d+)?", self.device):
            raise InvalidParameterError(
                f"device must be 'cpu', 'cuda' or 'cuda:N', got {self.device!r}"
            )

    @property
    def h(self) -> float:
        """Kernel (smoothing) radius, m."""
        return self.smoothing * self.spacing

    @property
    def radius(self) -> float:
        """Particle collision radius, m."""
        return 0.5 * self.spacing

    @property
    def adhesion_range(self) -> float:
        """Band beyond contact within which adhesion holds a particle, m (half a spacing)."""
        return 0.5 * self.spacing


@dataclass(frozen=True)
class DensityConstants:
    """What the density constraint and the surface forces derive from a :class:`SolverConfig`.

    Attributes:
        w0, grad_c: the rest sums (:func:`rest_sums`).
        eps: constraint-force mixing ε, ``relaxation`` × the full neighbourhood's Σ|∇C|², 1/m².
        wall_coef: the wall term's coefficient (:func:`wall_coef`).
        scorr: the tensile term's (k, n, (h² − Δq²)³, offset c). λ carries units of m² here
            (C is dimensionless, ∇C is 1/m), so Macklin & Müller's dimensionless k is scaled by
            the rest neighbourhood's 1/Σ|∇C|²; c is :func:`scorr_offset`.
        surface_band: 1 − ρ/ρ0 of a particle in a flat free surface
            (:func:`flat_surface_density`).
        coh_norm, curv_norm: :func:`surface_norms`.
        lattice_neighbours: neighbours within h of a particle in a full cubic lattice.
    """

    w0: float
    grad_c: float
    eps: float
    wall_coef: float
    scorr: tuple[float, float, float, float]
    surface_band: float
    coh_norm: float
    curv_norm: float
    lattice_neighbours: int

    @classmethod
    def from_config(cls, cfg: SolverConfig) -> DensityConstants:
        w0, grad_c, sum_grad2 = rest_sums(cfg)
        dq = cfg.scorr_dq * cfg.h
        coh_norm, curv_norm = surface_norms(cfg, grad_c)
        dist = np.linalg.norm(lattice(cfg), axis=1)
        return cls(
            w0=w0,
            grad_c=grad_c,
            eps=cfg.relaxation * sum_grad2,
            wall_coef=wall_coef(cfg),
            scorr=(
                cfg.scorr_k / sum_grad2,
                cfg.scorr_n,
                (cfg.h**2 - dq * dq) ** 3,
                scorr_offset(cfg),
            ),
            surface_band=1.0 - flat_surface_density(cfg),
            coh_norm=coh_norm,
            curv_norm=curv_norm,
            lattice_neighbours=int(np.count_nonzero((dist > 0) & (dist < cfg.h))),
        )


def rest_sums(cfg: SolverConfig) -> tuple[float, float, float]:
    """Rest sums of the density constraint, from a particle in a full cubic lattice of
    ``spacing`` (the kernel sum scaled by ``rest_packing``).

    Returns:
        w0: rest_packing × Σ (h − r)³ (the spiky sum without its constant), m³.
        grad_c: spiky-gradient constant −45/(π h⁶) divided by the rest density in kernel
            units, so ``spiky_grad(..., grad_c)`` is ∇C directly, 1/m⁴ · m.
        sum_grad2: Σ|∇C|² of the full neighbourhood, 1/m².
    """
    h = cfg.h
    r = lattice(cfg)
    dist = np.linalg.norm(r, axis=1)
    w0 = cfg.rest_packing * float(np.where(dist < h, (h - dist) ** 3, 0.0).sum())
    grad_c = -3.0 / w0  # d/dr of (h − r)³, over the rest sum
    with np.errstate(invalid="ignore", divide="ignore"):
        coef = np.where((dist < h) & (dist > 0), grad_c * (h - dist) ** 2 / dist, 0.0)
    grads = r * coef[:, None]
    sum_grad2 = float((grads**2).sum() + (grads.sum(0) ** 2).sum())
    return w0, grad_c, sum_grad2


def wall_coef(cfg: SolverConfig) -> float:
    """``coef`` of :func:`pourbench.fluids.kernels.wall_sum`: a particle at s/2 from a wall
    in a cubic lattice of spacing s misses the lattice points mirrored beyond the wall; their
    kernel sum over the continuum's a⁵ (h/20 − a/30) at a = h − s/2, times ``rest_packing``
    (as the rest sum w0). About 0.76 × 2π/s³ at h = 2s: the continuum counts neighbours
    closer than a lattice holds them."""
    h, s = cfg.h, cfg.spacing
    n = math.ceil(h / s)
    g = np.arange(-n, n + 1) * s
    beyond = -(np.arange(n) + 1.0) * s  # mirror layers at s, 2s, ... from the particle
    x, y, z = np.meshgrid(g, g, beyond, indexing="ij")
    dist = np.sqrt(x**2 + y**2 + z**2)
    mirror = float(np.where(dist < h, (h - dist) ** 3, 0.0).sum())
    a = h - s / 2
    return cfg.rest_packing * mirror / (a**5 * (h / 20 - a / 30))


def lattice(cfg: SolverConfig) -> np.ndarray:
    """Offsets (m) of a cubic lattice of ``spacing`` around a particle at the origin, out to
    at least h along each axis (the origin included)."""
    n = math.ceil(cfg.h / cfg.spacing)
    g = np.arange(-n, n + 1) * cfg.spacing
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)


def flat_surface_density(cfg: SolverConfig) -> float:
    """ρ/ρ0 of a particle in the flat top face of a cubic lattice (spiky kernel sums)."""
    pts = lattice(cfg)
    w = np.clip(cfg.h - np.linalg.norm(pts, axis=1), 0.0, None) ** 3
    return float(w[pts[:, 2] <= 0].sum() / w.sum())


def scorr_offset(cfg: SolverConfig) -> float:
    """The offset c of the tensile term s_corr = −k ((W(r)/W(Δq))^n − c) that a pair in a free
    surface takes in full (:func:`pourbench.fluids.kernels.pair_lambda`): the mean of
    (W(r)/W(Δq))^n over a cubic lattice's half-space below a particle, weighted by each
    neighbour's ∇W along the surface normal. With it s_corr exerts no net force on a particle
    in a flat free surface (Macklin & Müller's term, c = 0, pushes it outward, and with the
    unilateral density constraint nothing pulls it back: a free drop flies apart); the term
    still pushes pairs closer than about a spacing apart and pulls wider ones together."""
    h = cfg.h
    pts = lattice(cfg)
    below = pts[pts[:, 2] < 0]
    r = np.linalg.norm(below, axis=1)
    ok = r < h
    r, z = r[ok], -below[ok, 2]
    dq = cfg.scorr_dq * h
    ratio = (h * h - r * r) ** 3 / (h * h - dq * dq) ** 3
    weight = z * (h - r) ** 2 / r  # the spiky gradient's component along the normal
    return float(np.sum(ratio**cfg.scorr_n * weight) / np.sum(weight))


def surface_norms(cfg: SolverConfig, grad_c: float) -> tuple[float, float]:
    """Magnitudes of the cohesion and curvature sums of a particle on a flat lattice surface.

    Dividing by them makes FleX's cohesion / surface-tension coefficients fractions of
    ``cohesion_accel`` / ``surface_tension_accel`` at a flat free surface, at any spacing.
    """
    h = cfg.h
    below = lattice(cfg)
    below = below[below[:, 2] <= 0]  # half-space lattice; the particle sits at the origin
    dist = np.linalg.norm(below, axis=1)
    ok = (dist > 0) & (dist < h)
    r = dist[ok]
    spline = np.where(
        2 * r > h,
        64 * (h - r) ** 3 * r**3 / h**6,
        64 * (2 * (h - r) ** 3 * r**3 - h**6 / 64) / h**6,
    )
    coh = np.linalg.norm((below[ok] / r[:, None] * spline[:, None]).sum(0))
    grads = -below[ok] * (grad_c * (h - r) ** 2 / r)[:, None]
    # a surface particle's normal against (nearly normal-free) neighbours below it
    curv = h * np.linalg.norm(grads.sum(0)) * np.count_nonzero(below[ok][:, 2] < 0)
    return float(coh), float(curv)
