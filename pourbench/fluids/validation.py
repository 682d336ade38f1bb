"""Physical validation experiments of the liquid solver, shared by the tests and the bench.

Each function runs one experiment on the CPU (or ``device``) and returns the measured
quantities; ``tests/test_fluids_physics.py`` asserts them against physical expectations and
``pourbench bench fluids`` reports them beside the thesis' and the literature's numbers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pourbench.fluids.scenarios import GRAVITY, tilt_schedule, two_cup_scene
from pourbench.fluids.shapes import BoxShell, cup
from pourbench.fluids.solver import PBFSolver, SolverConfig

# Martin & Moyce (1952), n² = 2 (column height 2a, width a): surge-front position Z = x/a at
# T = t·sqrt(2g/a), interpolated from their tabulated measurements.
MARTIN_MOYCE = {1.0: 1.33, 2.0: 2.36, 3.0: 3.70}

VISCOUS_ORDER = ("water", "ink", "oil", "glycerine", "honey", "ketchup")
"""Table 6.2's liquids in order of FleX viscosity (and adhesion)."""


@dataclass(frozen=True)
class RestResult:
    """200 g of water left in a cup for ``seconds``."""

    density_error: float  # mean |ρ/ρ0 − 1| over the bulk
    max_speed: float  # m/s
    p99_speed: float  # m/s
    bulk_density: float  # kg/m^3, particle mass per volume in a probe inside the bulk
    solver: PBFSolver


def rest_in_cup(mass_g: float = 200.0, seconds: float = 1.0, device: str = "cpu") -> RestResult:
    """Fill a cup (radius 4 cm) with water at rest density and let it settle."""
    shape = cup(0.04, 0.08)
    s = PBFSolver(1, SolverConfig(device=device))
    s.add_collider(0, "plane", [0.0])
    c = s.add_container(0, shape)
    s.fill(0, c, mass_g, "water")
    s.step(round(seconds / s.config.dt))
    speed = np.linalg.norm(s.velocities(), axis=1)
    # mass per volume in a probe cylinder well inside the liquid (1 cm from the wall, the
    # bottom and the surface): a kernel-free measure of the density
    x = s.positions()
    rho_xy = np.hypot(x[:, 0], x[:, 1])
    lo, hi = shape.bottom_z + 0.01, np.quantile(x[:, 2], 0.99) - 0.01
    probe = (rho_xy < 0.03) & (x[:, 2] > lo) & (x[:, 2] < hi)
    bulk = probe.sum() * s.particle_mass(0) / (math.pi * 0.03**2 * (hi - lo))
    return RestResult(
        s.density_error(), float(speed.max()), float(np.quantile(speed, 0.99)), bulk, s
    )


def scale_reading(mass_g: float, seconds: float = 1.5, settle: float = 1.0) -> float:
    """Mean force-sensor reading (grams) under a cup holding ``mass_g`` of settled water."""
    scene = two_cup_scene("water", mass_g=0.0, target_g=mass_g)
    readings = []
    while scene.solver.time < seconds:
        scene.step()
        if scene.solver.time > settle:
            readings.append(scene.weight_g())
    return float(np.mean(readings))


def half_pour_times(
    liquids: Sequence[str] = VISCOUS_ORDER, seconds: float = 4.0, spacing: float = 0.006
) -> tuple[np.ndarray, np.ndarray]:
    """All liquids poured with the same tilt, one world each in one solver.

    Returns:
        Time (s) at which half the liquid had left the source cup (interpolated within the
        step; inf if never), and the grams left in the source after ``seconds``.
    """
    n = len(liquids)
    scene = two_cup_scene(list(liquids), 200.0, num_worlds=n, config=SolverConfig(spacing=spacing))
    s = scene.solver
    total = np.array([scene.metrics(w).total_g for w in range(n)])
    t_half = np.full(n, np.inf)
    prev_t, prev_left = 0.0, total.copy()
    while s.time < seconds:
        scene.set_tilt(tilt_schedule(s.time))
        scene.step()
        left = np.array([scene.metrics(w).inside_g[0] for w in range(n)])
        crossed = np.isinf(t_half) & (left <= total / 2)
        frac = (prev_left - total / 2) / np.maximum(prev_left - left, 1e-12)
        t_half[crossed] = prev_t + frac[crossed] * (s.time - prev_t)
        prev_t, prev_left = s.time, left
    return t_half, prev_left


def dam_break_fronts(a: float = 0.05, spacing: float = 0.0025) -> dict[float, float]:
    """Release a water column (width a, height 2a) in a tank; surge front Z at MARTIN_MOYCE's T."""
    cfg = SolverConfig(spacing=spacing, dt=1.0 / 480.0)
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
