"""Physical validation experiments of the liquid solver, shared by the tests and the bench.

Each function runs one experiment on the CPU (or ``device``) and returns the measured
quantities; ``tests/test_fluids_physics.py`` asserts them against physical expectations and
``pourbench bench fluids`` reports them beside the thesis' and the literature's numbers.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.special import jn_zeros

from pourbench.errors import InvalidParameterError
from pourbench.fluids.config import SolverConfig
from pourbench.fluids.coupling import MujocoCoupling
from pourbench.fluids.falling_ball import startup_fall, terminal_speed
from pourbench.fluids.params import LiquidProfile, liquid_profile
from pourbench.fluids.rheology import couette_inner_stress, omega_for_rate, yield_tilt
from pourbench.fluids.scenarios import GRAVITY, tilt_schedule, two_cup_scene
from pourbench.fluids.solver import PBFSolver
from pourbench.geometry.fill import container_lattice
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
    level_density: float  # kg/m^3, mass over the volume below the level (rest_in_cup), mean
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
    config: SolverConfig | None = None,
) -> tuple[RestResult, ...]:
    """Fill a cup (radius 4 cm) with water at rest density and let it settle; in each of
    ``windows`` (s, in time order, one run for all) sample speeds, kernel density and the
    liquid's mass per volume ``samples`` times. One result per window.

    The mass per volume is the liquid's mass over the cup's cross-section times its level,
    the level being twice its particles' mean height above the cup's floor: exact for a
    column of layers a spacing apart, which is how a settled particle liquid stands. A probe
    with sharp bounds counts whole layers in or out (docs/rest.md). ``config`` (its device and
    sleep threshold replaced by ``device`` and ``sleep_threshold``): the solver's settings."""
    radius = 0.04
    shape = cup(radius, 0.08)
    cfg = dataclasses.replace(
        config or SolverConfig(), device=device, sleep_threshold=sleep_threshold
    )
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
        errors, maxima, speeds, per_volume = [], [], [], []
        for _ in range(samples):
            s.step(every)
            x, v = s.positions(), np.linalg.norm(s.velocities(), axis=1)
            for w in range(len(masses_g)):
                sl = s.world_slice(w)
                xw = x[sl]
                errors.append(s.density_error(w))
                maxima.append(v[sl].max())
                speeds.append(v[sl])
                level = 2.0 * float(np.mean(xw[:, 2] - shape.bottom_z))
                mass = len(xw) * s.particle_mass(w)
                per_volume.append(mass / (math.pi * radius**2 * level))
        results.append(
            RestResult(
                float(max(errors)),
                float(max(maxima)),
                float(np.median(maxima)),
                float(np.quantile(np.concatenate(speeds), 0.99)),
                float(np.mean(per_volume)),
                s,
                tuple(masses_g),
                np.reshape(maxima, (samples, len(masses_g))),
            )
        )
    return tuple(results)


def wall_push_anisotropy(solver: PBFSolver) -> tuple[float, float, int]:
    """How much harder the corrected density solve pushes the particles beside a wall toward
    it than along it (``SolverConfig.corrected_pressure``): over the particles within one
    spacing of their nearest wall, the mean of n·C·n and of the mean tangential t·C·t, C a
    particle's correction matrix and n its wall's normal, with the matrices recomputed at the
    solver's current positions; and how many particles that is. 1 and 1 for a liquid whose
    neighbours, counted with the solid, sit evenly in every direction."""
    if not solver.config.corrected_pressure:
        raise InvalidParameterError("the correction matrices exist with corrected_pressure on")
    solver.launches.build_neighbours()
    solver.launches.correct_gradients()
    p = solver.buf.p.numpy().astype(float)
    corr = solver.buf.corr.numpy().astype(float)
    wall = solver.buf.wall.numpy().astype(float)
    n = wall[:, :3]
    layer = (solver.buf.wall_collider.numpy() >= 0) & (
        np.einsum("ij,ij->i", n, p) - wall[:, 3] < solver.config.spacing
    )
    if not layer.any():
        raise InvalidParameterError("no particle lies within a spacing of a wall")
    normal = np.einsum("ia,iab,ib->i", n[layer], corr[layer], n[layer])
    tangential = (np.trace(corr[layer], axis1=1, axis2=2) - normal) / 2.0
    return float(normal.mean()), float(tangential.mean()), int(layer.sum())


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
    config: SolverConfig | None = None,
) -> np.ndarray:
    """A sphere of ``radius`` (m) held still in a ``tank``-wide square tank (1 cm walls and
    floor) filled ``tank`` deep with each of ``liquids`` (one world each, one solver), its
    centre 1 cm below mid-depth: the liquid's mean upward force on it over ``window`` s after
    ``settle`` s, over the Archimedes lift ρ V g of the liquid's rest density. Hydrostatic
    balance makes it 1. ``config``: the solver's settings (default ``SolverConfig()``), run
    on ``device``."""
    cfg = dataclasses.replace(config or SolverConfig(), device=device)
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


