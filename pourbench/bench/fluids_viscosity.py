"""The viscosity sections of ``pourbench bench fluids``: what the physical viscosity and the
corrected pressure cost a Pour-v0 step (pours timed step by step in turn, :func:`timed_pours`),
and the falling-ball experiment of thesis §3.3 (Table 3.4) beside the thesis' marble speeds
and the closed form."""

from __future__ import annotations

import dataclasses
import itertools
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pourbench.bench.env import POUR_ACTION
from pourbench.envs.core import default_solver_config
from pourbench.envs.pour_v0 import PourEnv
from pourbench.fluids.config import SolverConfig
from pourbench.fluids.falling_ball import CYLINDER_RADIUS, MARBLE_RADIUS
from pourbench.fluids.params import liquid_profile
from pourbench.fluids.scenarios import tilt_schedule, two_cup_scene
from pourbench.fluids.validation import (
    SETTLING_STARTUP,
    SETTLING_TOLERANCE,
    SETTLING_VISCOSITIES,
    SHEAR_RATES,
    SHEAR_VISCOSITIES,
    SLOPE_TOLERANCE,
    YIELD_LAW_RATES,
    YIELD_LIMIT,
    falling_ball,
    newtonian,
    settling_sphere,
    shear_cell,
    yield_stress_liquid,
)

MARBLE_ORDER = (
    "water",
    "apple juice",
    "rapeseed oil",
    "hand-gel",
    "dish soap",
    "hand soap",
    "honey",
)
"""Table 3.4's liquids, fastest marble first."""


@dataclass(frozen=True)
class TimedPour:
    """One case of :func:`timed_pours`: the wall time of its timed steps and, for every step,
    the density iterations and the viscous conjugate-gradient iterations (the latter empty
    without the solve)."""

    seconds: float
    density_iterations: np.ndarray
    viscous_iterations: np.ndarray

    @property
    def ms_per_step(self) -> float:
        """Milliseconds per timed step (every step but the first, which loads the kernels)."""
        return 1e3 * self.seconds / max(1, len(self.density_iterations) - 1)


def timed_pours(
    cases: Mapping[str, tuple[Any, SolverConfig]], seconds: float
) -> dict[str, TimedPour]:
    """A 200 g pour of each case's liquid at its config (the validation pours' tilt), every
    case's scene built in this process and stepped in turn, one step each, so that all see the
    same machine load. A case's first step loads its kernels and is not timed."""
    scenes = {
        name: two_cup_scene(liquid, 200.0, config=cfg) for name, (liquid, cfg) in cases.items()
    }
    wall = dict.fromkeys(scenes, 0.0)
    density_its: dict[str, list[int]] = {name: [] for name in scenes}
    viscous_its: dict[str, list[int]] = {name: [] for name in scenes}
    first = True
    while any(scene.solver.time < seconds - 1e-9 for scene in scenes.values()):
        for name, scene in scenes.items():
            s = scene.solver
            if s.time >= seconds - 1e-9:
                continue
            scene.set_tilt(tilt_schedule(s.time))
            t0 = time.perf_counter()
            scene.step()
            if not first:
                wall[name] += time.perf_counter() - t0
            density_its[name].append(s.iterations_used()[0])
            if s.viscosity is not None:
                viscous_its[name].append(int(s.viscosity.iterations.numpy()[0]))
        first = False
    return {
        name: TimedPour(wall[name], np.array(density_its[name]), np.array(viscous_its[name]))
        for name in scenes
    }


def viscosity_cost(device: str = "cpu", seconds: float = 4.0) -> list[dict[str, Any]]:
    """A water and a honey pour at Pour-v0's settings with their physical viscosity, timed
    against the same liquid as a FleX-only profile (XSPH by its FleX coefficient, no solve:
    the solver before physical viscosities) in the same process, step by step in turn
    (:func:`timed_pours`)."""
    cfg = dataclasses.replace(default_solver_config(), device=device)
    rows = []
    for name in ("water", "honey"):
        print(f"fluids: viscosity cost, {name} pour at Pour-v0's settings…", file=sys.stderr)
        shipped = liquid_profile(name)
        flex = shipped.replace(viscosity_pa_s=None)
        runs = timed_pours({"flex": (flex, cfg), "physical": (shipped, cfg)}, seconds)
        flex_ms, ms = runs["flex"].ms_per_step, runs["physical"].ms_per_step
        its = runs["physical"].viscous_iterations
        rows.append(
            {
                "scene": f"200 g {name} ({shipped.viscosity_pa_s:g} Pa·s) poured for {seconds:g} s",
                "ms_per_step_flex": flex_ms,
                "ms_per_step": ms,
                "cost_ratio": ms / flex_ms,
                "viscosity_iterations_mean": float(its.mean()),
                "viscosity_iterations_max": int(its.max()),
            }
        )
    return rows


