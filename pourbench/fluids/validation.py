"""Physical validation experiments of the liquid solver, shared by the tests and the bench.

Each function runs one experiment on the CPU (or ``device``) and returns the measured
quantities; ``tests/test_fluids_physics.py`` asserts them against physical expectations and
``pourbench bench fluids`` reports them beside the thesis' and the literature's numbers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.special import jn_zeros

from pourbench.errors import InvalidParameterError
from pourbench.fluids.config import SolverConfig
from pourbench.fluids.coupling import MujocoCoupling
from pourbench.fluids.falling_ball import terminal_speed
from pourbench.fluids.params import LiquidProfile, liquid_profile
from pourbench.fluids.scenarios import GRAVITY, tilt_schedule, two_cup_scene
from pourbench.fluids.solver import PBFSolver
from pourbench.geometry.shapes import BoxShell, cup

# Martin & Moyce (1952), n² = 2 (column height 2a, width a): surge-front position Z = x/a at
# T = t·sqrt(2g/a), interpolated from their tabulated measurements.
MARTIN_MOYCE = {1.0: 1.33, 2.0: 2.36, 3.0: 3.70}

VISCOUS_ORDER = ("water", "ink", "oil", "glycerine", "honey", "ketchup")
"""Table 6.2's liquids in order of viscosity (physical, and FleX's) and adhesion."""


REST_FILLS_G = (190.0, 200.0, 210.0)
"""Water fills of the rest experiment. A settling liquid is chaotic: one fill's speeds at one
instant swing by 2× with a gram more or less, so the statistics pool nearby fills and a
window of time."""

REST_WINDOW_S = (0.9, 1.1)

REST_LATE_WINDOW_S = (2.9, 3.1)
"""The same fills two seconds later: a settled liquid must come to rest, not keep a jitter."""


@dataclass(frozen=True)
class RestResult:
    """Water left in a cup (one world per fill of ``REST_FILLS_G``), sampled over a window
    (``solver``: the run, at the end of its last window)."""

    density_error: float  # largest mean |ρ/ρ0 − 1| over the bulk of a world at a sample
    max_speed: float  # m/s, fastest particle of any world at any sample
    median_max_speed: float  # m/s, median over (world, sample) of the fastest particle
    p99_speed: float  # m/s, 99th percentile of all particle speeds at all samples
    bulk_density: float  # kg/m^3, mean particle mass per volume in a probe inside the bulk
    solver: PBFSolver
    masses_g: tuple[float, ...]  # the fills, one world each
    fastest: np.ndarray  # m/s, (sample, world): the fastest particle of a world at a sample

    def typical_fastest(self, mass_g: float) -> float:
        """m/s: the fastest particle of the fill of ``mass_g`` at the median sample (what one
        instant in the window shows; its extremes swing with the chaos of a settling liquid)."""
        return float(np.median(self.fastest[:, self.masses_g.index(mass_g)]))


def rest_in_cup(
    masses_g: Sequence[float] = REST_FILLS_G,
    windows: Sequence[tuple[float, float]] = (REST_WINDOW_S, REST_LATE_WINDOW_S),
    device: str = "cpu",
    samples: int = 12,
    sleep_threshold: float = 0.0,
) -> tuple[RestResult, ...]:
    """Fill a cup (radius 4 cm) with water at rest density and let it settle; in each of
    ``windows`` (s, in time order, one run for all) sample speeds, kernel density and a
    probe's mass per volume ``samples`` times. One result per window."""
    shape = cup(0.04, 0.08)
    cfg = SolverConfig(device=device, sleep_threshold=sleep_threshold)
    s = PBFSolver(len(masses_g), cfg)
    for w, mass in enumerate(masses_g):
        s.add_collider(w, "plane", [0.0])
        s.fill(w, s.add_container(w, shape), mass, "water")
    results = []
    for t0, t1 in windows:
        if t0 < s.time - 1e-9 or t1 <= t0:
            raise InvalidParameterError(
                f"rest windows must be increasing and disjoint, got {windows}"
            )
        s.step(round((t0 - s.time) / s.config.dt))
        every = max(1, round((t1 - t0) / s.config.dt / samples))
        errors, maxima, speeds, bulk = [], [], [], []
        for _ in range(samples):
            s.step(every)
            x, v = s.positions(), np.linalg.norm(s.velocities(), axis=1)
            for w in range(len(masses_g)):
                sl = s.world_slice(w)
                xw = x[sl]
                errors.append(s.density_error(w))
                maxima.append(v[sl].max())
                speeds.append(v[sl])
                # mass per volume in a probe cylinder well inside the liquid (1 cm from the
                # wall, the bottom and the surface): a kernel-free measure of the density
                rho_xy = np.hypot(xw[:, 0], xw[:, 1])
                lo, hi = shape.bottom_z + 0.01, np.quantile(xw[:, 2], 0.99) - 0.01
                probe = (rho_xy < 0.03) & (xw[:, 2] > lo) & (xw[:, 2] < hi)
                volume = math.pi * 0.03**2 * (hi - lo)
                bulk.append(probe.sum() * s.particle_mass(w) / volume)
        results.append(
            RestResult(
                float(max(errors)),
                float(max(maxima)),
                float(np.median(maxima)),
                float(np.quantile(np.concatenate(speeds), 0.99)),
                float(np.mean(bulk)),
                s,
                tuple(masses_g),
                np.reshape(maxima, (samples, len(masses_g))),
            )
        )
    return tuple(results)