SETTLING_VISCOSITIES = (0.1, 0.5, 5.0, 50.0)
"""Pa·s: the four decades over which a settling sphere is compared with the closed form."""

SETTLING_TOLERANCE = 0.25
"""How near the closed form the settling sphere's terminal speed must be, as a fraction of
it."""

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


BALL_RADIUS = 0.015
"""m: :func:`falling_ball`'s glass sphere."""

BALL_DENSITY = 2500.0
"""kg/m³: soda-lime glass."""

BALL_BORE = 0.05
"""m: the inner radius of :func:`falling_ball`'s cylinder."""

BALL_COLUMN = 0.14
"""m: :func:`falling_ball`'s column of liquid, Table 3.4's check."""

RELEASE_DEPTH = 0.005
"""m: how far under the surface the sphere's top is released."""


def stretch_start(
    liquid: LiquidProfile, radius: float, ball_density: float, bore: float, startup: float | None
) -> float:
    """m of fall: where :func:`falling_ball` starts timing the sphere in ``liquid``. A radius
    below the release; with ``startup`` = f, where the closed form's start-up from rest
    reaches f of its terminal speed if that is deeper
    (:func:`~pourbench.fluids.falling_ball.startup_fall`)."""
    if startup is None or not liquid.viscosity_pa_s:
        return radius
    fall = startup_fall(liquid.viscosity_pa_s, liquid.density, radius, ball_density, bore, startup)
    return max(radius, fall)


def column_for(start: float, radius: float) -> float:
    """m: the shallowest column in which a stretch that starts ``start`` below the release
    and is a diameter long ends with the sphere's centre 5 radii above the floor."""
    release = RELEASE_DEPTH + radius  # the sphere's centre under the surface at release
    return release + start + 2.0 * radius + 5.0 * radius


def falling_ball(
    liquids: Sequence[str | LiquidProfile],
    radius: float = BALL_RADIUS,
    bore: float = BALL_BORE,
    depth: float = BALL_COLUMN,
    seconds: float = 3.0,
    settle: float = 1.0,
    ball_density: float = BALL_DENSITY,
    config: SolverConfig | None = None,
    startup: float | None = None,
) -> list[FallingBall]:
    """The falling-ball experiment of thesis §3.3: a glass sphere of ``radius`` (m) and
    ``ball_density`` (kg/m³) on a vertical slide joint (MuJoCo, two-way coupled) on the axis
    of a cylinder of inner radius ``bore`` holding ``depth`` of each liquid (one world each).
    The sphere is held with its top 5 mm under the surface while the liquid settles for
    ``settle`` s, then released for at most ``seconds``; one that comes within a radius of the
    floor is held there. The stretch measured starts at :func:`stretch_start` (``startup``
    0.98 measures a terminal speed; the default times the thesis' marble as it was timed).
    It is a diameter long and must end with the sphere's centre 5 radii above the floor or
    higher (nearer, the floor slows it: Brenner's factor is 1 + 9R/8z to first order, 1.2
    there): a column too short for it is an :class:`InvalidParameterError`. Its three thirds
    in time give ``speeds``, NaN for a sphere that did not cross it within ``seconds``; the
    run ends once every sphere has. The closed form is Stokes' drag with the cylinder's
    Haberman–Sayre factor and the Schiller–Naumann inertia term
    (:func:`pourbench.fluids.falling_ball.terminal_speed`)."""
    profiles = [liquid_profile(liquid) for liquid in liquids]
    starts = np.array([stretch_start(p, radius, ball_density, bore, startup) for p in profiles])
    for p, start in zip(profiles, starts, strict=True):
        if column_for(start, radius) > depth + 1e-9:
            raise InvalidParameterError(
                f"a {depth * 100:g} cm column is too short to time the sphere in {p.name!r}: "
                f"its stretch starts {start * 100:.1f} cm below the release and is "
                f"{2 * radius * 100:g} cm long; it needs {column_for(start, radius) * 100:.1f} cm"
            )
    ends = starts + 2.0 * radius
    lowest = depth - RELEASE_DEPTH - 3.0 * radius  # a fall that ends a radius above the floor
    cfg = config or SolverConfig()
    n = len(liquids)
    mass = ball_density * 4.0 / 3.0 * math.pi * radius**3
    shape = cup(bore, depth + 4.0 * radius, wall=0.01)
    floor = shape.bottom_z
    z0 = floor + depth - radius - RELEASE_DEPTH
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
    while s.time - start < seconds - 1e-9 and np.any(falls[-1] < ends):
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
        stretch = (fall[:, w] >= starts[w]) & (fall[:, w] <= ends[w])
        ts, zs = t[stretch], fall[stretch, w]
        speeds = np.full(3, np.nan)  # it did not cross the stretch
        if len(ts) > 3 and fall[-1, w] >= ends[w]:
            edges = np.linspace(ts[0], ts[-1], 4)
            speeds = np.diff(np.interp(edges, ts, zs)) / np.diff(edges)
        name = liquid if isinstance(liquid, str) else liquid.name
        out.append(FallingBall(name, t, fall[:, w], speeds, closed, re))
    return out


