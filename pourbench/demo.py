"""``pourbench demo``: pour 200 g of water from one cup into another and record it.

Until the pouring environment lands this is the liquid core's demo: a source cup filled with
200 g of water is tilted about its lip over a receiving cup standing on a force sensor; the
poured / spilled / remaining grams and the sensor's reading are printed, and a rerun
recording of particles and containers is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm import tqdm


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--liquid", default="water", help="liquid profile name")
    parser.add_argument("--mass-g", type=float, default=200.0, help="liquid in the source cup")
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated time")
    parser.add_argument("--out", default="runs/demo.rrd", help="rerun recording path")
    parser.add_argument("--device", default="cpu", help='"cpu" or "cuda"')


def run_demo(args: argparse.Namespace) -> int:
    from pourbench.fluids.record import FluidRecorder
    from pourbench.fluids.scenarios import tilt_schedule, two_cup_scene
    from pourbench.fluids.solver import SolverConfig

    scene = two_cup_scene(args.liquid, args.mass_g, config=SolverConfig(device=args.device))
    solver = scene.solver
    out = Path(args.out)
    rec = FluidRecorder(out, solver)
    steps = round(args.seconds / solver.config.dt)
    frame = max(1, round(1 / 30 / solver.config.dt))  # record at 30 Hz
    print(
        f"pouring {args.mass_g:g} g of {solver.liquids[0].name} "
        f"({solver.num_particles} particles) for {args.seconds:g} s",
        file=sys.stderr,
    )
    for k in tqdm(range(steps), desc="simulating", unit="step", file=sys.stderr, mininterval=2):
        scene.set_tilt(tilt_schedule(solver.time))
        scene.step()
        if k % frame == 0:
            rec.log()
    rec.close()
    m = scene.metrics()
    print(f"poured into the receiving cup: {m.inside_g[1]:7.1f} g")
    print(f"spilled:                       {m.spilled_g:7.1f} g")
    print(f"remaining in the source cup:   {m.inside_g[0]:7.1f} g")
    print(f"still in flight:               {m.in_flight_g:7.1f} g")
    print(f"receiving cup's force sensor:  {scene.weight_g():7.1f} g")
    print(f"recording: {out.resolve()}  (open with `rerun {out}`)")
    return 1 if solver.diverged().any() else 0