@dataclass(frozen=True)
class ColumnResult:
    """A deep column of water left to settle (:func:`deep_column`), sampled over a window."""

    bottom_density: float  # mass per volume in the lowest 2 cm over the rest density, mean
    height_ratio: float  # surface height over the height the mass fills at rest density, mean
    max_speed: float  # m/s, fastest particle at any sample
    lost: int  # particles outside the box's cavity at the end
    iterations: float  # density iterations a step, mean over the window
    diverged: bool  # the solver flagged the world at some sample


def deep_column(
    height: float = 0.30,
    window: tuple[float, float] = (0.5, 1.0),
    samples: int = 6,
    config: SolverConfig | None = None,
) -> ColumnResult:
    """Fill a 4 × 4 cm box (5 mm walls) with a ``height`` (m) column of water (``config``: the
    default settings) and let it settle; sample ``samples`` times over ``window`` (s). The
    surface is the 99.5th percentile of particle heights plus half a spacing."""
    cfg = config or SolverConfig()
    s = PBFSolver(1, cfg)
    box = BoxShell(0.02, 0.02, height + 0.05, 0.005)
    s.fill(0, s.add_container(0, box), 1000.0 * 0.04 * 0.04 * height * 1e3, "water")
    area, rho0, m = 0.04 * 0.04, s.liquids[0].density, s.particle_mass(0)
    s.step(round(window[0] / cfg.dt))
    every = max(1, round((window[1] - window[0]) / cfg.dt / samples))
    bottom, ratio, fastest, its, diverged = [], [], 0.0, [], False
    for _ in range(samples):
        for _ in range(every):
            s.step()
            its.append(s.iterations_used()[0])
        x = s.positions()
        z = x[:, 2] - box.bottom_z
        # each particle's mass spread over a spacing of height: a count of centres below 2 cm
        # jumps by a particle (0.4 %) as one of the next layer dips below the line
        inside = np.clip((0.02 - z) / cfg.spacing + 0.5, 0.0, 1.0)
        bottom.append(inside.sum() * m / (area * 0.02) / rho0)
        ratio.append((np.quantile(z, 0.995) + cfg.spacing / 2) / (len(x) * m / (rho0 * area)))
        fastest = max(fastest, float(np.linalg.norm(s.velocities(), axis=1).max()))
        diverged |= bool(s.diverged()[0])
    lost = int((~box.contains(s.positions())).sum())
    return ColumnResult(
        float(np.mean(bottom)), float(np.mean(ratio)), fastest, lost, float(np.mean(its)), diverged
    )