SETTLING_STARTUP = 0.98
"""The share of its closed-form terminal speed the settling sphere's closed-form start-up
reaches where its timed stretch begins (:func:`settling_sphere`)."""

SETTLING_SLOWEST = 0.5
"""The slowest settling sphere :func:`settling_sphere` waits for, as a fraction of the
closed form: one slower reads NaN."""

SETTLING_SHARED_WAIT = 4.0
"""How many times the quickest one's wait the spheres that share a run of
:func:`settling_sphere` may wait."""


def settling_sphere(
    viscosities: Sequence[float], config: SolverConfig | None = None
) -> list[FallingBall]:
    """The falling ball's sphere (:func:`falling_ball`'s defaults) settling in a Newtonian
    liquid of each of ``viscosities`` (Pa·s, :func:`newtonian`), timed at its terminal speed:
    each stretch starts where the closed form's start-up has reached
    :data:`SETTLING_STARTUP` of it, in one column deep enough for the longest start-up
    (:data:`BALL_COLUMN` or deeper, to the next centimetre). Each run waits until its spheres
    have crossed their stretches at :data:`SETTLING_SLOWEST` of the closed form; spheres
    whose waits are within :data:`SETTLING_SHARED_WAIT` of each other share a run, so that a
    quick one does not wait on a slow one. The results in the order of ``viscosities``."""
    liquids = [newtonian(mu) for mu in viscosities]
    starts = [
        stretch_start(p, BALL_RADIUS, BALL_DENSITY, BALL_BORE, SETTLING_STARTUP) for p in liquids
    ]
    deepest = max([BALL_COLUMN, *(column_for(start, BALL_RADIUS) for start in starts)])
    depth = math.ceil(round(deepest * 100.0, 6)) / 100.0
    waits = []  # s: how long each sphere takes to cross its stretch at the slowest we wait for
    for p, start in zip(liquids, starts, strict=True):
        closed = terminal_speed(p.viscosity_pa_s, p.density, BALL_RADIUS, BALL_DENSITY, BALL_BORE)
        waits.append((start + 2.0 * BALL_RADIUS) / (SETTLING_SLOWEST * closed[0]))
    runs: list[list[int]] = []
    for i in sorted(range(len(liquids)), key=waits.__getitem__):
        if runs and waits[i] <= SETTLING_SHARED_WAIT * waits[runs[-1][0]]:
            runs[-1].append(i)
        else:
            runs.append([i])
    results: dict[int, FallingBall] = {}
    for members in runs:
        members.sort()
        balls = falling_ball(
            [liquids[i] for i in members],
            depth=depth,
            seconds=max(waits[i] for i in members),
            config=config,
            startup=SETTLING_STARTUP,
        )
        results.update(zip(members, balls, strict=True))
    return [results[i] for i in range(len(liquids))]


