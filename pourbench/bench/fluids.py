"""``pourbench bench fluids``: particle-steps per second of the PBF solver.

A dam-break block (column of water, at most 25 cm tall, released in a tank) at about 2k, 16k
and 128k particles with 4 density iterations, on the CPU and, when present, CUDA (plus 1M+
particles, in one world and as many worlds). Each case also times
:mod:`pourbench.bench.fluids_baseline`, an all-cells-candidates PBF, in the same process, a
step of each in turn, so the speed-up is measured, not quoted. The cost rows time a pour
against its baseline the same way.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import warp as wp

from pourbench.bench._report import devices, markdown_table, report_stem, write_report
from pourbench.bench.fluids_baseline import BaselinePBF
from pourbench.bench.fluids_viscosity import (
    correction_cost,
    falling_ball_check,
    settling_check,
    shear_cell_check,
    timed_pours,
    viscosity_cost,
)
from pourbench.envs.core import default_solver_config
from pourbench.fluids.config import SolverConfig
from pourbench.fluids.params import liquid_profile
from pourbench.fluids.solver import PBFSolver
from pourbench.fluids.validation import (
    MARTIN_MOYCE,
    REST_FILLS_G,
    REST_LATE_WINDOW_S,
    REST_WINDOW_S,
    VISCOUS_ORDER,
    dam_break_fronts,
    deep_column,
    floating_box,
    free_drop,
    half_pour_times,
    rest_in_cup,
    scale_reading,
)
from pourbench.geometry.shapes import BoxShell

TARGET_CPU_PPS = 1_000_000  # issue target at 16k particles on one core
TARGET_CUDA_PPS = 1_000_000_000
SLEEP = 0.005  # m/s, the sleepThreshold of the rest check's second run (docs/rest.md)
HAS_CUDA = True


BLOCK_MAX_LAYERS = 50  # a column at most 50 particles (25 cm at the default spacing) tall


def _block(n: int, d: float) -> tuple[np.ndarray, BoxShell]:
    """A water column of about ``n`` particles and its tank: width a, depth a/2, height 2a,
    up to :data:`BLOCK_MAX_LAYERS` layers; larger blocks grow wider instead of taller (a
    pouring scene holds centimetres of liquid, and the foot of a metre-tall column with 4
    iterations compresses to twice its rest neighbour count and more)."""
    side = max(2, round(n ** (1 / 3)))  # nx = side, ny = side / 2, nz = 2 side
    nz = min(2 * side, BLOCK_MAX_LAYERS)
    nx = side if nz == 2 * side else max(2, round(math.sqrt(2.0 * n / nz)))
    ny = max(1, nx // 2)
    tank = BoxShell(
        half_x=2.0 * nx * d, half_y=0.5 * ny * d + 0.5 * d, depth=2.2 * nz * d, wall=0.01
    )
    xs = (np.arange(nx) + 0.5) * d - tank.half_x
    ys = (np.arange(ny) + 0.5) * d - 0.5 * ny * d
    zs = (np.arange(nz) + 0.5) * d + tank.bottom_z
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1), tank


def _time_alternated(
    steps: Sequence[Callable[[], Any]], sync: Callable[[], Any], budget_s: float, min_steps: int = 3
) -> list[tuple[float, float]]:
    """Seconds per step of each of ``steps``, stepped in turn (one step each, so that all see
    the same machine load) after their warm-up: the median and the fastest of each one's
    repeats (on a shared machine the median swings by a third between runs; the fastest step
    is the steadier measure of the code)."""
    times: list[list[float]] = [[] for _ in steps]
    t_end = time.perf_counter() + budget_s
    while len(times[0]) < min_steps or (time.perf_counter() < t_end and len(times[0]) < 50):
        for step, kept in zip(steps, times, strict=True):
            t0 = time.perf_counter()
            step()
            sync()
            kept.append(time.perf_counter() - t0)
    return [(float(np.median(t)), float(np.min(t))) for t in times]


def run_case(
    device: str, n: int, worlds: int = 1, budget_s: float = 2.0, pair_lists: str = "auto"
) -> dict[str, Any]:
    """Time the solver and the baseline on the dam-break block, step by step in turn; one row
    of the table. The solver runs a fixed 4 iterations, as the baseline does (no
    ``max_density_error`` extras). ``neighbours_mean`` is read after the warm-up step, so it
    does not depend on how many steps the time budget allowed."""
    cfg = SolverConfig(device=device, iterations=4, max_iterations=4, pair_lists=pair_lists)
    pts, tank = _block(n // worlds, cfg.spacing)
    solver = PBFSolver(worlds, cfg)
    for w in range(worlds):
        solver.add_container(w, tank)
        solver.add_particles(w, pts)
    sync = wp.synchronize
    solver.step()  # the warm-up: kernels loaded, buffers sized; not timed
    sync()
    neighbours = float(solver.neighbour_counts().mean())
    steps: list[Callable[[], Any]] = [solver.step]
    base = None
    if worlds == 1:
        lo = np.array([-tank.half_x, -tank.half_y, tank.bottom_z])
        hi = np.array([tank.half_x, tank.half_y, tank.rim_height])
        base = BaselinePBF(pts, lo, hi, cfg)
        base.step()
        sync()
        steps.append(base.step)
    timed = _time_alternated(steps, sync, budget_s)
    sec, best = timed[0]
    total = solver.num_particles
    row: dict[str, Any] = {
        "device": device,
        "particles": total,
        "worlds": worlds,
        "iterations": cfg.iterations,
        "pair_lists": "half" if solver.half_lists else "full",
        "ms_per_step": sec * 1e3,
        "particle_steps_per_s": total / sec,
        "best_particle_steps_per_s": total / best,
        "neighbours_mean": neighbours,
    }
    if base is not None:
        bsec = timed[1][0]
        row["baseline_particle_steps_per_s"] = base.n / bsec
        row["speedup_vs_baseline"] = bsec / sec
    return row


def cases(quick: bool, device: str = "auto") -> list[tuple[str, int, int, str]]:
    """(device, particles, worlds, pair-list mode) of every row; the device's default mode,
    plus the CPU at 16k with the CUDA default (full lists) for comparison and CUDA at 128k with
    the CPU default (half lists, summed with atomics)."""
    out = []
    for dev in devices(device, quick):
        if quick:
            out.append((dev, 16_000, 1, "auto"))
        elif dev == "cpu":
            out += [("cpu", n, 1, "auto") for n in (2_000, 16_000, 128_000)]
            out += [("cpu", 16_000, 1, "full")]
        else:
            out += [("cuda", n, 1, "auto") for n in (2_000, 16_000, 128_000, 1_024_000)]
            out += [("cuda", 128_000, 1, "half"), ("cuda", 1_024_000, 64, "auto")]
    return out


COLUMNS = [
    "device",
    "particles",
    "worlds",
    "iterations",
    "pair_lists",
    "ms_per_step",
    "particle_steps_per_s",
    "best_particle_steps_per_s",
    "baseline_particle_steps_per_s",
    "speedup_vs_baseline",
    "neighbours_mean",
]


def holding_cost(device: str = "cpu", seconds: float = 4.0) -> list[dict[str, Any]]:
    """What the extra iterations of ``SolverConfig.max_density_error`` cost: a water and a
    honey pour at Pour-v0's settings, each timed against the same pour on its fixed
    ``iterations`` (the solver without extras) in the same process, step by step in turn
    (:func:`~pourbench.bench.fluids_viscosity.timed_pours`); and the 30 cm column at the
    defaults, which on its fixed 4 iterations blows up."""
    rows = []
    base = dataclasses.replace(default_solver_config(), device=device)
    fixed = dataclasses.replace(base, max_iterations=base.iterations)
    settings = f"Pour-v0: {base.spacing * 1e3:g} mm, 1/{1 / base.dt:.0f} s, {base.iterations} its"
    for liquid in ("water", "honey"):
        print(f"fluids: holding cost, {liquid} pour at Pour-v0's settings…", file=sys.stderr)
        runs = timed_pours({"fixed": (liquid, fixed), "adaptive": (liquid, base)}, seconds)
        its = runs["adaptive"].density_iterations
        fixed_ms, ms = runs["fixed"].ms_per_step, runs["adaptive"].ms_per_step
        rows.append(
            {
                "scene": f"200 g {liquid} poured for {seconds:g} s",
                "settings": settings,
                "ms_per_step_fixed": fixed_ms,
                "ms_per_step": ms,
                "cost_ratio": ms / fixed_ms,
                "iterations_mean": float(its.mean()),
                "iterations_max": float(its.max()),
            }
        )
    print("fluids: holding cost, 30 cm column…", file=sys.stderr)
    cfg = SolverConfig(device=device)
    t0 = time.perf_counter()
    col = deep_column(window=(0.5, 1.0), config=cfg)
    steps = round(1.0 / cfg.dt)
    rows.append(
        {
            "scene": "30 cm water column, 4 × 4 cm box (fixed 4 its: blows up)",
            "settings": f"defaults: {cfg.spacing * 1e3:g} mm, 1/{1 / cfg.dt:.0f} s, "
            f"{cfg.iterations} its",
            "ms_per_step_fixed": None,
            "ms_per_step": 1e3 * (time.perf_counter() - t0) / steps,
            "cost_ratio": None,
            "iterations_mean": col.iterations,
            "iterations_max": None,
        }
    )
    return rows


def validation(device: str = "cpu") -> tuple[dict[str, Any], str]:
    """Run the physical validation experiments on ``device``; their numbers and a markdown
    table."""
    print(
        f"fluids: physical validation on {device} (rest, weight, floating box, free drop,"
        " viscous pours, dam break)…",
        file=sys.stderr,
    )
    rest, late = rest_in_cup(windows=(REST_WINDOW_S, REST_LATE_WINDOW_S), device=device)
    (asleep,) = rest_in_cup(windows=(REST_WINDOW_S,), device=device, sleep_threshold=SLEEP)
    fills = " / ".join(f"{m:g}" for m in REST_FILLS_G)
    t0, t1 = REST_WINDOW_S
    w50, w200 = scale_reading(50.0, device=device), scale_reading(200.0, device=device)
    afloat = floating_box(device=device)
    t_half, left = half_pour_times(device=device)
    fronts = dam_break_fronts(device=device)
    drop = free_drop(device=device)
    column = deep_column(config=SolverConfig(device=device))
    blowup = deep_column(window=(0.05, 0.3), config=SolverConfig(device=device, max_iterations=4))
    out: dict[str, Any] = {
        "device": device,
        "rest_density_error": rest.density_error,
        "rest_max_speed_m_s": rest.max_speed,
        "rest_median_max_speed_m_s": rest.median_max_speed,
        "rest_200g_fastest_m_s": rest.typical_fastest(200.0),
        "rest_late_200g_fastest_m_s": late.typical_fastest(200.0),
        "rest_p99_speed_m_s": rest.p99_speed,
        "rest_level_density_kg_m3": rest.level_density,
        "rest_late_max_speed_m_s": late.max_speed,
        "rest_late_density_error": late.density_error,
        "rest_asleep_max_speed_m_s": asleep.max_speed,
        "rest_asleep_density_error": asleep.density_error,
        "scale_50g_reads_g": w50,
        "scale_200g_reads_g": w200,
        "float_archimedes_draft_m": afloat.archimedes,
        "float_draft_m": afloat.draft,
        "float_column_difference_m": afloat.column_difference,
        "float_lift_over_weight": afloat.lift,
        "half_pour_time_s": dict(zip(VISCOUS_ORDER, t_half.tolist(), strict=True)),
        "residue_after_4s_g": dict(zip(VISCOUS_ORDER, left.tolist(), strict=True)),
        "dam_break_Z": {str(k): v for k, v in fronts.items()},
        "free_drop_rms_radius": drop,
        "column_bottom_density": column.bottom_density,
        "column_height_ratio": column.height_ratio,
        "column_lost": column.lost,
        "column_iterations": column.iterations,
        "column_fixed_4_diverged": blowup.diverged,
        "column_fixed_4_lost": blowup.lost,
    }
    lines = [
        "| check | measured | expected |",
        "|---|---|---|",
        f"| rest ({fills} g water, {t0:g}–{t1:g} s): largest bulk density error"
        f" | {rest.density_error:.4f} | ≤ 0.02 |",
        f"| rest: fastest particle, largest / median over samples (m/s) | {rest.max_speed:.4f}"
        f" / {rest.median_max_speed:.4f} | — |",
        f"| rest: the 200 g fill's fastest particle at its median sample (m/s) | "
        f"{rest.typical_fastest(200.0):.4f} | ≤ 0.03 |",
        f"| rest: p99 particle speed (m/s) | {rest.p99_speed:.4f} | ≤ 0.015 |",
        f"| rest: mass / volume below the liquid's level (kg/m³) | {rest.level_density:.0f}"
        " | 1000 ± 2 % |",
        f"| rest at {REST_LATE_WINDOW_S[0]:g}–{REST_LATE_WINDOW_S[1]:g} s: the 200 g fill's"
        f" fastest particle at its median sample / fastest of all (m/s) / bulk density error |"
        f" {late.typical_fastest(200.0):.4f} / {late.max_speed:.4f} / {late.density_error:.4f}"
        " | ≤ 0.02 / ≤ 0.03 / ≤ 0.02 |",
        f"| rest at {t0:g}–{t1:g} s with sleepThreshold {SLEEP * 100:g} cm/s: fastest particle"
        f" (m/s) / bulk density error | {asleep.max_speed:.4f} / {asleep.density_error:.4f}"
        " | ≤ 0.02 / ≤ 0.02 |",
        f"| force sensor, 50 g settled (g) | {w50:.2f} | 50 ± 1 |",
        f"| force sensor, 200 g settled (g) | {w200:.2f} | 200 ± 4 |",
        f"| floating 500 kg/m³ box: liquid's lift / weight | {afloat.lift:.3f} | 1 |",
        f"| floating box: water column beside it − under it (mm) | "
        f"{afloat.column_difference * 1e3:.1f} | {afloat.archimedes * 1e3:.1f} (Archimedes) |",
        f"| floating box: draft below the water level (mm) | {afloat.draft * 1e3:.1f} | "
        f"{afloat.archimedes * 1e3:.1f} (Archimedes; deeper where liquid packs denser: "
        "the box's edges) |",
        "| free 8³ drop of water in zero gravity: rms radius at 0 / 0.25 / 0.5 / 1 s (ball radii)"
        f" | {' / '.join(f'{r:.3f}' for r in drop)} | grows ≤ 20 % |",
    ]
    for liq, t, g in zip(VISCOUS_ORDER, t_half, left, strict=True):
        lines.append(
            f"| {liq} ({liquid_profile(liq).viscosity_pa_s:g} Pa·s): half-pour time (s) / left"
            f" after 4 s (g) | {t:.3f} / {g:.1f} | water, ink, oil within 2 %; then increasing |"
        )
    lines += [
        f"| 30 cm column (4 × 4 cm box, 0.5–1 s): lowest 2 cm mass / volume over rest | "
        f"{column.bottom_density:.3f} | ≤ 1.03 |",
        f"| 30 cm column: surface over its rest-density height | {column.height_ratio:.3f} | "
        "1 ± 0.03 |",
        f"| 30 cm column: particles out of the box / density iterations a step | {column.lost}"
        f" / {column.iterations:.1f} | 0 / — |",
        f"| 30 cm column on a fixed 4 iterations (0.05–0.3 s): flagged diverged / particles "
        f"out | {blowup.diverged} / {blowup.lost} | blows up, flagged |",
    ]
    for T, z in fronts.items():
        lines.append(
            f"| dam break Z at T = {T:g} | {z:.2f} | {MARTIN_MOYCE[T]:.2f} ± 15 % "
            "(Martin & Moyce 1952) |"
        )
    return out, "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    rows = []
    choice = getattr(args, "device", "auto")
    for device, n, worlds, lists in cases(args.quick, choice):
        print(
            f"fluids: {device} ~{n} particles, {worlds} world(s), {lists} lists…", file=sys.stderr
        )
        rows.append(run_case(device, n, worlds, pair_lists=lists))
        rate = rows[-1]["particle_steps_per_s"]
        print(
            f"fluids:   {rows[-1]['particles']} particles, {rate:.3g} particle-steps/s",
            file=sys.stderr,
        )
    checks_device = "cuda" if choice == "cuda" else "cpu"
    checks, checks_md = ({}, "") if args.quick else validation(checks_device)
    hold = [] if args.quick else holding_cost(checks_device)
    visc_cost = [] if args.quick else viscosity_cost(checks_device)
    corr_cost = [] if args.quick else correction_cost(checks_device)
    ball, ball_note = ([], "") if args.quick else falling_ball_check(checks_device)
    settling, settling_note = ([], "") if args.quick else settling_check(checks_device)
    shear, shear_fits, shear_note = ([], [], "") if args.quick else shear_cell_check(checks_device)
    body = "\n".join(
        [
            "Dam-break block in a tank (width a, height 2a, at most 25 cm tall: larger blocks "
            "grow wider), 4 Jacobi density iterations, dt = 1/240 s, spacing 5 mm "
            "(h = 1 cm). `particle_steps_per_s` = particles × steps / wall time of "
            "`PBFSolver.step` (median step; `best_…` from the fastest step). The baseline is "
            "an all-cells-candidates PBF "
            "(`pourbench/bench/fluids_baseline.py`: hash-grid query in every pass, no "
            "viscosity/vorticity/SDF collisions) timed in the same process, a step of each "
            "in turn. `pair_lists`: "
            "half lists (each pair once, added to both particles; the CPU default) or full "
            "lists (each particle sums its own side, lists interleaved so a GPU warp reads "
            "them coalesced; the CUDA default, reproducible without atomics between threads).",
            "",
            markdown_table(rows, COLUMNS),
            "",
            f"Targets: ≥ {TARGET_CPU_PPS:,} particle-steps/s at 16k particles on one CPU core; "
            f"≥ {TARGET_CUDA_PPS:,} on CUDA at 1M+ particles. Warp runs CPU kernels on one core. "
            "`pourbench bench fluids --device cuda` writes the CUDA rows alone to "
            "`fluids_cuda.md`.",
            "",
            f"## Cost of liquid that holds ({checks_device})" if hold else "",
            "",
            "A world iterates past `iterations` while some particle is more than "
            "`max_density_error` too dense (`SolverConfig`; Pour-v0 15 %, the defaults 1.5 %). "
            "`ms_per_step_fixed`: the same run on its fixed `iterations`, in the same process."
            if hold
            else "",
            "",
            markdown_table(hold) if hold else "",
            "",
            f"## Cost of the physical viscosity ({checks_device})" if visc_cost else "",
            "",
            "Pour-v0's settings; `ms_per_step_flex`: the same liquid as a FleX-only profile "
            "(XSPH by its FleX coefficient, no implicit solve), in the same process. "
            "`viscosity_iterations`: the implicit solve's conjugate-gradient iterations a step "
            "(docs/viscosity.md)."
            if visc_cost
            else "",
            "",
            markdown_table(visc_cost) if visc_cost else "",
            "",
            f"## Cost of the corrected pressure ({checks_device})" if corr_cost else "",
            "",
            "A Pour-v0 environment step with `SolverConfig.corrected_pressure` on; "
            "`ms_per_step_plain`: the same environment with it off, in the same process, "
            "stepped in turn with the same actions (docs/viscosity.md)."
            if corr_cost
            else "",
            "",
            markdown_table(corr_cost) if corr_cost else "",
            "",
            f"## Physical checks ({checks_device})" if checks_md else "",
            "",
            checks_md,
            "",
            f"## Falling ball, thesis §3.3 ({checks_device})" if ball else "",
            "",
            ball_note,
            "",
            markdown_table(ball) if ball else "",
            "",
            f"## Settling against the closed form ({checks_device})" if settling else "",
            "",
            settling_note,
            "",
            markdown_table(settling) if settling else "",
            "",
            f"## Shear cell: stress against rate ({checks_device})" if shear else "",
            "",
            shear_note,
            "",
            markdown_table(shear_fits) if shear_fits else "",
            "",
            markdown_table(shear) if shear else "",
        ]
    )
    if not args.no_write:
        write_report(
            report_stem("fluids", choice),
            rows,
            out=args.out,
            title="Fluid solver: throughput and physical checks",
            body_md=body,
            extra={
                "validation": checks,
                "holding_cost": hold,
                "viscosity_cost": visc_cost,
                "correction_cost": corr_cost,
                "falling_ball": ball,
                "settling": settling,
                "shear_cell": shear,
                "shear_cell_fits": shear_fits,
            }
            if checks
            else None,
        )
    if args.json:
        print(json.dumps({"suite": "fluids", "rows": rows, "validation": checks, "holding": hold}))
    else:
        print(markdown_table(rows, COLUMNS))
    return 0