def scale_reading(
    mass_g: float, seconds: float = 1.5, settle: float = 1.0, device: str = "cpu"
) -> float:
    """Mean force-sensor reading (grams) under a cup holding ``mass_g`` of settled water."""
    scene = two_cup_scene("water", mass_g=0.0, target_g=mass_g, config=SolverConfig(device=device))
    readings = []
    while scene.solver.time < seconds:
        scene.step()
        if scene.solver.time > settle:
            readings.append(scene.weight_g())
    return float(np.mean(readings))


@dataclass(frozen=True)
class FloatResult:
    """A box floating in a tank of water (:func:`floating_box`), averaged over the last
    0.5 s. Depths are in metres of water at 1000 kg/m³."""

    archimedes: float  # draft at which the displaced water weighs what the box does
    draft: float  # the box bottom's depth below the water level (top layer + half a spacing)
    column_difference: float  # water column beside the box minus the column under it
    lift: float  # the liquid's vertical force on the box over the box's weight


def floating_box(
    body_density: float = 500.0, seconds: float = 1.5, device: str = "cpu"
) -> FloatResult:
    """Drop a 6 × 6 × 4 cm box of ``body_density`` (kg/m³, on a MuJoCo free joint) into a
    10 × 10 cm tank holding 500 g of water and let it float: two-way coupling, the liquid's
    reaction in ``xfrc_applied`` against MuJoCo's gravity.

    In hydrostatic equilibrium the pressure at the tank floor is the same under the box and
    beside it, so the water column beside it exceeds the column under it by the box's mass
    over its footprint (``column_difference`` = ``archimedes``), a measure of masses that
    the liquid's compression does not change. The settled particles form a jammed packing
    that carries part of the box's weight sideways, so it comes out 1-2 mm short, by an
    amount that varies with the fill (docs/contact.md). ``draft`` is geometric: where the
    liquid packs denser than at rest (without the density constraint's wall term, against
    every wall; with it, still at the box's edges and corners), the box sits deeper than
    ``archimedes``.
    """
    half, half_h, water_g, margin = 0.03, 0.02, 500.0, 0.005
    mass = body_density * (2 * half) ** 2 * 2 * half_h
    cfg = SolverConfig(device=device)
    xml = f"""<mujoco><option timestep="{cfg.dt!r}"/><worldbody>
      <body name="float" pos="0 0 0.09"><freejoint/>
        <geom name="hull" type="box" size="{half} {half} {half_h}" mass="{mass!r}"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    solver = PBFSolver(1, cfg)
    tank = BoxShell(0.05, 0.05, 0.1, 0.01)
    solver.fill(0, solver.add_container(0, tank), water_g, "water")
    coupling = MujocoCoupling(solver, model, [data])
    coupling.add_geoms(["hull"])
    per_particle = solver.particle_mass(0) / 1000.0  # m³ of water at 1000 kg/m³
    drafts, columns, lifts = [], [], []
    while solver.time < seconds - 1e-9:
        coupling.step()
        if solver.time > seconds - 0.5:  # the lift every step: its mean over the window
            lifts.append(data.xfrc_applied[1, 2] / (mass * GRAVITY))
        if solver.time > seconds - 0.5 and solver.steps % 6 == 0:
            x = solver.positions()
            ax, ay = np.abs(x[:, 0]), np.abs(x[:, 1])
            # columns 5 mm clear of the box's and the tank's sides: under the box, and the
            # two bands beside it (x on either side, along y)
            inner, outer = half - margin, tank.half_x - margin
            under = (ax < inner) & (ay < inner)
            beside = (ax > half + margin) & (ax < outer) & (ay < outer)
            column_under = under.sum() * per_particle / (2 * inner) ** 2
            column_beside = beside.sum() * per_particle / (2 * (outer - half - margin) * 2 * outer)
            columns.append(column_beside - column_under)
            outside = (ax > half) | (ay > half)
            level = np.quantile(x[outside, 2], 0.99) + cfg.spacing / 2
            drafts.append(level - (data.qpos[2] - half_h))
    return FloatResult(
        archimedes=body_density / 1000.0 * 2 * half_h,
        draft=float(np.mean(drafts)),
        column_difference=float(np.mean(columns)),
        lift=float(np.mean(lifts)),
    )


def half_pour_times(
    liquids: Sequence[str] = VISCOUS_ORDER,
    seconds: float = 4.0,
    spacing: float = 0.006,
    device: str = "cpu",
    sleep_threshold: float = 0.0,
    dt: float = SolverConfig.dt,
    max_deg: float = 135.0,
) -> tuple[np.ndarray, np.ndarray]:
    """All liquids poured with the same tilt (:func:`tilt_schedule`, stopping at ``max_deg``
    degrees), one world each in one solver, at step ``dt``.

    Returns:
        Time (s) at which half the liquid had left the source cup (interpolated within the
        step; inf if never), and the grams left in the source after ``seconds``.
    """
    n = len(liquids)
    cfg = SolverConfig(spacing=spacing, dt=dt, device=device, sleep_threshold=sleep_threshold)
    scene = two_cup_scene(list(liquids), 200.0, num_worlds=n, config=cfg)
    s = scene.solver
    total = np.array([scene.metrics(w).total_g for w in range(n)])
    t_half = np.full(n, np.inf)
    prev_t, prev_left = 0.0, total.copy()
    while s.time < seconds:
        scene.set_tilt(tilt_schedule(s.time, max_deg=max_deg))
        scene.step()
        left = np.array([scene.metrics(w).inside_g[0] for w in range(n)])
        crossed = np.isinf(t_half) & (left <= total / 2)
        frac = (prev_left - total / 2) / np.maximum(prev_left - left, 1e-12)
        t_half[crossed] = prev_t + frac[crossed] * (s.time - prev_t)
        prev_t, prev_left = s.time, left
    return t_half, prev_left


def dam_break_fronts(
    a: float = 0.05, spacing: float = 0.0025, device: str = "cpu"
) -> dict[float, float]:
    """Release a water column (width a, height 2a) in a tank; surge front Z at MARTIN_MOYCE's T."""
    cfg = SolverConfig(spacing=spacing, dt=1.0 / 480.0, device=device)
    s = PBFSolver(1, cfg)
    tank = BoxShell(half_x=0.15, half_y=0.0125, depth=0.12, wall=0.005)
    s.add_container(0, tank)
    xs = np.arange(spacing / 2, a, spacing)
    ys = np.arange(-tank.half_y + spacing / 2, tank.half_y, spacing)
    zs = np.arange(spacing / 2, 2 * a, spacing) + tank.bottom_z
    X, Y, Z = np.meshgrid(xs - tank.half_x, ys, zs, indexing="ij")
    s.add_particles(0, np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1))
    scale = math.sqrt(2 * GRAVITY / a)
    out = {}
    for T in MARTIN_MOYCE:
        s.step(round((T / scale - s.time) / cfg.dt))
        x = s.positions()
        low = x[:, 2] < tank.bottom_z + 0.2 * a  # the surge front runs along the floor
        front = np.quantile(x[low, 0], 0.995) + tank.half_x + spacing / 2
        out[T] = float(front / a)
    return out


