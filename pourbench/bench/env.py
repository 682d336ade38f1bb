"""``pourbench bench env``: environment steps per second of Pour-v0, single and vectorised.

Cases: the single env and the vector env at 16, 64 and 256 worlds on the CPU (and on CUDA
when a device is present), default settings (liquid drawn from lesson 1, targets 50–200 g,
8 mm particles, 10 Hz control with 12 physics substeps). Each case resets once, takes two
warm-up steps, then steps with a fixed pouring action for a time budget; throughput counts
one step of one world as one environment step.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from typing import Any

import numpy as np

from pourbench.bench._report import devices, markdown_table, report_stem, write_report

COLUMNS = (
    "front_end",
    "device",
    "worlds",
    "particles",
    "g_per_particle",
    "env_steps_per_s",
    "s_per_vector_step",
)
TARGET_SINGLE_CPU = 200.0
HAS_CUDA = True


def cases(quick: bool, device: str = "auto") -> list[tuple[str, str, int]]:
    """(front end, device, worlds) of every case."""
    worlds = (16,) if quick else (16, 64, 256)
    out = []
    for dev in devices(device, quick):
        out.append(("single", dev, 1))
        out += [("vector", dev, n) for n in worlds]
    return out


def run_case(
    front_end: str, device: str, worlds: int, budget_s: float = 5.0, min_steps: int = 3
) -> dict[str, Any]:
    """Time one case (at least ``min_steps`` environment steps and ``budget_s`` seconds);
    returns a leaderboard row. An episode that ends is reset, as a training loop does (the
    vector env resets its worlds itself), and the resets count in the time."""
    from pourbench.envs import default_solver_config
    from pourbench.envs.pour import PourEnv
    from pourbench.envs.vector import PourVectorEnv

    scfg = dataclasses.replace(default_solver_config(), device=device)
    if front_end == "single":
        env = PourEnv(solver=scfg)
        env.reset(seed=0)
        action = np.array([0.5, 1.0], np.float32)
        batch = env.batch
    else:
        env = PourVectorEnv(worlds, solver=scfg)
        env.reset(seed=0)
        action = np.tile(np.array([0.5, 1.0], np.float32), (worlds, 1))
        batch = env.batch

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(action)
        if front_end == "single" and (terminated or truncated):
            env.reset()

    for _ in range(2):
        step()
    steps, t0 = 0, time.perf_counter()
    while steps < min_steps or time.perf_counter() - t0 < budget_s:
        step()
        steps += 1
    wall = time.perf_counter() - t0
    grams = np.mean([batch.solver.particle_mass(w) * 1e3 for w in range(worlds)])
    env.close()
    return {
        "front_end": front_end,
        "device": device,
        "worlds": worlds,
        "particles": int(batch.solver.num_particles),
        "g_per_particle": float(grams),
        "env_steps_per_s": worlds * steps / wall,
        "s_per_vector_step": wall / steps,
    }


def run(args: argparse.Namespace) -> int:
    rows = []
    choice = getattr(args, "device", "auto")
    for front, dev, n in cases(args.quick, choice):
        print(f"env: {front} {dev} {n} world(s)…", file=sys.stderr)
        rows.append(run_case(front, dev, n))
    body = "\n".join(
        [
            "`pourbench/Pour-v0` with its defaults: 8 mm particles (about 0.5 g of liquid "
            "each), physics at 120 Hz with 3 density iterations, 10 Hz control (12 substeps "
            "per environment step). `env_steps_per_s` = worlds × steps / wall time.",
            "",
            markdown_table(rows, COLUMNS),
            "",
            f"Target: ≥ {TARGET_SINGLE_CPU:g} steps/s for one CPU env.",
        ]
    )
    if not args.no_write:
        write_report(
            report_stem("env", choice),
            rows,
            out=args.out,
            title="Pour-v0: environment throughput",
            body_md=body,
        )
    if args.json:
        print(json.dumps({"suite": "env", "rows": rows}))
    else:
        print(markdown_table(rows, COLUMNS))
    return 0
