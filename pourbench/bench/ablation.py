"""``pourbench bench ablation``: thesis Figures 6.7 and 6.8, what curiosity and the
curriculum add to PPO.

Three runs of ``pourbench train`` with the same algorithm, budget, seed and evaluations:

* ``ppo``: Algorithm 5's reward alone, water in every episode (``--no-icm --no-curriculum``);
* ``ppo_icm``: with the curiosity module's intrinsic reward (``--no-curriculum``);
* ``ppo_icm_curriculum``: with both (the thesis' PourNet).

Each is evaluated every tenth of its budget on the same water episodes (10 pours, seeds
1000…, targets drawn by the env; the curriculum run too, whose own default would be Table
6.2's six liquids), and the figure plots that evaluation's mean absolute pouring error, and
the mean error of the training episodes that ended in each rollout, against environment
steps. The training curve counts every ended episode: the thesis' running average (§6.5.1)
counts only completed ones, so a policy that never completes an episode would have none.
The runs live in ``runs/ablation/<variant>/``; a stopped ablation resumes
each run from its last checkpoint, and a finished run is read back, not trained again.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path
from typing import Any

from pourbench.bench._report import git_sha, markdown_table, write_report
from pourbench.errors import InvalidParameterError

VARIANTS: dict[str, dict[str, bool]] = {
    "ppo": {"icm": False, "curriculum": False},
    "ppo_icm": {"icm": True, "curriculum": False},
    "ppo_icm_curriculum": {"icm": True, "curriculum": True},
}
ALGORITHM, POLICY = "recurrent_ppo", "lstm"
BUDGET_STEPS = 200_000
EVAL_LIQUID = "water"
QUICK = {"budget_steps": 256, "num_envs": 2, "n_steps": 32, "batch_size": 64}
RUNS = Path("runs") / "ablation"


def train_variant(name: str, quick: bool, runs: Path = RUNS) -> dict[str, Any]:
    """Train (or resume, or read back) one variant; its ``result.json``."""
    from dataclasses import fields

    from pourbench.agents.train import TrainArgs, train

    out = runs / ("quick" if quick else "full") / name
    size = QUICK if quick else {"budget_steps": BUDGET_STEPS}
    steps = size["budget_steps"]
    result = out / "result.json"
    if result.is_file():
        done = json.loads(result.read_text())
        names = {f.name for f in fields(TrainArgs)}
        had = TrainArgs(**{k: v for k, v in done["args"].items() if k in names})
        if had.eval_liquids() != (EVAL_LIQUID,):
            raise InvalidParameterError(
                f"ablation: the run in {str(out)!r} was evaluated on "
                f"{', '.join(had.eval_liquids())}, not {EVAL_LIQUID}; move it away to train "
                "the variant anew"
            )
        if done["timesteps"] >= steps:
            print(f"ablation: {name} read back from {result}", file=sys.stderr)
            return done
    args = TrainArgs(
        algorithm=ALGORITHM,
        policy=POLICY,
        **VARIANTS[name],
        **size,
        seq_len=size.get("n_steps", 64),
        eval_every_steps=max(1, steps // 10),
        eval_episodes=1 if quick else 10,
        eval_liquid=EVAL_LIQUID,
        workers=1 if quick else 0,
        out=str(out),
        resume=(out / "model.zip").is_file(),
    )
    print(f"ablation: training {name} for {steps} steps into {out}", file=sys.stderr)
    with contextlib.redirect_stdout(sys.stderr):  # stdout holds the suite's JSON only
        return train(args, command=f"pourbench bench ablation ({name})")


def curves(out: Path) -> dict[str, list[tuple[float, float]]]:
    """A run's evaluation error and training episodes' error against steps."""
    from pourbench.agents.plots import read_progress

    series = read_progress(sorted(out.glob("logs/*/progress.csv")))
    return {k: series.get(k, []) for k in ("eval/mean_abs_error_g", "pour/error_g")}


def plot(runs: dict[str, dict[str, list[tuple[float, float]]]], png: Path) -> Path:
    """The variants' two curves side by side (matplotlib, no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    titles = {
        "eval/mean_abs_error_g": "evaluation: mean absolute error on water, g",
        "pour/error_g": "training: mean error of the episodes ended per rollout, g",
    }
    for ax, (key, title) in zip(axes, titles.items(), strict=True):
        for name, series in runs.items():
            if series[key]:
                xs, ys = zip(*series[key], strict=True)
                ax.plot(xs, ys, marker=".", label=name)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("environment steps", fontsize=8)
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=8)
    fig.suptitle("PPO, + curiosity, + curriculum (thesis Figures 6.7 and 6.8)", fontsize=10)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    partial = png.with_name(png.stem + ".partial.png")
    fig.savefig(partial, dpi=100)
    plt.close(fig)
    partial.replace(png)
    return png


def rows_of(results: dict[str, dict], runs: dict[str, dict]) -> list[dict[str, Any]]:
    """One row per variant: steps, wall time, final and best evaluation error, the last
    training episodes' mean error over the last tenth of the steps, and a random policy's
    error on the same episodes."""
    rows = []
    for name, r in results.items():
        evals = [e for _, e in runs[name]["eval/mean_abs_error_g"]]
        training = runs[name]["pour/error_g"]
        late = [e for s, e in training if s > 0.9 * r["timesteps"]]
        rows.append(
            {
                "variant": name,
                "steps": r["timesteps"],
                "train_h": r["total_train_s"] / 3600.0,
                "final_eval_error_g": r["mean_abs_error_g"],
                "best_eval_error_g": min([*evals, r["mean_abs_error_g"]]),
                "final_training_error_g": sum(late) / len(late) if late else None,
                "random_eval_error_g": r["random_mean_abs_error_g"],
            }
        )
    return rows


def run(args: argparse.Namespace) -> int:
    sha = git_sha()
    results = {name: train_variant(name, args.quick) for name in VARIANTS}
    runs = {name: curves(Path(r["args"]["out"])) for name, r in results.items()}
    rows = rows_of(results, runs)
    out = Path(args.out)
    body = "\n".join(
        [
            f"Three `pourbench train` runs of {ALGORITHM} ({POLICY}), seed 0, the same budget "
            "and evaluations: `ppo` (Algorithm 5's reward alone, water in every episode), "
            "`ppo_icm` (with the curiosity module), `ppo_icm_curriculum` (with the liquid "
            "curriculum too: the thesis' PourNet). `final_eval_error_g` / `best_eval_error_g`: "
            "the evaluation on water (10 pours, seeds 1000…) at the end and at its best; "
            "`final_training_error_g`: the mean error of the training episodes that ended in "
            "the last tenth of the steps (every ended episode, timed out ones too); "
            "`random_eval_error_g`: a random policy on the same episodes. "
            "Each run's sessions (command, git SHA, machine) are in its `state.json`.",
            "",
            markdown_table(rows),
            "",
            "![ablation](ablation.png)" if not args.no_write else "",
        ]
    )
    if not args.no_write:
        plot(runs, out / "ablation.png")
        write_report(
            "ablation",
            rows,
            out=str(out),
            title="Curiosity and curriculum: thesis Figures 6.7 and 6.8",
            body_md=body,
            extra={"curves": {n: {k: list(v) for k, v in c.items()} for n, c in runs.items()}},
            git_sha_at_start=sha,
        )
    if args.json:
        print(json.dumps({"suite": "ablation", "rows": rows}))
    else:
        print(markdown_table(rows))
    return 0
