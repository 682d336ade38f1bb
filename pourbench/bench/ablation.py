"""``pourbench bench ablation``: thesis Figures 6.7 and 6.8, what curiosity and the
curriculum add to PPO, and how an off-policy learner compares, over seeds.

Four variants of ``pourbench train``, each with every seed of :data:`SEEDS`, the same step
budget and the same evaluations:

* ``ppo``: RecurrentPPO (LSTM) on water in every episode (``--no-icm --no-curriculum``),
  with :data:`DENSE`: Algorithm 5's reward plus the potential-based shaping term and the
  progress reward (every gram of the error paid as the scale moves), and the directed tilt
  map, the step size falling linearly to zero over the budget. Algorithm 5's reward alone
  never pours within this budget (docs/training.md), which leaves curiosity and the
  curriculum nothing to add to;
* ``ppo_icm``: with the curiosity module's intrinsic reward (``--no-curriculum``);
* ``ppo_icm_curriculum``: with both (the thesis' PourNet, on the same dense reward);
* ``sac``: SAC on water (:data:`OFF_POLICY`), the off-policy learner that poured best in
  the fewest steps in docs/training.md, with :data:`DENSE`'s reward terms and step-size fall
  but the tilt as a target instead of the directed tilt ("The tilt as a target"), the
  directed approach, its entropy coefficient held at 0.015, a quarter gradient update per
  environment step and 16 worlds. It evaluates with the mean of what its policy applies
  (:func:`pourbench.agents.loading.applied_mean`). TD3 with the rate maps held this place
  before and never poured in its evaluations (docs/training.md, "Ablation").

Each run is evaluated every tenth of its budget on the same water episodes (10 pours, seeds
1000…, targets drawn by the env; the curriculum run too, whose own default would be Table
6.2's six liquids). The figure plots, per variant, that evaluation's mean absolute pouring
error over the seeds (line: mean; band: the seeds' lowest to highest) against environment
steps and against training wall time, and the mean error of the training episodes that ended
in each rollout against steps. The training curve counts every ended episode: the thesis'
running average (§6.5.1) counts only completed ones, so a policy that never completes an
episode would have none. The table gives, per variant, the first evaluation step at which each
seed's error reached :data:`TARGET_G`. The budget (:data:`BUDGET_STEPS`) is the one at which
a PPO run has learned to pour; docs/training.md has what the twelve runs cost. The runs live in
``runs/ablation/full/<variant>/seed<k>/``; a stopped ablation resumes each run from its last
checkpoint, and a finished run is read back, not trained again (one trained with other
settings than its variant's is refused). A finished full run also keeps its record (its
result and its curves) in ``<out>/ablation_runs/<variant>-seed<k>.json`` beside the report,
which is committed with it: a fresh clone reads the finished runs back from there and trains
only the runs that have none, so the ablation resumes run by run across machines whose
``runs/`` folder is gone. ``--quick``: seed 0 alone, 256 steps a run, no records.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from pourbench.bench._report import git_sha, markdown_table, write_report
from pourbench.errors import InvalidParameterError
from pourbench.outputs import write_text_atomic

DENSE: dict[str, Any] = {
    "shaping": 1.0,
    "progress_per_g": 0.05,
    "directed_tilt": True,
    "lr_schedule": "linear",
}
"""The reward terms, the tilt map and the step size's fall to zero over the budget that every
variant trains with (docs/training.md)."""
VARIANTS: dict[str, dict[str, bool]] = {
    "ppo": {"icm": False, "curriculum": False},
    "ppo_icm": {"icm": True, "curriculum": False},
    "ppo_icm_curriculum": {"icm": True, "curriculum": True},
}
"""The thesis' ablation: RecurrentPPO (LSTM) runs that differ only in these flags."""
ALGORITHM, POLICY = "recurrent_ppo", "lstm"
OFF_POLICY: dict[str, dict[str, Any]] = {
    "sac": {
        "algorithm": "sac",
        "policy": "mlp",
        "icm": False,
        "curriculum": False,
        **DENSE,
        "directed_tilt": False,
        "tilt_target": True,
        "directed_approach": True,
        "ent_coef": 0.015,
        "utd": 0.25,
        "num_envs": 16,
    },
}
"""The off-policy learner beside them: its :class:`~pourbench.agents.train.TrainArgs`."""
SEEDS = (0, 1, 2)
BUDGET_STEPS = 200_000
TARGET_G = 10.0
"""The evaluation error whose first crossing the table reports, g."""
EVAL_LIQUID = "water"
QUICK = {"budget_steps": 256, "num_envs": 2, "n_steps": 32, "batch_size": 64}
RUNS = Path("runs") / "ablation"
RECORDS = "ablation_runs"
"""The folder beside the report that keeps each finished full run's record."""


