"""``pourbench demo``: the liquid core on its own, on the CPU.

A source cup filled with 200 g of water is tilted about its lip over a receiving cup standing
on a MuJoCo force sensor; the poured / spilled / remaining grams and the sensor's reading are
printed, and a rerun recording of particles and containers is written (moved into place only
when the run finishes, so a failed run keeps the previous one). The pouring task with its
PD baseline is ``pourbench eval``.
"""

from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

from pourbench.argtypes import positive_float
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


def run_demo(args: argparse.Namespace) -> int:
    """Run the demo with the parsed flags (also callable directly: every value is checked
    before the scene is built or the recording started)."""
    from pourbench.fluids.record import FluidRecorder
    from pourbench.fluids.scenarios import tilt_schedule, two_cup_scene
    from pourbench.fluids.solver import SolverConfig, cuda_available

    mass_g = check_positive("mass_g", args.mass_g)
    seconds = check_positive("seconds", args.seconds)
    if args.device not in ("cpu", "cuda"):
        raise InvalidParameterError(f"device must be 'cpu' or 'cuda', got {args.device!r}")
    if args.device == "cuda" and not cuda_available():
        raise ValueError("--device cuda: Warp sees no CUDA device")
    config = SolverConfig(device=args.device)
    steps = round(seconds / config.dt)
    if steps < 1:
        raise InvalidParameterError(
            f"seconds must be at least one solver step ({config.dt:g} s), got {args.seconds!r}"
        )
    check_output_path(args.out)  # before the scene is built: a bad path fails at once
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