def free_drop(
    liquid: str = "water", times: Sequence[float] = (0.25, 0.5, 1.0), device: str = "cpu"
) -> list[float]:
    """An 8 × 8 × 8 cube of ``liquid`` at rest spacing released in zero gravity, no walls: its
    rms radius (about its centre of mass, over the radius of a ball of its volume) at the
    start and at each of ``times`` (s, increasing)."""
    cfg = SolverConfig(reorder_every=0, gravity=(0.0, 0.0, 0.0), device=device)
    g = (np.arange(8) - 3.5) * cfg.spacing
    cube = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    ball = (len(cube) * cfg.spacing**3 * 3.0 / (4.0 * math.pi)) ** (1.0 / 3.0)
    s = PBFSolver(1, cfg)
    s.set_liquid(0, liquid)
    s.add_particles(0, cube)

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((x - x.mean(0)) ** 2, axis=1)))) / ball

    radii = [rms(cube)]
    for t in times:
        s.step(round((t - s.time) / cfg.dt))
        radii.append(rms(s.positions()))
    return radii


def held_sphere_lift(
    liquids: Sequence[str | LiquidProfile],
    radius: float = 0.01,
    tank: float = 0.08,
    settle: float = 1.5,
    window: float = 1.0,
    device: str = "cpu",
) -> np.ndarray:
    """A sphere of ``radius`` (m) held still in a ``tank``-wide square tank (1 cm walls and
    floor) filled ``tank`` deep with each of ``liquids`` (one world each, one solver), its
    centre 1 cm below mid-depth: the liquid's mean upward force on it over ``window`` s after
    ``settle`` s, over the Archimedes lift ρ V g of the liquid's rest density. Hydrostatic
    balance makes it 1."""
    cfg = SolverConfig(device=device)
    s = PBFSolver(len(liquids), cfg)
    shell = BoxShell(tank / 2, tank / 2, tank + 0.02, 0.01)
    volume = 4.0 / 3.0 * math.pi * radius**3
    archimedes = np.empty(len(liquids))
    bodies = []
    for w, liquid in enumerate(liquids):
        bodies.append(s.new_body_slot())
        s.add_collider(w, "sphere", [radius], pose=[0, 0, tank / 2, 1, 0, 0, 0], body=bodies[-1])
        s.set_liquid(w, liquid)
        rho = s.liquids[w].density
        s.fill(w, s.add_container(w, shell), rho * (tank**3 - volume) * 1e3, liquid)
        archimedes[w] = rho * volume * GRAVITY
    s.step(round(settle / cfg.dt))
    steps = round(window / cfg.dt)
    lift = np.zeros(len(liquids))
    for _ in range(steps):
        s.step()
        lift += s.body_wrenches()[0][bodies, 2]
    return lift / steps / archimedes