SHEAR_VISCOSITIES = (0.1, 1.0, 10.0)
"""Pa·s: the Newtonian liquids the shear cell checks for a yield stress."""

SHEAR_RATES = (1.0, 3.0, 10.0)
"""1/s: the shear rates (Newtonian, at the inner cylinder) of those checks."""

YIELD_LIMIT = 0.15
"""The largest stress at zero rate a Newtonian liquid may show in the shear cell, as a
fraction of its stress at the middle rate (the line through its stresses)."""

SLOPE_TOLERANCE = 0.25
"""How near the liquid's viscosity that line's slope must be, as a fraction of it."""

REDUCED_SCORR_SPREAD = 0.3
"""``SolverConfig.bulk_scorr_spread`` of the corrected solve's checks with less of the bulk's
tensile variation: of 0, 0.3, 0.6 and 1, the lowest at which settled water still comes to
rest within its bounds (docs/viscosity.md, "The bulk's tensile term")."""

YIELD_LAW_RATES = (1.0, 3.0, 10.0, 30.0)
"""1/s: the rates at which the shear cell checks a Herschel–Bulkley liquid."""


def yield_stress_liquid() -> LiquidProfile:
    """A Herschel–Bulkley test liquid of 1000 kg/m³ shaped like a ketchup: τ_y = 20 Pa,
    K = 10 Pa·sⁿ, n = 0.25 (ketchups' Herschel–Bulkley fits have n of 0.22–0.26 and K of
    7–20 Pa·sⁿ, Koocheki et al. 2009, Int. J. Food Sci. Technol. 44:596), its reference
    viscosity 10 Pa·s, every FleX velocity term off (:func:`newtonian`)."""
    return newtonian(10.0).replace(
        name="Herschel–Bulkley 20 Pa, 10 Pa·s^0.25",
        yield_stress_pa=20.0,
        consistency_pa_sn=10.0,
        flow_index=0.25,
    )


@dataclass(frozen=True)
class ShearCell:
    """A concentric-cylinder rheometer run (:func:`shear_cell`): one liquid, several speeds."""

    liquid: str
    inner: float  # m, the turning cylinder's radius
    outer: float  # m, the fixed cup's inner radius
    rates: np.ndarray  # 1/s, a Newtonian liquid's shear rate at the inner cylinder
    stresses: np.ndarray  # Pa, measured: the torque on the inner cylinder / (2π R₁² L)
    closed_form: np.ndarray  # Pa, the liquid's law's stress there (rheology.couette_inner_stress)
    wetted: np.ndarray  # m, the liquid's depth L at the end, per speed
    radii: np.ndarray  # m, centres of the gap's bins
    speeds: np.ndarray  # (speeds, bins) mean azimuthal speed over the window / (Ω R₁)
    newtonian_speeds: np.ndarray  # (bins,) the Newtonian profile / (Ω R₁)

    def fit(self) -> tuple[float, float]:
        """Least-squares line through (rate, stress): (stress at zero rate, Pa; slope, Pa·s)."""
        slope, intercept = np.polyfit(self.rates, self.stresses, 1)
        return float(intercept), float(slope)

    def yield_share(self) -> float:
        """The line's stress at zero rate over the stress at the middle rate (the median):
        what :data:`YIELD_LIMIT` bounds for a Newtonian liquid."""
        return self.fit()[0] / float(np.median(self.stresses))


