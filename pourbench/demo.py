"""``pourbench demo``: a pour on the CPU, with a rerun recording.

With a shipped PourNet policy (the first of :data:`DEMO_POLICIES` that ships), it pours
``--target-g`` of the liquid from ``--mass-g`` in the pouring container on
``pourbench/Pour-v0``, one episode, and prints the grams poured, spilled and left, the
scale's reading and the error. With none shipped (or with ``--scripted``), the liquid core
on its own: a source cup of ``--mass-g`` is tilted about its lip over a receiving cup
standing on a MuJoCo force sensor for ``--seconds``, and the poured / spilled / remaining
grams and the sensor's reading are printed. The recording is moved into place only when
the run finishes, so a failed run keeps the previous one. Other policies pour with
``pourbench eval``.
"""

from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

from pourbench.argtypes import positive_float, shipped_policies
from pourbench.errors import InvalidParameterError, check_positive
from pourbench.outputs import check_output_path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--liquid", default="water", help="liquid profile name")
    parser.add_argument(
        "--mass-g", type=positive_float, default=200.0, help="liquid in the source cup, g"
    )
    parser.add_argument("--seconds", type=positive_float, default=4.0, help="simulated time, s")
    parser.add_argument("--out", default="runs/demo.rrd", help="rerun recording to write")
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    parser.add_argument(
        "--target-g", type=positive_float, default=100.0, help="target of the policy's pour, g"
    )
    parser.add_argument(
        "--scripted", action="store_true", help="the scripted tilt even when a PourNet policy ships"
    )


DEMO_POLICIES = ("pournet-lstm", "pournet-mlp")
"""The shipped policies the demo pours with, in order of preference."""


def demo_policy() -> str | None:
    """The first of :data:`DEMO_POLICIES` that ships, or None when none does."""
    shipped = shipped_policies()
    return next((name for name in DEMO_POLICIES if name in shipped), None)


def run_demo(args: argparse.Namespace) -> int:
    """Run the demo with the parsed flags (also callable directly: every value is checked
    before the scene is built or the recording started)."""
    from pourbench.fluids.config import SolverConfig
    from pourbench.fluids.record import FluidRecorder
    from pourbench.fluids.scenarios import tilt_schedule, two_cup_scene
    from pourbench.fluids.solver import cuda_available

    mass_g = check_positive("mass_g", args.mass_g)
    seconds = check_positive("seconds", args.seconds)
    if args.device not in ("cpu", "cuda"):
        raise InvalidParameterError(f"device must be 'cpu' or 'cuda', got {args.device!r}")
    if args.device == "cuda" and not cuda_available():
        raise InvalidParameterError("--device cuda: Warp sees no CUDA device")
    config = SolverConfig(device=args.device)
    steps = round(seconds / config.dt)
    if steps < 1:
        raise InvalidParameterError(
            f"seconds must be at least one solver step ({config.dt:g} s), got {args.seconds!r}"
        )
    check_output_path(args.out)  # before the scene is built: a bad path fails at once
    policy = demo_policy()
    if policy is not None and not getattr(args, "scripted", False):
        return _policy_demo(args, policy, mass_g)
    scene = two_cup_scene(args.liquid, mass_g, config=config)
    solver = scene.solver
    rec = FluidRecorder(args.out, solver)
    try:  # interrupted or failed: keep the previous recording, leave no partial file
        frame = max(1, round(1 / 30 / solver.config.dt))  # record at 30 Hz
        print(
            f"pouring {mass_g:g} g of {solver.liquids[0].name} "
            f"({solver.num_particles} particles) for {seconds:g} s",
            file=sys.stderr,
        )
        bar = tqdm(range(steps), desc="simulating", unit="step", file=sys.stderr, mininterval=2)
        for k in bar:
            scene.set_tilt(tilt_schedule(solver.time))
            scene.step()
            if k % frame == 0:
                rec.log()
        out = rec.close()
    except BaseException:
        rec.discard()
        raise
    m = scene.metrics()
    print(f"poured into the receiving cup: {m.inside_g[1]:7.1f} g")
    print(f"spilled:                       {m.spilled_g:7.1f} g")
    print(f"remaining in the source cup:   {m.inside_g[0]:7.1f} g")
    print(f"still in flight:               {m.in_flight_g:7.1f} g")
    print(f"receiving cup's force sensor:  {scene.weight_g():7.1f} g")
    print(f"recording: {out.resolve()}  (open with `rerun {out}`)")
    return 1 if solver.diverged().any() else 0


def _policy_demo(args: argparse.Namespace, policy: str, mass_g: float) -> int:
    """One Pour-v0 episode of the shipped ``policy`` pouring ``args.target_g`` of
    ``args.liquid`` from ``mass_g``, recorded to ``args.out``."""
    from pourbench.agents.loading import load_policy
    from pourbench.envs.pour_v0 import PourEnv

    target_g = check_positive("target_g", getattr(args, "target_g", 100.0))
    if target_g >= mass_g:
        raise InvalidParameterError(
            f"target_g ({target_g:g} g) must be below mass_g ({mass_g:g} g), the liquid the "
            "pouring container starts with"
        )
    act = load_policy(policy)
    env = PourEnv(liquid=args.liquid, record_path=args.out)
    try:
        obs, info = env.reset(seed=0, options={"target_g": target_g, "initial_g": mass_g})
        print(
            f"{policy} pours {target_g:g} g of {info['liquid']} from {mass_g:g} g in the "
            f"pouring container {info['container']!r}",
            file=sys.stderr,
        )
        bar = tqdm(desc="pouring", unit="step", file=sys.stderr)
        new, done = True, False
        while not done:
            obs, _, term, trunc, info = env.step(act(obs, new))
            new, done = False, term or trunc
            bar.update()
        bar.close()
    except BaseException:  # interrupted or failed: keep the previous recording
        env.discard_recording()
        raise
    finally:
        env.close()
    print(f"poured into the receiving container: {info['poured_g']:7.1f} g")
    print(f"spilled:                             {info['spilled_g']:7.1f} g")
    print(f"left in the pouring container:       {info['remaining_g']:7.1f} g")
    print(f"scale reading (filtered):            {info['measured_g']:7.1f} g")
    print(f"error against the target:            {info['error_g']:7.1f} g")
    print(f"recording: {args.out}  (open with `rerun {args.out}`)")
    return 1 if info["sim_diverged"] else 0
