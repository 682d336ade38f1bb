"""``pourbench bench env``: environment steps per second of Pour-v0, single and vectorised.

Cases: the single env, and the vector env at 16, 64 and 256 worlds with 1 and with 2 worker
processes on the CPU; on CUDA (when a device is present) the single env and 256, 1024 and
4096 worlds in one process. Default settings (liquid drawn from lesson 1, targets 50–200 g,
8 mm particles, 10 Hz control with 12 physics substeps). Each case resets once, takes two
warm-up steps, then steps with a fixed pouring action for a time budget; throughput counts
one step of one world as one environment step; every case alternates step by step with the
world-by-world step (:mod:`pourbench.bench.env_baseline`, in this
process, on the same worlds), whose throughput and the speed-up over it are in the last
columns. ``host_share`` is the share of the processes'
time outside the solver's steps: 1 − (solver seconds summed over the processes) / (workers ×
wall time); on CUDA the device is synchronised around each solver step to time its kernels.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from pourbench.bench._report import devices, markdown_table, report_stem, write_report
from pourbench.bench.env_pinned import PINNED_SHA, PinnedPour, source_tree
from pourbench.bench.env_robot import ROBOT_CASES, robot_case
from pourbench.errors import InvalidParameterError

TARGET_SINGLE_CPU = 200.0
TARGET_VECTOR_CPU = 400.0  # 64 worlds on 2 workers
HAS_CUDA = True
CPU_WORLDS = (16, 64, 256)
CUDA_WORLDS = (256, 1024, 4096)
CPU_WORKERS = (1, 2)

POUR_ACTION = np.array([0.5, 1.0], np.float32)
"""The fixed action every case steps with: Algorithm 4's (ω, r), rotation at half its limit
and translation at full, so the container moves over the receiving one and pours."""


def cases(quick: bool, device: str = "auto") -> list[tuple[str, str, int]]:
    """(front end, device, worlds) of every case (each vector case on the CPU runs with every
    count of :func:`workers_for`)."""
    out = []
    for dev in devices(device, quick):
        worlds = (16,) if quick else (CUDA_WORLDS if dev == "cuda" else CPU_WORLDS)
        out.append(("single", dev, 1))
        out += [("vector", dev, n) for n in worlds]
    return out


def workers_for(front_end: str, device: str) -> tuple[int, ...]:
    """Worker counts timed for a case: the CPU's vector env with 1 and 2, else 1."""
    return CPU_WORKERS if (front_end == "vector" and device == "cpu") else (1,)


def run_case(
    front_end: str,
    device: str,
    worlds: int,
    budget_s: float = 5.0,
    min_steps: int = 3,
    workers: int = 1,
    pinned: Path | None = None,
) -> dict[str, Any]:
    """Time one case (at least ``min_steps`` environment steps and ``budget_s`` seconds);
    returns a leaderboard row. An episode that ends is reset, as a training loop does (the
    vector env resets its worlds itself), and the resets count in the time. The same worlds
    stepped by :class:`~pourbench.bench.env_baseline.LoopedPourBatch` (the world-by-world
    step, in this process) alternate step by step with the case, so both see the same
    machine load, until the baseline has had ``budget_s`` and ``min_steps`` of its own.
    With ``pinned`` (an earlier commit's source tree, :mod:`pourbench.bench.env_pinned`) the
    same case as that code steps it, in child processes on ``workers`` processes, alternates
    with them the same way."""
    from pourbench.envs import PourConfig, default_solver_config
    from pourbench.envs.pour_v0 import PourEnv
    from pourbench.envs.vector import PourVectorEnv

    scfg = dataclasses.replace(default_solver_config(), device=device)
    sync = device != "cpu"
    if front_end == "single":
        env = PourEnv(solver=scfg)
        env.reset(seed=0)
        action = POUR_ACTION
        env.batch.time_solver(sync)

        def solver_s() -> float:
            return env.batch.solver_seconds

        def particles() -> tuple[int, float]:
            return env.batch.solver.num_particles, env.batch.particle_g[0]

    else:
        env = PourVectorEnv(worlds, workers=workers, solver=scfg)
        env.reset(seed=0)
        action = np.tile(POUR_ACTION, (worlds, 1))
        env.solver_seconds(sync)

        def solver_s() -> float:
            return float(sum(env.solver_seconds()))

        def particles() -> tuple[int, float]:
            counts = [env.call_world(w, _particles) for w in range(worlds)]
            return sum(n for n, _ in counts), float(np.mean([g for _, g in counts]))

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(action)
        if front_end == "single" and (terminated or truncated):
            env.reset()

    looped = _Looped(worlds, PourConfig(solver=scfg))
    old = None if pinned is None else PinnedPour(pinned, front_end, worlds, workers)
    for _ in range(2):
        step()
        looped.step()
    steps, base_steps, s0, wall, base_wall = 0, 0, solver_s(), 0.0, 0.0
    old_steps, old_wall = 0, 0.0
    try:
        while steps < min_steps or wall < budget_s:
            t0 = time.perf_counter()
            step()
            wall += time.perf_counter() - t0
            steps += 1
            # the baselines alternate with the case until each has had its own budget (where
            # one is far slower, as at thousands of CUDA worlds, it takes fewer steps)
            if base_steps < min_steps or base_wall < budget_s:
                t0 = time.perf_counter()
                looped.step()
                base_wall += time.perf_counter() - t0
                base_steps += 1
            if old is not None and (old_steps < min_steps or old_wall < budget_s):
                old_wall += old.step()
                old_steps += 1
    finally:
        if old is not None:
            old.close()
    in_solver = solver_s() - s0
    count, grams = particles()
    env.close()
    pinned_row = {}
    if old is not None:
        pinned_row = {
            "pinned_env_steps_per_s": worlds * old_steps / old_wall,
            "speedup_vs_pinned": (old_wall / old_steps) / (wall / steps),
        }
    return {
        "front_end": front_end,
        "device": device,
        "worlds": worlds,
        "workers": workers,
        "particles": int(count),
        "g_per_particle": float(grams),
        "env_steps_per_s": worlds * steps / wall,
        "s_per_vector_step": wall / steps,
        "host_share": max(0.0, 1.0 - in_solver / (workers * wall)),
        "baseline_env_steps_per_s": worlds * base_steps / base_wall,
        "speedup_vs_baseline": (base_wall / base_steps) / (wall / steps),
        **pinned_row,
    }