def shear_cell(
    liquid: str | LiquidProfile,
    rates: Sequence[float],
    inner: float = 0.02,
    outer: float = 0.04,
    depth: float = 0.06,
    settle: float = 1.0,
    spin: float | None = None,
    window: float = 0.5,
    config: SolverConfig | None = None,
) -> ShearCell:
    """A Couette rheometer: a cylinder of radius ``inner`` (m) standing on the floor of a cup of
    inner radius ``outer``, the annulus filled ``depth`` (m) deep with ``liquid`` and settled
    for ``settle`` s, then the cylinder turned at the speed Ω that gives each of ``rates``
    (1/s) at its wall in a Newtonian liquid (one world per rate), for ``spin`` s to reach a
    steady flow (by default 1.5 s, or ten times the gap's viscous time (R₂ − R₁)² / (π² ν)
    of the liquid's reference viscosity where that is longer) and ``window`` s over which
    the liquid's torque on it and the azimuthal speeds across the gap (mid-depth, a third
    of the depth clear of the floor and the surface) are averaged.

    The cylinder's surface has no friction of its own: the torque reaches it through the
    viscous solve's no-slip wall alone, so a liquid without a physical viscosity feels none.
    ``closed_form`` is the liquid's law in a long cell (:mod:`pourbench.fluids.rheology`); the
    floor adds a little torque that the closed form leaves out.
    """
    cfg = config or SolverConfig(xsph_viscosity=0.0)
    profile = liquid_profile(liquid)
    law = profile.rheology()
    if law is None:
        raise InvalidParameterError(
            f"liquid {profile.name!r} has no physical viscosity: a shear cell measures one"
        )
    rates = np.asarray(rates, float)
    if len(rates) == 0 or np.any(~(rates > 0)):
        raise InvalidParameterError(f"rates must be > 0, got {rates.tolist()!r}")
    omegas = np.array([omega_for_rate(rate, inner, outer) for rate in rates])
    if spin is None:
        nu = (profile.viscosity_pa_s or 0.0) / profile.density
        spin = max(1.5, 10.0 * (outer - inner) ** 2 / (math.pi**2 * nu))
    n = len(omegas)
    s = PBFSolver(n, cfg)
    shape = cup(outer, depth + 0.04, wall=0.006)
    half = 0.5 * (depth + 0.03)
    centre = np.array([0.0, 0.0, shape.bottom_z + half - 0.005])  # 5 mm into the floor
    points = container_lattice(shape, cfg.spacing)
    annulus = points[
        (np.hypot(points[:, 0], points[:, 1]) > inner + 0.4 * cfg.spacing)
        & (points[:, 2] < shape.bottom_z + depth)
    ]
    cylinders, bodies = [], []
    for w in range(n):
        s.add_container(w, shape)
        s.set_liquid(w, profile)
        bodies.append(s.new_body_slot())
        pose = [*centre, 1.0, 0.0, 0.0, 0.0]
        cylinders.append(s.add_collider(w, "cylinder", [inner, half], pose=pose, body=bodies[-1]))
        s.add_particles(w, annulus)
    coms = np.tile(centre, (n, 1))
    poses = np.tile([*centre, 1.0, 0.0, 0.0, 0.0], (n, 1))
    s.set_collider_poses(cylinders, poses, coms)
    s.step(round(settle / cfg.dt))
    edges = np.linspace(inner, outer, round(2 * (outer - inner) / cfg.spacing) + 1)
    radii = 0.5 * (edges[:-1] + edges[1:])
    torque = np.zeros(n)
    speed_sum = np.zeros((n, len(radii)))
    speed_count = np.zeros((n, len(radii)))
    spin_steps, window_steps = round(spin / cfg.dt), round(window / cfg.dt)
    for k in range(spin_steps + window_steps):
        angle = omegas * (k + 1) * cfg.dt
        poses[:, 3], poses[:, 6] = np.cos(angle / 2), np.sin(angle / 2)
        s.set_collider_poses(cylinders, poses, coms)
        s.step()
        if k < spin_steps:
            continue
        torque += s.body_wrenches()[1][bodies, 2]
        if (k - spin_steps) % 4:
            continue
        x, v = s.positions(), s.velocities()
        for w in range(n):
            xs, vs = x[s.world_slice(w)], v[s.world_slice(w)]
            r = np.hypot(xs[:, 0], xs[:, 1])
            height = xs[:, 2] - shape.bottom_z
            mid = (height > depth / 3) & (height < 2 * depth / 3)
            azimuthal = (xs[:, 0] * vs[:, 1] - xs[:, 1] * vs[:, 0]) / np.maximum(r, 1e-9)
            b = np.clip(np.searchsorted(edges, r[mid]) - 1, 0, len(radii) - 1)
            speed_sum[w] += np.bincount(b, azimuthal[mid], len(radii))
            speed_count[w] += np.bincount(b, minlength=len(radii))
    x = s.positions()
    wetted = (
        np.array([np.percentile(x[s.world_slice(w), 2], 99) for w in range(n)])
        - shape.bottom_z
        + 0.5 * cfg.spacing
    )
    stresses = -torque / window_steps / (2 * math.pi * inner**2 * wetted)
    speeds = speed_sum / np.maximum(speed_count, 1) / (omegas[:, None] * inner)
    a = inner**2 / (outer**2 - inner**2)
    newtonian = a * (outer**2 / radii - radii) / inner
    return ShearCell(
        profile.name,
        inner,
        outer,
        rates,
        stresses,
        np.array([couette_inner_stress(law, o, inner, outer) for o in omegas]),
        wetted,
        radii,
        speeds,
        newtonian,
    )