def correction_cost(device: str = "cpu", steps: int = 300, seed: int = 0) -> list[dict[str, Any]]:
    """What ``SolverConfig.corrected_pressure`` costs a Pour-v0 step with water and with
    honey: two environments, the correction on in one and off in the other, reset with the
    same seed and stepped in turn with ``pourbench bench env``'s pouring action, in this
    process, for ``steps`` environment steps each (the first, which loads the kernels,
    untimed)."""
    base = dataclasses.replace(default_solver_config(), device=device)
    rows = []
    for name in ("water", "honey"):
        print(f"fluids: corrected-pressure cost, Pour-v0 with {name}…", file=sys.stderr)
        envs = {
            on: PourEnv(liquid=name, solver=dataclasses.replace(base, corrected_pressure=on))
            for on in (False, True)
        }
        wall = dict.fromkeys(envs, 0.0)
        for env in envs.values():
            env.reset(seed=seed)
        for k in range(steps + 1):
            for on, env in envs.items():
                t0 = time.perf_counter()
                _, _, terminated, truncated, _ = env.step(POUR_ACTION)
                if k > 0:
                    wall[on] += time.perf_counter() - t0
                if terminated or truncated:
                    env.reset(seed=seed + k)
        for env in envs.values():
            env.close()
        off_ms, on_ms = 1e3 * wall[False] / steps, 1e3 * wall[True] / steps
        rows.append(
            {
                "scene": f"Pour-v0, {name}, the pouring action {tuple(POUR_ACTION.tolist())}",
                "env_steps": steps,
                "ms_per_step_plain": off_ms,
                "ms_per_step": on_ms,
                "cost_ratio": on_ms / off_ms,
            }
        )
    return rows


def falling_ball_check(device: str = "cpu") -> tuple[list[dict[str, Any]], str]:
    """Table 3.4's liquids as shipped in :func:`pourbench.fluids.validation.falling_ball`
    (1.5 cm glass sphere, 5 cm-radius cylinder, 14 cm column): rows, and whether the
    terminal speeds keep Table 3.4's order."""
    print("fluids: falling ball through Table 3.4's liquids…", file=sys.stderr)
    results = falling_ball(MARBLE_ORDER, config=SolverConfig(device=device))
    rows = []
    for r in results:
        p = liquid_profile(r.liquid)
        rows.append(
            {
                "liquid": p.name,
                "viscosity_pa_s": p.viscosity_pa_s,
                "thesis_marble_m_s": p.marble_speed,
                "speeds_m_s": " / ".join(f"{v:.4f}" for v in r.speeds),
                "terminal_m_s": r.terminal,
                "closed_form_m_s": r.closed_form,
                "terminal_over_closed_form": r.terminal / r.closed_form,
                "reynolds": r.reynolds,
            }
        )
    pairs = itertools.pairwise(zip(MARBLE_ORDER, [r.terminal for r in results], strict=True))
    swapped = [f"{a} / {b}" for (a, ta), (b, tb) in pairs if not ta > tb]
    order = "yes" if not swapped else "no: " + ", ".join(swapped)
    note = (
        "Table 3.4's liquids as shipped: a glass sphere of 1.5 cm radius (three spacings; "
        "2500 kg/m³) on a vertical slide joint (MuJoCo, two-way coupled), released just under "
        "the surface of a 14 cm column in a cylinder of 5 cm inner radius after 1 s of "
        "settling, for up to 3 s. `speeds`: mean "
        "speed over each third (in time) of the fall from a radius below the release until "
        "its centre is 5 radii above the floor; `terminal`: the last two thirds; nan: the "
        "sphere did not cross that stretch within the 3 s, or crossed it in fewer than four "
        "steps. "
        "`closed_form`: Stokes' "
        "drag with the cylinder's Haberman–Sayre factor and the Schiller–Naumann inertia term "
        "(`pourbench/fluids/falling_ball.py`). The thesis' marble (assumed 15.9 mm, in a "
        f"{2e3 * CYLINDER_RADIUS:.1f} mm bore: {MARBLE_RADIUS / CYLINDER_RADIUS:.2f} of it) "
        "is another geometry: its speeds are compared by order only. In water, apple juice "
        "and oil the sphere falls at Re in the thousands and does not reach a terminal speed "
        "in 14 cm, as the thesis' marble did not in 8.9 cm.\n\n"
        f"Terminal speeds in Table 3.4's order: {order}."
    )
    return rows, note


def _within(ratio: float) -> str:
    return "yes" if abs(ratio - 1.0) <= SETTLING_TOLERANCE else "no"