@dataclass(frozen=True)
class SpinDown:
    """A spinning liquid coming to rest in a cup (:func:`spin_down`)."""

    times: np.ndarray  # s since the spin was set
    angular_momentum: np.ndarray  # about the cup's axis, over its value at the start
    closed_form: np.ndarray  # the same for a continuum of the liquid's viscosity
    radius: float  # m, the cup's inner radius
    depth: float  # m, the liquid's depth when the spin was set


def spin_down(
    liquid: LiquidProfile,
    radius: float = 0.03,
    seconds: float = 0.5,
    omega: float = 2.0,
    settle: float = 1.0,
    samples: int = 10,
    config: SolverConfig | None = None,
) -> SpinDown:
    """Liquid 1.5 ``radius`` deep in a cup of inner ``radius`` (m), settled ``settle`` s, set
    rotating rigidly at ``omega`` rad/s about the cup's axis, then left for ``seconds``: its
    angular momentum about the axis at ``samples`` times, beside the closed form for a liquid
    of viscosity ν = ``liquid.viscosity_pa_s`` / ρ between a no-slip side wall and floor,
    under a free surface. That is separable: Σ_n (8/λ_n²) exp(−ν λ_n² t / R²), λ_n the roots
    of J₁ (a rigid rotation's Fourier–Bessel series), times Σ_m 8/((2m−1)² π²)
    exp(−ν ((2m−1) π / 2L)² t) (the floor's sine series, L the depth)."""
    cfg = config or SolverConfig()
    s = PBFSolver(1, cfg)
    shape = cup(radius, 2.5 * radius, wall=0.006)
    c = s.add_container(0, shape)
    s.set_liquid(0, liquid)
    inner = float(shape.inner_radius(shape.bottom_z + 0.01))
    s.fill(0, c, s.liquids[0].density * math.pi * inner**2 * 1.5 * radius * 1e3, liquid)
    s.step(round(settle / cfg.dt))
    x = s.positions()
    depth = float(x[:, 2].max() - shape.bottom_z + cfg.spacing / 2)
    spin = np.stack([-omega * x[:, 1], omega * x[:, 0], np.zeros(len(x))], axis=1)
    s.clear_world(0)
    s.add_particles(0, x, spin)

    def turn() -> float:
        p, v = s.positions(), s.velocities()
        return float((p[:, 0] * v[:, 1] - p[:, 1] * v[:, 0]).sum())

    start = turn()
    every = max(1, round(seconds / cfg.dt / samples))
    times, turns = [], []
    for _ in range(samples):
        s.step(every)
        times.append(s.time - settle)
        turns.append(turn() / start)
    t = np.array(times)
    nu = (liquid.viscosity_pa_s or 0.0) / s.liquids[0].density
    lam = jn_zeros(1, 400)
    odd = 2.0 * np.arange(1, 400) - 1.0
    side = (8.0 / lam**2 * np.exp(-nu * np.outer(t, lam**2) / inner**2)).sum(axis=1)
    floor = (
        8.0 / (odd * math.pi) ** 2 * np.exp(-nu * np.outer(t, (odd * math.pi / (2 * depth)) ** 2))
    ).sum(axis=1)
    return SpinDown(t, np.array(turns), side * floor, inner, depth)