@dataclass(frozen=True)
class TiltedLayer:
    """A layer of liquid on a tray tilted and held (:func:`tilted_layer`)."""

    liquid: str
    tilts_deg: np.ndarray  # the trays' tilts
    times: np.ndarray  # s since the tilt was reached
    shifts: np.ndarray  # (tilts, times) m, the layer's centre of mass downhill since then
    depth: float  # m, the layer's depth when flat
    yield_tilt_deg: float  # the law's (rheology.yield_tilt): 0 without a yield stress


def tilted_layer(
    liquid: str | LiquidProfile,
    tilts_deg: Sequence[float],
    depth: float = 0.02,
    half_length: float = 0.06,
    half_width: float = 0.02,
    settle: float = 0.5,
    turn: float = 0.2,
    hold: float = 1.0,
    samples: int = 4,
    config: SolverConfig | None = None,
) -> TiltedLayer:
    """A layer ``depth`` (m) deep covering the floor of a tray (inner half-extents
    ``half_length`` × ``half_width``, m), one tray a world: settled flat for ``settle`` s,
    tilted about its short axis at a steady rate to each of ``tilts_deg`` over ``turn`` s,
    then held for ``hold`` s, over which the layer's centre of mass moves downhill by
    ``shifts`` (in the tray's frame, at ``samples`` times evenly spaced over the hold). A
    yield stress τ_y holds the layer while the stress at its floor, ρ g h sin θ, is below it
    (``yield_tilt_deg``); a liquid without one flows toward the lower wall at any tilt."""
    cfg = config or SolverConfig(xsph_viscosity=0.0)
    profile = liquid_profile(liquid)
    tilts = np.radians(np.asarray(tilts_deg, float))
    if len(tilts) == 0 or np.any(tilts < 0) or np.any(tilts >= math.pi / 2):
        raise InvalidParameterError(f"tilts_deg must be in [0, 90), got {list(tilts_deg)!r}")
    tray = BoxShell(half_length, half_width, depth + 0.03, 0.01)
    s = PBFSolver(len(tilts), cfg)
    trays = []
    for w in range(len(tilts)):
        trays.append(s.add_container(w, tray))
        s.fill(w, trays[-1], profile.density * 4 * half_length * half_width * depth * 1e3, profile)
    s.step(round(settle / cfg.dt))

    def poses(angle: np.ndarray) -> np.ndarray:
        out = np.zeros((len(angle), 7))
        out[:, 3], out[:, 5] = np.cos(angle / 2), np.sin(angle / 2)  # about +y: +x goes down
        return out

    def downhill() -> np.ndarray:  # mean x of each world's liquid in its tray's frame
        x = s.positions()
        out = np.empty(len(tilts))
        for w, angle in enumerate(tilts):
            p = x[s.world_slice(w)]
            out[w] = np.mean(p[:, 0] * math.cos(angle) - p[:, 2] * math.sin(angle))
        return out

    turn_steps = max(1, round(turn / cfg.dt))
    for k in range(turn_steps):
        s.set_collider_poses(trays, poses(tilts * (k + 1) / turn_steps))
        s.step()
    start = downhill()
    every = max(1, round(hold / cfg.dt / samples))
    shifts = []
    for _ in range(samples):
        s.step(every)
        shifts.append(downhill() - start)
    law = profile.rheology()
    yield_deg = (
        0.0 if law is None else math.degrees(yield_tilt(law, profile.density, depth, GRAVITY))
    )
    times = every * cfg.dt * np.arange(1, samples + 1)
    return TiltedLayer(profile.name, np.degrees(tilts), times, np.array(shifts).T, depth, yield_deg)