def settling_check(device: str = "cpu") -> tuple[list[dict[str, Any]], str]:
    """The falling ball's sphere settling in a Newtonian liquid of each of
    :data:`~pourbench.fluids.validation.SETTLING_VISCOSITIES` (1000 kg/m³, FleX terms and XSPH
    off), timed at its terminal speed (``validation.settling_sphere``), with the density solve
    as shipped and with ``corrected_pressure``: rows against the closed form, and a note
    saying over which of them it holds."""
    print("fluids: a sphere settling over four decades of viscosity…", file=sys.stderr)
    rows = []
    for solve, corrected in (("plain", False), ("corrected", True)):
        cfg = SolverConfig(xsph_viscosity=0.0, corrected_pressure=corrected, device=device)
        results = settling_sphere(SETTLING_VISCOSITIES, config=cfg)
        for mu, r in zip(SETTLING_VISCOSITIES, results, strict=True):
            ratio = r.terminal / r.closed_form
            rows.append(
                {
                    "viscosity_pa_s": mu,
                    "density_solve": solve,
                    "speeds_m_s": " / ".join(f"{v:.4f}" for v in r.speeds),
                    "terminal_m_s": r.terminal,
                    "closed_form_m_s": r.closed_form,
                    "terminal_over_closed_form": ratio,
                    "reynolds": r.reynolds,
                    f"within_{SETTLING_TOLERANCE:.0%}": _within(ratio),
                }
            )
    note = (
        "The falling ball's sphere and cylinder (above) in a Newtonian liquid of 1000 kg/m³ "
        "whose only velocity filter is its physical viscosity (`validation.newtonian`, "
        "`xsph_viscosity` 0), timed at its terminal speed (`validation.settling_sphere`): the "
        "stretch, a diameter long, starts where the closed form's own start-up from rest "
        f"reaches {SETTLING_STARTUP:.0%} of its terminal speed (at 0.1 Pa·s 11 cm below the "
        "release) and at least a radius below it, in a column deep enough for every "
        "viscosity's start-up (24 cm). `plain`: the density "
        "solve as shipped; `corrected`: `SolverConfig.corrected_pressure`. Held to the closed "
        f"form within {SETTLING_TOLERANCE:.0%} (docs/viscosity.md, 'Settling sphere')."
    )
    return rows, note


def _shear_rows(cell, law: str) -> list[dict[str, Any]]:
    """One row per speed of a :class:`~pourbench.fluids.validation.ShearCell`."""
    mid = len(cell.newtonian_speeds) // 2
    return [
        {
            "liquid": law,
            "rate_per_s": rate,
            "stress_pa": stress,
            "closed_form_pa": closed,
            "stress_over_closed_form": stress / closed,
            "wall_layer_speed": speeds[0],
            "mid_gap_speed": speeds[mid],
            "newtonian_mid_gap_speed": cell.newtonian_speeds[mid],
        }
        for rate, stress, closed, speeds in zip(
            cell.rates, cell.stresses, cell.closed_form, cell.speeds, strict=True
        )
    ]


def shear_cell_check(device: str = "cpu") -> tuple[list[dict[str, Any]], list[dict[str, Any]], str]:
    """The concentric-cylinder rheometer (:func:`~pourbench.fluids.validation.shear_cell`)
    with Newtonian liquids of :data:`~pourbench.fluids.validation.SHEAR_VISCOSITIES` and the
    Herschel–Bulkley test liquid: per-speed rows, one fit row per Newtonian liquid (stress
    at zero rate over the stress at the middle rate, slope over the viscosity), and a note."""
    print("fluids: a Couette rheometer, Newtonian and Herschel–Bulkley…", file=sys.stderr)
    cfg = SolverConfig(xsph_viscosity=0.0, device=device)
    rows, fits = [], []
    for mu in SHEAR_VISCOSITIES:
        cell = shear_cell(newtonian(mu), SHEAR_RATES, config=cfg)
        rows += _shear_rows(cell, f"{mu:g} Pa·s")
        intercept, slope = cell.fit()
        share = cell.yield_share()
        fits.append(
            {
                "viscosity_pa_s": mu,
                "stress_at_zero_rate_pa": intercept,
                "over_middle_stress": share,
                "slope_pa_s": slope,
                "slope_over_viscosity": slope / mu,
                "no_yield": "yes"
                if abs(share) <= YIELD_LIMIT and abs(slope / mu - 1.0) <= SLOPE_TOLERANCE
                else "no",
            }
        )
    liquid = yield_stress_liquid()
    rows += _shear_rows(shear_cell(liquid, YIELD_LAW_RATES, config=cfg), liquid.name)
    note = (
        "A cylinder of 2 cm radius turning inside a fixed cup of 4 cm, the annulus 6 cm deep "
        "(`validation.shear_cell`, 1000 kg/m³, FleX terms and XSPH off): the torque on the "
        "cylinder over 2π R₁² L against the closed form of the liquid's law in a long cell "
        "(`rheology.couette_inner_stress`), averaged over 0.5 s of steady flow. `rate_per_s` "
        "is a Newtonian liquid's rate at the cylinder. Speeds are azimuthal, over the wall's "
        "(Ω R₁), in the bin beside the cylinder and at mid-gap, mid-depth. A Newtonian "
        f"liquid shows no yield when the line through its stresses meets zero rate below "
        f"{YIELD_LIMIT:.0%} of its middle stress and its slope is its viscosity within "
        f"{SLOPE_TOLERANCE:.0%}. The Herschel–Bulkley liquid (`validation.yield_stress_liquid`) "
        "is a ketchup-like test law, not a shipped profile (docs/viscosity.md)."
    )
    return rows, fits, note