@dataclass(frozen=True)
class FallingBall:
    """A sphere falling through a column of one liquid (:func:`falling_ball`)."""

    liquid: str
    times: np.ndarray  # s since release
    fall: np.ndarray  # m, the sphere centre's fall since release
    speeds: np.ndarray  # m/s, mean downward speed over each third of the measured stretch
    closed_form: float  # m/s, falling_ball.terminal_speed for the liquid and this geometry
    reynolds: float  # of the closed form's speed, on the sphere's diameter

    @property
    def terminal(self) -> float:
        """m/s: the mean speed over the last two thirds of the measured stretch."""
        return float(self.speeds[1:].mean())


SETTLING_VISCOSITIES = (0.05, 0.5, 5.0, 50.0)
"""Pa·s: the four decades over which a settling sphere is compared with the closed form."""

SETTLING_RANGE_PA_S = (0.5, 50.0)
"""Pa·s: the viscosities over which the settling sphere is held to the closed form. Below
them the particle method's own viscosity and the settled packing's resistance set the
sphere's speed, not the liquid's viscosity (docs/viscosity.md)."""

SETTLING_TOLERANCE = 0.30
"""How near the closed form the settling sphere's terminal speed must be over
:data:`SETTLING_RANGE_PA_S`, as a fraction of it."""

FLEX_VELOCITY_TERMS = (
    *("viscosity", "cohesion", "surfaceTension", "adhesion", "vorticityConfinement"),
    *("staticFriction", "dynamicFriction", "particleFriction"),
)
"""A profile's FleX terms that change velocities."""


def newtonian(viscosity_pa_s: float, density: float = 1000.0) -> LiquidProfile:
    """A liquid whose only velocity filter is its physical viscosity (Pa·s) when run with
    ``SolverConfig(xsph_viscosity=0)``: water's other parameters, every FleX velocity term
    off."""
    off = dict.fromkeys(FLEX_VELOCITY_TERMS, 0.0)
    return liquid_profile("water").replace(
        name=f"newtonian {viscosity_pa_s:g} Pa·s",
        density=density,
        viscosity_cp=None,
        viscosity_pa_s=viscosity_pa_s,
        **off,
    )