def variant_names() -> list[str]:
    """Every variant, the thesis' three first."""
    return [*VARIANTS, *OFF_POLICY]


def settings(name: str) -> dict[str, Any]:
    """The :class:`~pourbench.agents.train.TrainArgs` fields that make variant ``name``."""
    if name in VARIANTS:
        return {"algorithm": ALGORITHM, "policy": POLICY, **DENSE, **VARIANTS[name]}
    return dict(OFF_POLICY[name])


def _steps(quick: bool) -> int:
    """The step budget of a run: the quick one's or :data:`BUDGET_STEPS`."""
    return QUICK["budget_steps"] if quick else BUDGET_STEPS


def _refuse_other(done: dict[str, Any], name: str, steps: int, where: str) -> None:
    """Raise unless the finished run ``done`` (a ``result.json``) was trained with variant
    ``name``'s settings for a budget of ``steps`` (the step size falls to zero over it) and
    evaluated on :data:`EVAL_LIQUID`; ``where`` names it."""
    from dataclasses import fields

    from pourbench.agents.train import TrainArgs

    names = {f.name for f in fields(TrainArgs)}
    had = TrainArgs(**{k: v for k, v in done["args"].items() if k in names})
    if had.eval_liquids() != (EVAL_LIQUID,):
        raise InvalidParameterError(
            f"ablation: the run in {where!r} was evaluated on "
            f"{', '.join(had.eval_liquids())}, not {EVAL_LIQUID}; move it away to train "
            "the variant anew"
        )
    differ = {
        k: (getattr(had, k), v)
        for k, v in {**settings(name), "budget_steps": steps}.items()
        if k != "num_envs" and getattr(had, k) != v
    }
    if differ:
        said = ", ".join(f"{k}={a!r}, not {b!r}" for k, (a, b) in differ.items())
        raise InvalidParameterError(
            f"ablation: the run in {where!r} was trained with {said}; move it away "
            "to train the variant anew"
        )


