"""pourbench: liquid-pouring benchmarks on MuJoCo and a Warp position-based-fluids solver.

The ``pourbench`` console script. Subcommands import their heavy modules lazily so
``pourbench --help`` stays fast. Each benchmark suite is a module ``pourbench.bench.<suite>``
exposing ``run(args) -> int``; a suite with a CUDA path sets ``HAS_CUDA = True`` and reads
``args.device``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from pourbench.argtypes import nonnegative_int, policy_name, positive_float, positive_int
from pourbench.errors import InvalidParameterError, PourbenchError

BENCH_SUITES = ("fluids", "teleop", "planning", "env", "transfer", "pouring", "ablation")


def _cmd_bench(args: argparse.Namespace) -> int:
    suites = BENCH_SUITES if args.suite == "all" else (args.suite,)
    modules = [importlib.import_module(f"pourbench.bench.{suite}") for suite in suites]
    if getattr(args, "ray", None) is not None:
        if not all(getattr(m, "HAS_RAY", False) for m in modules):
            raise InvalidParameterError(
                f"--ray: bench {args.suite} has no Ray path; pouring and transfer do"
            )
        from pourbench.bench._jobs import import_ray

        import_ray()  # before any work: says how to install it
    against = getattr(args, "against", None)
    if against is not None:
        if "env" not in suites:
            raise InvalidParameterError(f"--against: bench {args.suite} has no pinned comparison")
        if against.lower() != "none":
            from pourbench.bench.env_pinned import resolve_commit

            resolve_commit(against, Path(__file__).resolve().parent.parent)
    if getattr(args, "finished", False) and "ablation" not in suites:
        raise InvalidParameterError(f"--finished: bench {args.suite} has no recorded runs")
    if args.device == "cuda":
        from pourbench.fluids.solver import cuda_available

        if not cuda_available():
            raise InvalidParameterError("--device cuda: Warp sees no CUDA device")
        modules = [m for m in modules if getattr(m, "HAS_CUDA", False)]
        if not modules:
            raise InvalidParameterError(f"bench {args.suite} has no CUDA path; use --device cpu")
    if getattr(args, "out", None) is None:  # a quick run is a smoke test: no tables
        args.out = "leaderboard"
        if args.quick and not args.no_write:
            args.no_write = True
            print("--quick: leaderboard not written (give --out to write it)", file=sys.stderr)
    if not args.no_write:
        from pourbench.outputs import check_output_folder

        check_output_folder(args.out)  # before any work: a bad folder fails in a second
    if not (args.json and len(modules) > 1):
        rc = 0
        for module in modules:
            rc |= module.run(args)
        return rc
    # several suites, one JSON object: {"suites": [each suite's object, in order]}
    rc, docs = 0, []
    for module in modules:
        with contextlib.redirect_stdout(io.StringIO()) as captured:
            rc |= module.run(args)
        docs.append(json.loads(captured.getvalue()))
    print(json.dumps({"suites": docs}, default=str))
    return rc


def _cmd_eval(args: argparse.Namespace) -> int:
    from pourbench.agents.evaluate import evaluate

    result = evaluate(
        args.policy,
        args.episodes,
        args.target_g,
        seed=args.seed,
        progress=True,
        liquid=args.liquid,
        container_set=args.containers,
    )
    for k, (e, s) in enumerate(zip(result.errors_g, result.spilled_g, strict=True)):
        print(f"episode {k}: error {e:6.2f} g  spill {s:6.2f} g  steps {result.steps[k]}")
    print(f"{args.policy} on {args.liquid}, target {args.target_g:g} g: {result.summary()}")
    return 0


def _print_table(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
    """Columns left-aligned to their widest cell, under a header and a rule."""
    widths = [max(len(r[i]) for r in (header, *rows)) for i in range(len(header))]
    for row in (header, tuple("-" * w for w in widths), *rows):
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())


def _cmd_liquids(args: argparse.Namespace) -> int:
    from pourbench.fluids import liquid_names, liquid_profile

    rows = []
    for name in liquid_names():
        p = liquid_profile(name)
        mu = "-" if p.viscosity_pa_s is None else f"{p.viscosity_pa_s:g}"
        rows.append(
            (name.lower(), f"{p.density:g}", mu, f"{p.viscosity:g}", f"{p.adhesion:g}",
             f"{p.cohesion:g}", f"{p.surface_tension:g}")
        )  # fmt: skip
    _print_table(
        ("name", "density kg/m^3", "viscosity Pa*s", "FleX viscosity", "adhesion", "cohesion",
         "surface tension"),
        rows,
    )  # fmt: skip
    return 0


def _cmd_containers(args: argparse.Namespace) -> int:
    from pourbench.containers import container_names, get_container

    shipped = [get_container(name) for name in container_names()]
    rows = [(c.name, c.role, c.kind, c.description) for c in shipped]
    _print_table(("name", "set", "kind", "description"), rows)
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from pourbench.scene import build_pour_scene
    from pourbench.view import check_display, record

    robot = None if args.robot == "none" else args.robot
    if args.viewer:
        check_display()  # before the scene is built: a missing display fails fast
    scene = build_pour_scene(args.pouring, args.receiving, robot)
    data = scene.make_data()
    if args.viewer:
        import mujoco.viewer

        mujoco.viewer.launch(scene.model, data)
        return 0
    print(f"wrote {record(scene.model, data, args.out)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pourbench", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    defaults = {"formatter_class": argparse.ArgumentDefaultsHelpFormatter}

    demo = sub.add_parser(
        "demo", help="pour 200 g of water between two cups; write a recording", **defaults
    )
    from pourbench.demo import add_arguments as demo_arguments
    from pourbench.demo import run_demo

    demo_arguments(demo)
    demo.set_defaults(func=run_demo)

    bench = sub.add_parser(
        "bench", help="run a benchmark suite and write leaderboard/<suite>.*", **defaults
    )
    bench.add_argument("suite", choices=(*BENCH_SUITES, "all"))
    bench.add_argument(
        "--quick",
        action="store_true",
        help="the smallest case only; writes no table unless --out is given",
    )
    bench.add_argument(
        "--json",
        action="store_true",
        help='print one JSON object to stdout (for "all": {"suites": [one per suite]})',
    )
    bench.add_argument(
        "--out",
        default=argparse.SUPPRESS,  # no "(default: None)" in the help
        help="folder for the tables (default: leaderboard; with --quick, no tables unless given)",
    )
    bench.add_argument("--no-write", action="store_true", help="do not write leaderboard files")
    bench.add_argument(
        "--device",
        default="auto",
        choices=("auto", "cpu", "cuda"),
        help="auto: the CPU, plus CUDA when present; cuda: the CUDA rows alone (and the fluid "
        "checks on CUDA), written to leaderboard/<suite>_cuda.*",
    )
    bench.add_argument(
        "--ray",
        nargs="?",
        const="local",
        default=None,
        metavar="ADDRESS",
        help="pouring, transfer: spread the episodes over Ray: a local Ray on this machine's "
        "cores, or the cluster at ADDRESS (auto: the one `ray start` began here); the same "
        "tables as without it (docs/ray.md)",
    )
    bench.add_argument(
        "--against",
        default=None,
        metavar="SHA",
        help="env: alternate each CPU case with Pour-v0 as this earlier commit steps it "
        "(default: f8f94b4, the code before the batched step, left out with --quick; none: "
        "no comparison); needs the project's git checkout",
    )
    bench.add_argument(
        "--finished",
        action="store_true",
        help="ablation: the table and figure of the runs whose records are in "
        "<out>/ablation_runs/, training none",
    )
    bench.set_defaults(func=_cmd_bench)

    ev = sub.add_parser(
        "eval", help="pour with a policy on Pour-v0; print error, spill, success", **defaults
    )
    ev.add_argument(
        "--policy",
        type=policy_name,
        default="pd",
        help="pd, random, a shipped policy's name, or a model saved by training "
        "(e.g. runs/pournet/model.zip)",
    )
    ev.add_argument("--liquid", default="water", help="liquid profile name")
    ev.add_argument("--target-g", type=positive_float, default=100.0, help="target amount, g")
    ev.add_argument("--episodes", type=positive_int, default=10, help="episodes to run")
    ev.add_argument("--seed", type=nonnegative_int, default=0, help="first episode's seed")
    ev.add_argument("--containers", default="training", choices=("training", "novel"))
    ev.set_defaults(func=_cmd_eval)

    sub.add_parser(  # main() hands its flags to pourbench.agents.train (tyro)
        "train",
        help="train PourNet (PPO / RecurrentPPO / SAC, ICM, curriculum) on Pour-v0; "
        "compare it with a random policy (`pourbench train --help` lists its settings)",
        add_help=False,
    )

    sweep = sub.add_parser(
        "sweep",
        help="a grid or random search of `pourbench train` runs on Ray Tune (docs/ray.md)",
        **defaults,
    )
    from pourbench.agents.sweep import add_arguments as sweep_arguments
    from pourbench.agents.sweep import run as run_sweep

    sweep_arguments(sweep)
    sweep.set_defaults(func=run_sweep)

    liquids = sub.add_parser("liquids", help="list the shipped liquid profiles")
    liquids.set_defaults(func=_cmd_liquids)

    containers = sub.add_parser("containers", help="list the shipped containers")
    containers.set_defaults(func=_cmd_containers)

    view = sub.add_parser(
        "view", help="record a composed scene to a rerun .rrd (or open it)", **defaults
    )
    view.add_argument("what", choices=("scene",))
    view.add_argument(
        "--robot",
        default="movo",
        choices=("movo", "panda", "none"),
        help="none: the pouring container on a mocap body",
    )
    view.add_argument(
        "--pouring", default="training", help="pouring container (`pourbench containers`)"
    )
    view.add_argument(
        "--receiving", default="tray", help="receiving container (`pourbench containers`)"
    )
    view.add_argument("--out", default="runs/scene.rrd", help="rerun recording to write")
    view.add_argument("--viewer", action="store_true", help="open MuJoCo's viewer instead")
    view.set_defaults(func=_cmd_view)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    try:
        if words[:1] == ["train"]:
            from pourbench.agents.train import main as train_main

            return train_main(words[1:], prog="pourbench train")
        args = build_parser().parse_args(words)
        return int(args.func(args) or 0)
    except PourbenchError as exc:  # bad input: one clear line, no traceback
        print(f"pourbench: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: outputs are written atomically, nothing half-done stays
        print("pourbench: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