class _Looped:
    """The baseline's worlds, reset with seed ``k`` for world ``k`` and reset again when
    their episode ends (as the vector env does)."""

    def __init__(self, worlds: int, config: Any) -> None:
        from pourbench.bench.env_baseline import LoopedPourBatch

        self.batch = LoopedPourBatch(worlds, config)
        for w in range(worlds):
            self.batch.reset_world(w, seed=w)
        self.batch.flush()
        self.action = np.tile(POUR_ACTION.astype(np.float64), (worlds, 1))

    def step(self) -> None:
        _, _, terminated, truncated, _ = self.batch.step(self.action)
        done = np.flatnonzero(terminated | truncated)
        for w in done:
            self.batch.reset_world(int(w))
        if len(done):
            self.batch.flush()


def _particles(batch: Any, world: int) -> tuple[int, float]:
    """(particles, grams a particle) of one world (run in the process holding it)."""
    sl = batch.solver.world_slice(world)
    return sl.stop - sl.start, float(batch.particle_g[world])


def pinned_tree(against: str | None, quick: bool) -> tuple[Path | None, str | None]:
    """The source tree and full SHA of the commit the CPU cases alternate with: ``against``
    ("none": no comparison), by default :data:`PINNED_SHA` (none with ``quick``). Refused
    when asked for explicitly outside the project's git checkout; the default is then left
    out with a line on stderr."""
    if against is None and quick:
        return None, None
    if against is not None and against.lower() == "none":
        return None, None
    repo = Path(__file__).resolve().parents[2]
    try:
        tree = source_tree(against or PINNED_SHA, repo)
    except InvalidParameterError as exc:
        if against is not None:
            raise
        print(f"env: no pinned comparison ({exc})", file=sys.stderr)
        return None, None
    return tree, tree.name


def run(args: argparse.Namespace) -> int:
    rows = []
    choice = getattr(args, "device", "auto")
    tree, pinned_sha = pinned_tree(getattr(args, "against", None), args.quick)
    for front, dev, n in cases(args.quick, choice):
        for workers in workers_for(front, dev):
            print(f"env: {front} {dev} {n} world(s), {workers} worker(s)…", file=sys.stderr)
            pinned = tree if dev == "cpu" else None
            rows.append(run_case(front, dev, n, workers=workers, pinned=pinned))
    robot_rows = []
    if not args.quick and choice != "cuda":
        for robot, planner in ROBOT_CASES:
            print(f"env: PourRobot-v0, {robot}, {planner}…", file=sys.stderr)
            robot_rows.append(robot_case(robot, planner))
    body = "\n".join(
        [
            "`pourbench/Pour-v0` with its defaults: 8 mm particles (about 0.5 g of liquid "
            "each), physics at 120 Hz with 3 density iterations (more in a world while some "
            "particle is over 15 % too dense), 10 Hz control (12 substeps per environment "
            "step). `env_steps_per_s` = worlds × steps / wall time; "
            "`workers`: processes the vector env's worlds are spread over; `host_share`: "
            "1 − (time in the solver's steps, summed over the processes) / (workers × wall "
            "time); `baseline_env_steps_per_s`: the same worlds stepped as before the batched "
            "step (per-world MuJoCo stepping, coupling, sensor and evaluation loops; "
            "`pourbench/bench/env_baseline.py`), in the same process, alternating step by step "
            "with the case (until it has had its own time budget); `speedup_vs_baseline` = "
            "its time a step / the case's."
            + (
                f" `pinned_env_steps_per_s`: the same case as the code at `{pinned_sha[:7]}` "
                "steps it (the last commit before the batched step; "
                "`pourbench/bench/env_pinned.py`), in child processes of this venv, one per "
                "worker, alternating step by step with the case; `speedup_vs_pinned` = its "
                "time a step / the case's: what a user of that code gains."
                if pinned_sha
                else ""
            ),
            "",
            markdown_table(rows),
            "",
            f"Targets: ≥ {TARGET_SINGLE_CPU:g} steps/s for one CPU env, ≥ "
            f"{TARGET_VECTOR_CPU:g} for 64 worlds on 2 CPU workers.",
            "",
            "## PourRobot-v0 (cpu)" if robot_rows else "",
            "",
            "One `pourbench/PourRobot-v0` (water, 100 g) with each robot and planner, and a "
            "single Pour-v0 env (water, 100 g) stepped in the same process, alternating step "
            "by step (`pourbench/bench/env_robot.py`). `planner_ms_per_step`: the planner's "
            "own solve time in a step."
            if robot_rows
            else "",
            "",
            markdown_table(robot_rows) if robot_rows else "",
        ]
    )
    if not args.no_write:
        write_report(
            report_stem("env", choice),
            rows,
            out=args.out,
            title="Pour-v0: environment throughput",
            body_md=body,
            extra={"robot": robot_rows} if robot_rows else None,
        )
    if args.json:
        print(json.dumps({"suite": "env", "rows": rows, "robot": robot_rows}))
    else:
        print(markdown_table(rows))
    return 0