def train_variant(name: str, seed: int, quick: bool, runs: Path = RUNS) -> dict[str, Any]:
    """Train (or resume, or read back) one variant with one seed; its ``result.json``."""
    from pourbench.agents.train import TrainArgs, train

    out = runs / ("quick" if quick else "full") / name / f"seed{seed}"
    size = dict(QUICK) if quick else {"budget_steps": BUDGET_STEPS}
    steps = _steps(quick)
    result = out / "result.json"
    if result.is_file():
        done = json.loads(result.read_text())
        _refuse_other(done, name, steps, str(out))
        if done["timesteps"] >= steps:
            print(f"ablation: {name} seed {seed} read back from {result}", file=sys.stderr)
            return done
    chosen = {**settings(name), **size}  # the quick run's size wins over a variant's worlds
    if chosen["algorithm"] == ALGORITHM:  # sb3-contrib's sequence is the rollout
        chosen["seq_len"] = chosen.get("n_steps", 64)
    args = TrainArgs(
        **chosen,
        seed=seed,
        eval_every_steps=max(1, steps // 10),
        eval_episodes=1 if quick else 10,
        eval_liquid=EVAL_LIQUID,
        workers=1 if quick else 0,
        out=str(out),
        resume=(out / "model.zip").is_file(),
    )
    print(f"ablation: training {name} seed {seed} for {steps} steps into {out}", file=sys.stderr)
    with contextlib.redirect_stdout(sys.stderr):  # stdout holds the suite's JSON only
        return train(args, command=f"pourbench bench ablation ({name}, seed {seed})")


Series = list[tuple[float, float]]

KEYS = ("eval/mean_abs_error_g", "eval/train_s", "pour/error_g")
"""What a run's curves hold: its evaluations' error and training wall time (s), and the
training episodes' error, each against environment steps."""


def finished_run(
    name: str, seed: int, quick: bool, runs: Path = RUNS, records: Path | None = None
) -> tuple[dict[str, Any], dict[str, Series]]:
    """One variant's run with one seed, finished: its ``result.json`` and its :func:`curves`.

    With ``records`` (a folder), a record ``<records>/<name>-seed<seed>.json`` of a run that
    reached the budget is read back without ``runs`` (a record of other settings is refused,
    as a run is); otherwise the run is trained, resumed or read back from ``runs``
    (:func:`train_variant`) and its record written there."""
    if records is not None:
        kept = recorded_run(name, seed, quick, records)
        if kept is not None:
            return kept
    result = train_variant(name, seed, quick, runs)
    series = curves(Path(result["args"]["out"]))
    if records is not None:
        record = records / f"{name}-seed{seed}.json"
        record.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(record, json.dumps({"result": result, "curves": series}, indent=1) + "\n")
    return result, series


def recorded_run(
    name: str, seed: int, quick: bool, records: Path
) -> tuple[dict[str, Any], dict[str, Series]] | None:
    """The record ``<records>/<name>-seed<seed>.json`` of a run that reached the budget, as
    ``(result, curves)``; ``None`` when there is none or it stopped short. A record of other
    settings than the variant's is refused, as a run is."""
    record = records / f"{name}-seed{seed}.json"
    if not record.is_file():
        return None
    kept = json.loads(record.read_text())
    _refuse_other(kept["result"], name, _steps(quick), str(record))
    if kept["result"]["timesteps"] < _steps(quick):
        return None
    print(f"ablation: {name} seed {seed} read back from {record}", file=sys.stderr)
    series = {k: [(float(s), float(v)) for s, v in kept["curves"].get(k, [])] for k in KEYS}
    return kept["result"], series


def curves(out: Path) -> dict[str, Series]:
    """A run's :data:`KEYS` series from its ``progress.csv`` files."""
    from pourbench.agents.plots import read_progress

    series = read_progress(sorted(out.glob("logs/*/progress.csv")))
    return {k: series.get(k, []) for k in KEYS}


def band(runs: list[dict[str, Series]], key: str, x: str | None = None) -> np.ndarray:
    """(k, 4) rows ``(x, mean, lowest, highest)`` of ``key`` over the seeds' runs, matched by
    evaluation (or logging) index up to the shortest run; ``x`` is the mean step, or the
    mean value of series ``x`` at the same index (an evaluation's wall time). Runs that
    logged ``key`` a different number of times (an off-policy run logs every few episodes,
    and its episodes' lengths differ from seed to seed) are matched by step instead: each
    is interpolated at the sparsest run's steps within the steps every run covers."""
    if not runs or any(not r[key] for r in runs):
        return np.zeros((0, 4))
    if x is None and len({len(r[key]) for r in runs}) > 1:
        lo = max(r[key][0][0] for r in runs)
        hi = min(r[key][-1][0] for r in runs)
        sparsest = min(runs, key=lambda r: len(r[key]))
        at = np.array([s for s, _ in sparsest[key] if lo <= s <= hi])
        ys = np.array([np.interp(at, *np.array(r[key]).T) for r in runs])
        return np.column_stack([at, ys.mean(0), ys.min(0), ys.max(0)])
    k = min(len(r[key]) for r in runs)
    if x is not None:
        k = min([k, *(len(r[x]) for r in runs)])
    ys = np.array([[v for _, v in r[key][:k]] for r in runs])
    if x is None:
        xs = np.array([[s for s, _ in r[key][:k]] for r in runs])
    else:
        xs = np.array([[v for _, v in r[x][:k]] for r in runs])
    return np.column_stack([xs.mean(0), ys.mean(0), ys.min(0), ys.max(0)])


def first_reaching(series: Series, threshold: float = TARGET_G) -> float:
    """The first step whose value is at most ``threshold`` (``inf``: never)."""
    return next((s for s, v in series if v <= threshold), math.inf)


def plot(runs: dict[str, list[dict[str, Series]]], png: Path) -> Path:
    """Per variant, the evaluation error over the seeds against steps and against wall time,
    and the training episodes' error against steps (matplotlib, no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 3.6))
    panels = (
        ("eval/mean_abs_error_g", None, "evaluation on water, g", "environment steps", 1.0),
        ("eval/mean_abs_error_g", "eval/train_s", "evaluation on water, g", "training, h", 3600),
        ("pour/error_g", None, "training episodes ended per rollout, g", "environment steps", 1),
    )
    for ax, (key, x, title, xlabel, unit) in zip(axes, panels, strict=True):
        for name, seeds in runs.items():
            b = band(seeds, key, x)
            if len(b):
                (line,) = ax.plot(b[:, 0] / unit, b[:, 1], marker=".", label=name)
                ax.fill_between(b[:, 0] / unit, b[:, 2], b[:, 3], color=line.get_color(), alpha=0.2)
        ax.set_title(f"{title}: mean, band over seeds", fontsize=9)
        ax.set_xlabel(xlabel, fontsize=8)
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=8)
    learners = ", ".join(v["algorithm"].upper() for v in OFF_POLICY.values())
    fig.suptitle(
        f"PPO, + curiosity, + curriculum (thesis Figures 6.7 and 6.8), and {learners}",
        fontsize=10,
    )
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    partial = png.with_name(png.stem + ".partial.png")
    fig.savefig(partial, dpi=100)
    plt.close(fig)
    partial.replace(png)
    return png


def rows_of(
    results: dict[str, list[dict[str, Any]]], runs: dict[str, list[dict[str, Series]]]
) -> list[dict[str, Any]]:
    """One row per variant over its seeds: steps and wall time a run, the final evaluation's
    mean and standard deviation, the best evaluation of any seed, the training episodes'
    mean error over the last tenth of the steps, the first step at which each seed's
    evaluation reached :data:`TARGET_G`, and a random policy's error on the same episodes."""
    rows = []
    for name, seeds in results.items():
        finals = [r["mean_abs_error_g"] for r in seeds]
        evals = [e for run in runs[name] for _, e in run["eval/mean_abs_error_g"]]
        late = [
            e
            for r, run in zip(seeds, runs[name], strict=True)
            for s, e in run["pour/error_g"]
            if s > 0.9 * r["timesteps"]
        ]
        reached = [first_reaching(run["eval/mean_abs_error_g"]) for run in runs[name]]
        rows.append(
            {
                "variant": name,
                "seeds": len(seeds),
                "steps": round(float(np.mean([r["timesteps"] for r in seeds]))),
                "train_h": float(np.mean([r["total_train_s"] for r in seeds])) / 3600.0,
                "final_eval_error_g": float(np.mean(finals)),
                "final_eval_sd_g": float(np.std(finals)),
                "best_eval_error_g": min([*evals, *finals]),
                "final_training_error_g": float(np.mean(late)) if late else None,
                f"first_step_at_{TARGET_G:g}g": ", ".join(
                    "never" if math.isinf(s) else f"{s:.0f}" for s in reached
                ),
                "random_eval_error_g": seeds[0]["random_mean_abs_error_g"],
            }
        )
    return rows


def run(args: argparse.Namespace) -> int:
    sha = git_sha()
    seeds = SEEDS[:1] if args.quick else SEEDS
    out = Path(args.out)
    only_recorded = getattr(args, "finished", False)
    if only_recorded and args.quick:
        raise InvalidParameterError("--finished reads the full runs' records; not with --quick")
    records = None if args.quick or args.no_write else out / RECORDS
    finished: dict[str, list[tuple[dict[str, Any], dict[str, Series]]]] = {
        name: [] for name in variant_names()
    }
    missing = []
    for k in seeds:  # every variant's first seed first: a stopped ablation compares them sooner
        for name in variant_names():
            if not only_recorded:
                finished[name].append(finished_run(name, k, args.quick, records=records))
            elif (kept := recorded_run(name, k, False, out / RECORDS)) is not None:
                finished[name].append(kept)
            else:
                missing.append(f"`{name}` seed {k}")
    finished = {name: runs for name, runs in finished.items() if runs}
    if not finished:
        raise InvalidParameterError(f"--finished: no finished run's record in {out / RECORDS}")
    results = {name: [r for r, _ in runs] for name, runs in finished.items()}
    runs = {name: [c for _, c in runs] for name, runs in finished.items()}
    rows = rows_of(results, runs)
    sac = OFF_POLICY["sac"]
    body = "\n".join(
        [
            f"`pourbench train` runs of {ALGORITHM} ({POLICY}) with seeds "
            f"{', '.join(map(str, seeds))}, the same budget and evaluations, each with Algorithm "
            f"5's reward plus shaping {DENSE['shaping']:g} and a progress reward of "
            f"{DENSE['progress_per_g']:g} a gram, and the directed tilt: `ppo` (water in "
            "every episode), `ppo_icm` (with the curiosity module), `ppo_icm_curriculum` "
            "(with the liquid curriculum too: the thesis' PourNet); and `sac` (SAC on "
            "water with the tilt as a target instead of the directed tilt, the directed "
            f"approach, entropy coefficient {sac['ent_coef']:g}, {sac['utd']:g} updates a "
            f"step, {sac['num_envs']} worlds, evaluated with the mean of what its policy "
            "applies). "
            "`final_eval_error_g` ± `final_eval_sd_g`: "
            "the evaluation on water (10 pours, seeds 1000…) at the end, mean and standard "
            "deviation over the seeds; `best_eval_error_g`: the best evaluation of any seed; "
            "`final_training_error_g`: the mean error of the training episodes that ended "
            "in the last tenth of the steps (every ended episode, timed out ones too); "
            f"`first_step_at_{TARGET_G:g}g`: per seed, the first evaluation at or under "
            f"{TARGET_G:g} g; `random_eval_error_g`: a random policy on the same episodes. "
            "Each run's sessions (command, git SHA, machine) are in its `state.json`.",
            "",
            *(
                [
                    f"The finished runs only (`--finished`): not yet trained {', '.join(missing)}.",
                    "",
                ]
                if missing
                else []
            ),
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
            title="Curiosity, curriculum and an off-policy learner: thesis Figures 6.7 and 6.8",
            body_md=body,
            extra={
                "curves": {
                    name: [{k: list(v) for k, v in c.items()} for c in cs]
                    for name, cs in runs.items()
                }
            },
            git_sha_at_start=sha,
        )
    if args.json:
        print(json.dumps({"suite": "ablation", "rows": rows}))
    else:
        print(markdown_table(rows))
    return 0
