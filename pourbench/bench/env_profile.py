"""Where a Pour-v0 environment step spends its time (a profile, not a leaderboard suite).

``python -m pourbench.bench.env_profile --worlds 64 --steps 12`` steps Pour-v0 (the single
env for one world, else a vector env on one worker) with the pouring action of
``pourbench bench env`` and prints two tables in milliseconds per environment step:

- the step's parts: the solver's recorded kernels (graph replays), the solver's own host
  work (pose upload, read-backs, checks) and the env's host work by stage, each as the wall
  time of the calls that do it;
- the solver by kernel: the same run with the graphs off (``SolverConfig.graph=False``), each
  recorded launch timed on its own; Warp runs CPU kernels inside the call, so on the CPU a
  launch's time is its kernel's plus the replay of its packed arguments (about 1 µs).

Timers wrap the named functions for the run and are removed after it.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import dataclasses
import functools
import time
from collections import Counter
from collections.abc import Iterator
from typing import Any

import numpy as np

ACTION = (0.5, 1.0)  # the pouring action of pourbench bench env


@contextlib.contextmanager
def timed(targets: dict[str, tuple[Any, str]]) -> Iterator[tuple[dict[str, float], Counter]]:
    """Wrap each ``(owner, attribute)`` of ``targets`` with a wall-clock timer for the
    ``with`` block; yields the seconds spent in each and its calls, by label (the originals
    come back on exit)."""
    seconds: dict[str, float] = collections.defaultdict(float)
    calls: Counter = collections.Counter()
    saved = []
    for label, (owner, name) in targets.items():
        original = getattr(owner, name)
        saved.append((owner, name, original))
        setattr(owner, name, _timer(original, label, seconds, calls))
    try:
        yield seconds, calls
    finally:
        for owner, name, original in reversed(saved):
            setattr(owner, name, original)


def _timer(fn: Any, label: str, seconds: dict[str, float], calls: Counter) -> Any:
    @functools.wraps(fn)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            seconds[label] += time.perf_counter() - t0
            calls[label] += 1

    return wrapped


def _make(worlds: int, graph: bool) -> tuple[Any, Any, np.ndarray]:
    """(env, its PourBatch, action) with the env's default solver, graphs on or off, after
    two warm-up steps."""
    from pourbench.envs import default_solver_config
    from pourbench.envs.pour_v0 import PourEnv
    from pourbench.envs.vector import PourVectorEnv

    scfg = dataclasses.replace(default_solver_config(), graph=graph)
    if worlds == 1:
        env = PourEnv(solver=scfg)
        action = np.array(ACTION, np.float32)
    else:
        env = PourVectorEnv(worlds, workers=1, solver=scfg)
        action = np.tile(np.array(ACTION, np.float32), (worlds, 1))
    env.reset(seed=0)
    for _ in range(2):
        env.step(action)
    return env, env.unwrapped.batch if worlds == 1 else env.batch, action


def _run(env: Any, action: np.ndarray, steps: int, single: bool) -> float:
    """Step ``steps`` times (the single env resets when its episode ends); wall seconds."""
    t0 = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(action)
        if single and (terminated or truncated):
            env.reset()
    return time.perf_counter() - t0


def step_parts(worlds: int, steps: int) -> tuple[dict[str, float], dict[str, Any]]:
    """Milliseconds per environment step by part (graphs on), and facts of the run
    (particles, ms and env steps/s)."""
    import warp as wp

    from pourbench.envs import core
    from pourbench.fluids import coupling, solver

    env, batch, action = _make(worlds, graph=True)
    S, B = solver.PBFSolver, core.PourBatch
    targets = {
        "solver kernels (graph replays)": (wp, "capture_launch"),
        "solver.step": (S, "step"),
        "solver host: pose upload, wall-speed bound": (S, "_upload_poses"),
        "env: action handler": (core, "handle_actions"),
        "env: set_collider_poses": (S, "set_collider_poses"),
        "env: reaction log": (coupling.ReactionLog, "record"),
        "env: sensor samples and filter": (B, "_sense"),
        "env: divergence test": (S, "diverged"),
        "env: liquid accounting": (B, "measure"),
        "env: collision test": (B, "collided"),
        "env: observation": (B, "observe"),
    }
    with timed(targets) as (sec, _):
        wall = _run(env, action, steps, worlds == 1)
    particles = batch.solver.num_particles
    env.close()
    ms = {k: 1e3 * v / steps for k, v in sec.items()}
    step_ms = ms.pop("solver.step")
    kernels = ms["solver kernels (graph replays)"]
    upload = ms["solver host: pose upload, wall-speed bound"]
    ms["solver host: other (read-backs, checks, clock)"] = step_ms - kernels - upload
    env_ms = sum(v for k, v in ms.items() if k.startswith("env:"))
    ms["env: other"] = 1e3 * wall / steps - step_ms - env_ms
    facts = {
        "particles": particles,
        "ms_per_env_step": 1e3 * wall / steps,
        "env_steps_per_s": worlds * steps / wall,
    }
    return ms, facts


def kernel_times(worlds: int, steps: int) -> dict[str, tuple[float, float]]:
    """Per recorded launch (and Warp's sort and scan): (ms per environment step, calls per
    environment step), graphs off."""
    import warp as wp

    from pourbench.fluids import step

    env, _, action = _make(worlds, graph=False)
    seconds: dict[str, float] = collections.defaultdict(float)
    calls: Counter = collections.Counter()
    launch = step.StepLaunches.launch

    def timed_launch(self: Any, key: str, *args: Any, **kwargs: Any) -> None:
        t0 = time.perf_counter()
        launch(self, key, *args, **kwargs)
        seconds[key] += time.perf_counter() - t0
        calls[key] += 1

    sort_scan = {name: (wp.utils, name) for name in ("radix_sort_pairs", "array_scan")}
    step.StepLaunches.launch = timed_launch
    try:
        with timed(sort_scan) as (sec, n):
            _run(env, action, steps, worlds == 1)
    finally:
        step.StepLaunches.launch = launch
    env.close()
    seconds.update(sec)
    calls.update(n)
    return {k: (1e3 * v / steps, calls[k] / steps) for k, v in seconds.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=1, help="1: the single env")
    parser.add_argument("--steps", type=int, default=100, help="environment steps timed")
    args = parser.parse_args(argv)
    parts, facts = step_parts(args.worlds, args.steps)
    total = facts["ms_per_env_step"]
    print(
        f"Pour-v0, {args.worlds} world(s), {facts['particles']} particles: {total:.2f} ms per "
        f"vector step, {facts['env_steps_per_s']:.1f} env steps/s\n"
    )
    print("| part | ms per env step | share |\n|---|---|---|")
    for k, v in parts.items():
        print(f"| {k} | {v:.3f} | {v / total:.1%} |")
    kernels = kernel_times(args.worlds, args.steps)
    summed = sum(v for v, _ in kernels.values())
    print(f"\nGraphs off, by launch (sum {summed:.2f} ms per env step):\n")
    print("| launch | ms per env step | calls per env step | share |\n|---|---|---|---|")
    for k, (v, n) in sorted(kernels.items(), key=lambda kv: -kv[1][0]):
        print(f"| {k} | {v:.3f} | {n:.1f} | {v / summed:.1%} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