def falling_ball(
    liquids: Sequence[str | LiquidProfile],
    radius: float = 0.015,
    bore: float = 0.05,
    depth: float = 0.14,
    seconds: float = 3.0,
    settle: float = 1.0,
    ball_density: float = 2500.0,
    config: SolverConfig | None = None,
) -> list[FallingBall]:
    """The falling-ball experiment of thesis §3.3: a glass sphere of ``radius`` (m) and
    ``ball_density`` (kg/m³) on a vertical slide joint (MuJoCo, two-way coupled) on the axis
    of a cylinder of inner radius ``bore`` holding ``depth`` of each liquid (one world each).
    The sphere is held with its top 5 mm under the surface while the liquid settles for
    ``settle`` s, then released for ``seconds``; one that comes within a radius of the floor
    is held there. The stretch measured starts a radius below the release (past the start-up)
    and ends with the sphere's centre 5 radii above the floor (nearer, the floor slows it:
    Brenner's factor is 1 + 9R/8z to first order, 1.2 there); its three thirds in time give
    ``speeds``. The closed form is Stokes' drag with the cylinder's Haberman–Sayre factor and
    the Schiller–Naumann inertia term (:func:`pourbench.fluids.falling_ball.terminal_speed`)."""
    cfg = config or SolverConfig()
    n = len(liquids)
    mass = ball_density * 4.0 / 3.0 * math.pi * radius**3
    shape = cup(bore, depth + 4.0 * radius, wall=0.01)
    floor = shape.bottom_z
    z0 = floor + depth - radius - 0.005
    xml = f"""<mujoco><option timestep="{cfg.dt!r}"/><worldbody>
      <body name="ball" pos="0 0 {z0!r}"><joint type="slide" axis="0 0 1"/>
        <geom name="ball" type="sphere" size="{radius!r}" mass="{mass!r}"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    datas = [mujoco.MjData(model) for _ in range(n)]
    s = PBFSolver(n, cfg)
    coupling = MujocoCoupling(s, model, datas)
    coupling.add_geoms(["ball"])
    ball_volume = 4.0 / 3.0 * math.pi * radius**3
    for w, liquid in enumerate(liquids):
        s.set_liquid(w, liquid)
        rho = s.liquids[w].density
        s.fill(w, s.add_container(w, shape), rho * (math.pi * bore**2 * depth - ball_volume) * 1e3)

    while s.time < settle - 1e-9:  # MuJoCo stands still: the sphere is held where it is
        coupling.sync()
        s.step()
        coupling.apply()
    start = s.time
    times, falls = [0.0], [np.zeros(n)]
    lowest = z0 - floor - 2.0 * radius  # a fall that ends a radius above the floor
    while s.time - start < seconds - 1e-9 and min(falls[-1]) < lowest:
        coupling.step()
        fall = np.array([-d.qpos[0] for d in datas])
        for w in np.flatnonzero(fall >= lowest):  # stopped over the floor MuJoCo does not see
            datas[w].qpos[0], datas[w].qvel[0] = -lowest, 0.0
            mujoco.mj_kinematics(model, datas[w])
        times.append(s.time - start)
        falls.append(np.minimum(fall, lowest))
    t, fall = np.array(times), np.array(falls)
    out = []
    for w, liquid in enumerate(liquids):
        rho = s.liquids[w].density
        mu = s.liquids[w].viscosity_pa_s or 0.0
        closed, re = terminal_speed(mu, rho, radius, ball_density, bore) if mu else (math.inf, 0.0)
        stretch = (fall[:, w] >= radius) & (fall[:, w] <= lowest - 3.0 * radius)
        ts, zs = t[stretch], fall[stretch, w]
        speeds = np.full(3, np.nan)  # it did not reach the stretch
        if len(ts) > 3:
            edges = np.linspace(ts[0], ts[-1], 4)
            speeds = np.diff(np.interp(edges, ts, zs)) / np.diff(edges)
        name = liquid if isinstance(liquid, str) else liquid.name
        out.append(FallingBall(name, t, fall[:, w], speeds, closed, re))
    return out
