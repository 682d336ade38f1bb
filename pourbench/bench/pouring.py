"""``pourbench bench pouring``: thesis Table 6.3 on this project's liquids, and the novel
containers of Figure 6.13 / Table 6.1.

**Table 6.3's protocol.** Table 6.2's six liquids × 50 / 100 / 150 / 200 g × 10 pours (seeds
0…9) on ``pourbench/Pour-v0``, the pouring container drawn by the env from its training set,
by every policy: the shipped policies of :data:`SHIPPED` where they exist (PourNet trained
from scratch, ``pournet-lstm`` and ``pournet-mlp``, and the residual corrections of the PD,
``pd-residual-lstm`` and ``pd-residual-mlp``), the PD baseline and a uniform random policy;
the thesis' LSTM and FNN numbers beside.

**Novel containers.** Every container of the ``novel`` set × water 50 g × 3 pours, by the
same policies, in grams and millilitres, beside the thesis' PourNet range for water (Table
6.1, 3.8–8.66 ml). A container that cannot hold the target (the spoon) gets "–" and, in its
``note``, what it holds.

A cell's pours run in a row in one env, seeds 0, 1, …, as the thesis poured each profile 10
times: each pour's observation carries the running average error of the pours before it
(observation 10), as in training, where a world's episodes follow one another. One job is one
cell, (policy, liquid, container, target, pours), a fresh env of its own, so its result
depends on nothing else: not on the order or the process it runs in. Jobs are spread over
one process per core, or over a Ray cluster with ``--ray`` (:mod:`pourbench.bench._jobs`);
each result is appended as it finishes to ``runs/pouring/episodes.jsonl``, keyed by the git
SHA at the start, so a run that stops resumes where it was.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from pourbench.argtypes import shipped_policies
from pourbench.bench._jobs import flag_counts, run_jobs
from pourbench.bench._report import git_sha, markdown_table, write_report

HAS_RAY = True
"""``--ray`` spreads the episodes over Ray workers (:mod:`pourbench.bench._jobs`)."""

TARGETS_G = (50.0, 100.0, 150.0, 200.0)
POURS = 10
NOVEL_TARGET_G = 50.0
NOVEL_POURS = 3

THESIS_TABLE_6_3 = {
    "lstm": {
        "water": (7.72, 2.3, 4.96, 4.76),
        "ink": (4.44, 6.34, 8.38, 5.9),
        "oil": (4.66, 8.64, 6.44, 7.38),
        "glycerine": (4.4, 7.66, 8.8, 6.9),
        "honey": (9.1, 5.26, 12.0, 10.54),
        "ketchup": (11.66, 20.36, None, None),
    },
    "fnn": {
        "water": (8.49, 5.13, 7.65, 5.65),
        "ink": (7.65, 7.94, 8.32, 6.17),
        "oil": (5.35, 8.91, 8.3, 8.25),
        "glycerine": (8.3, 8.52, 8.6, 7.5),
        "honey": (9.4, 8.26, 10.2, 10.79),
        "ketchup": (15.42, 19.40, None, None),
    },
}
"""Thesis Table 6.3: mean absolute deviation (g) of the LSTM and FNN PourNet in FleX, per
liquid at 50 / 100 / 150 / 200 g (None: ketchup's large targets were never reached)."""

THESIS_WATER_ML = (3.8, 8.66)
"""Thesis Table 6.1: PourNet's mean deviation range for water over its pouring containers, ml."""

SHIPPED = ("pournet-lstm", "pournet-mlp", "pd-residual-lstm", "pd-residual-mlp")
"""The shipped policies the tables compare: PourNet trained from scratch, then the residual
policies over the PD baseline."""
BASELINES = ("pd", "random")
LOG = Path("runs") / "pouring" / "episodes.jsonl"

Job = tuple[str, str, str | None, float, int]  # policy, liquid, container, target, pours
Pour = tuple[str, str, str | None, float, int]  # policy, liquid, container, target, seed


def policies() -> tuple[str, ...]:
    """The shipped policies of :data:`SHIPPED` that exist, then the baselines."""
    return (*(p for p in SHIPPED if p in shipped_policies()), *BASELINES)


def describe(name: str) -> str:
    """How the shipped policy ``name`` was trained, in one line of its metadata: algorithm,
    steps, worlds, residual over the PD or warm start, gSDE, reward, curiosity, curriculum,
    checkpoint."""
    from pourbench.agents.loading import policy_metadata

    meta = policy_metadata(name)
    cfg = meta["settings"]
    if cfg.get("residual"):
        start = f"a residual over the PD baseline (scale {cfg['residual']:g})"
    elif cfg.get("warm_start_steps"):
        start = f"cloned from {cfg['warm_start_steps']} steps of the PD"
    else:
        start = "from scratch"
    if cfg.get("sde"):
        start += ", exploring with gSDE"
    if cfg.get("ent_coef"):
        start += f", entropy coefficient {cfg['ent_coef']:g}"
    reward = "Algorithm 5"
    if cfg.get("final_error_per_g"):
        reward += f" + {cfg['final_error_per_g']:g} per gram of final error"
    if cfg.get("shaping"):
        reward += f" + potential-based shaping {cfg['shaping']:g}"
    if cfg.get("progress_per_g"):
        reward += f" + {cfg['progress_per_g']:g} per gram of progress"
    parts = [
        f"{meta['algorithm']} ({meta['policy']})",
        f"{meta['steps']} steps in {meta['wall_time_s']:.0f} s on {cfg['num_envs']} worlds",
        start,
        f"reward {reward}",
        *(["the directed tilt"] if cfg.get("directed_tilt") else []),
        *(["the tilt target"] if cfg.get("tilt_target") else []),
        *(["the directed approach"] if cfg.get("directed_approach") else []),
        f"curiosity {'on' if cfg['icm'] else 'off'}",
        f"curriculum {'on' if cfg['curriculum'] else 'off'}"
        + (" (rehearsing the earlier lessons)" if cfg.get("rehearse") else ""),
        f"checkpoint {meta['checkpoint']['file']} at {meta['checkpoint']['timesteps']} steps",
    ]
    return f"`{name}`: " + ", ".join(parts) + "."


def ablation_line(out: Path) -> str:
    """One line on the from-scratch runs beside the shipped policies: the final evaluations
    of ``pourbench bench ablation`` (its reward, every variant's mean and spread over its
    seeds) from ``<out>/ablation.json``, or how to make them."""
    path = out / "ablation.json"
    if not path.is_file():
        return "From scratch, with seeds: run `pourbench bench ablation` for its rows."
    from pourbench.bench.ablation import DENSE

    report = json.loads(path.read_text())
    rows = report["rows"]
    scores = ", ".join(
        f"`{r['variant']}` {r['final_eval_error_g']:.2f} ± {r['final_eval_sd_g']:.2f} g"
        for r in rows
    )
    low, high = min(r["steps"] for r in rows), max(r["steps"] for r in rows)
    steps = f"{low}" if low == high else f"{low}–{high}"
    return (
        f"From scratch (`pourbench bench ablation` at `{report['git_sha']}`, {steps} steps a "
        f"run, Algorithm 5 + potential-based shaping {DENSE['shaping']:g} + "
        f"{DENSE['progress_per_g']:g} per gram of progress, no PD in the loop): {scores} "
        "(mean ± standard deviation over the seeds) on its 10 water pours at the end of "
        f"training, where a random policy errs by {rows[0]['random_eval_error_g']:.2f} g "
        "([ablation.md](ablation.md))."
    )


def pours(policy: str, liquid: str, container: str | None, target_g: float, count: int) -> dict:
    """``count`` pours of ``target_g`` of ``liquid`` by ``policy`` in a row on one Pour-v0
    (seeds 0, 1, …): from the ``novel`` set's ``container``, or (None) from the training set
    as the env draws it. ``{"pours": [...]}``, one outcome per pour; each is
    ``{"too_small": reason}`` where the container cannot hold the target."""
    from pourbench.agents.evaluate import pour_episode
    from pourbench.agents.loading import load_policy
    from pourbench.envs.options import known_liquid
    from pourbench.envs.pour_v0 import PourEnv
    from pourbench.errors import CapacityError

    env = PourEnv(liquid=liquid, container_set="training" if container is None else "novel")
    act = load_policy(policy, 0)
    density = known_liquid(liquid).density / 1000.0  # g/ml
    options: dict[str, Any] = {"target_g": target_g}
    if container is not None:
        options["container"] = container
    outcomes: list[dict] = []
    try:
        for seed in range(count):
            start = time.perf_counter()
            info, steps = pour_episode(env, act, seed, options)
            outcomes.append(
                {
                    "error_g": float(info["error_g"]),
                    "error_ml": float(info["error_g"] / density),
                    "spilled_g": float(info["spilled_g"]),
                    "success": bool(info["is_success"]),
                    "collided": bool(info["collided"]),
                    "sim_diverged": bool(info["sim_diverged"]),
                    "container": str(info["container"]),
                    "average_error_g": float(info["average_error_g"]),
                    "steps": steps,
                    "wall_s": time.perf_counter() - start,
                }
            )
    except CapacityError as exc:  # a novel container too small for the target
        outcomes = [{"too_small": str(exc)}] * count
    finally:
        env.close()
    return {"pours": outcomes}


def run_episodes(
    jobs: list[Job], log: Path, sha: str, workers: int, ray_address: str | None = None
) -> dict[Pour, dict]:
    """Every job's :func:`pours`, by pour (its job's first four values and its seed): from
    ``log`` where the code at git SHA ``sha`` ran it already, otherwise over ``workers``
    processes or on Ray (``ray_address``), appended to it
    (:func:`pourbench.bench._jobs.run_jobs`)."""
    results = run_jobs(pours, jobs, log, sha, "pouring cells", workers, ray_address)
    return {
        (*job[:4], seed): outcome
        for job, result in results.items()
        for seed, outcome in enumerate(result["pours"])
    }


def _mean(results: dict[Pour, dict], jobs: list[Pour], key: str = "error_g") -> float:
    return float(np.mean([results[j][key] for j in jobs]))


def liquid_table(
    results: dict[Pour, dict],
    names: tuple[str, ...],
    liquids: tuple[str, ...],
    targets: tuple[float, ...],
    pours: int,
) -> list[dict[str, Any]]:
    """One row per liquid and target: each policy's mean absolute error (g) and success rate
    over the pours, beside the thesis' LSTM and FNN."""
    rows = []
    for liquid in liquids:
        for target in targets:
            row: dict[str, Any] = {"liquid": liquid, "target_g": target}
            i = TARGETS_G.index(target)
            row["thesis_lstm_g"] = THESIS_TABLE_6_3["lstm"][liquid][i]
            row["thesis_fnn_g"] = THESIS_TABLE_6_3["fnn"][liquid][i]
            flags = []
            for p in names:
                jobs = [(p, liquid, None, target, s) for s in range(pours)]
                row[f"{p}_g"] = _mean(results, jobs)
                row[f"{p}_success"] = _mean(results, jobs, "success")
                if f := flag_counts([results[j] for j in jobs], ("collided", "sim_diverged")):
                    flags.append(f"{p}: {f}")
            row["flags"] = "; ".join(flags)
            rows.append(row)
    return rows


def container_table(
    results: dict[Pour, dict], names: tuple[str, ...], containers: tuple[str, ...], pours: int
) -> list[dict[str, Any]]:
    """One row per novel container: each policy's mean absolute error over the pours of
    50 g of water, g and ml; None, and the reason in ``note``, for a container that cannot
    hold the target."""
    rows = []
    for c in containers:
        row: dict[str, Any] = {"container": c}
        small = ""
        for p in names:
            jobs = [(p, "water", c, NOVEL_TARGET_G, s) for s in range(pours)]
            small = small or next((results[j]["too_small"] for j in jobs
                                   if "too_small" in results[j]), "")  # fmt: skip
            row[f"{p}_g"] = None if small else _mean(results, jobs)
            row[f"{p}_ml"] = None if small else _mean(results, jobs, "error_ml")
        row["note"] = small
        rows.append(row)
    return rows


def table_means(rows: list[dict[str, Any]], columns: list[str]) -> dict[str, dict[str, float]]:
    """Each column's mean (g) over two sets of the table's cells: ``all`` the cells where it
    has a value (the thesis' columns have none for ketchup at 150 and 200 g), and
    ``thesis_cells`` only the cells the thesis filled, so that every column is averaged over
    the same cells as the thesis' rows."""
    thesis_cells = [r for r in rows if r["thesis_lstm_g"] is not None]

    def means(cells: list[dict[str, Any]]) -> dict[str, float]:
        return {c: float(np.mean([r[c] for r in cells if r[c] is not None])) for c in columns}

    return {"all": means(rows), "thesis_cells": means(thesis_cells)}


def _averages(means: dict[str, float]) -> str:
    return ", ".join(f"{c} {m:.2f}" for c, m in means.items())


def run(args: argparse.Namespace) -> int:
    from pourbench.agents.evaluate import TABLE_6_2
    from pourbench.containers import container_names

    quick = args.quick
    liquids = ("water",) if quick else TABLE_6_2
    targets = (100.0,) if quick else TARGETS_G
    pours = 2 if quick else POURS
    novel = container_names("novel")[:2] if quick else container_names("novel")
    novel_pours = 1 if quick else NOVEL_POURS
    names = policies()
    sha = git_sha()
    jobs: list[Job] = [
        (p, liquid, None, target, pours) for p in names for liquid in liquids for target in targets
    ]
    jobs += [(p, "water", c, NOVEL_TARGET_G, novel_pours) for p in names for c in novel]
    log = LOG.with_name("episodes-quick.jsonl") if quick else LOG
    results = run_episodes(jobs, log, sha, os.cpu_count() or 1, getattr(args, "ray", None))
    rows = liquid_table(results, names, liquids, targets, pours)
    crows = container_table(results, names, novel, novel_pours)
    columns = ["liquid", "target_g", "thesis_lstm_g", "thesis_fnn_g"]
    columns += [f"{p}_{k}" for p in names for k in ("g", "success")] + ["flags"]
    ccolumns = ["container"] + [f"{p}_{k}" for p in names for k in ("g", "ml")] + ["note"]
    pending = [p for p in SHIPPED if p not in names]
    means = table_means(rows, ["thesis_lstm_g", "thesis_fnn_g", *(f"{p}_g" for p in names)])
    n_thesis = sum(r["thesis_lstm_g"] is not None for r in rows)
    body = "\n".join(
        [
            "Policies: " + ", ".join(f"`{p}`" for p in names) + "."
            + (
                f" Not shipped yet: {', '.join(f'`{p}`' for p in pending)}; their rows appear "
                "when they are."
                if pending
                else ""
            ),
            *(f"- {describe(p)}" for p in names if p in SHIPPED),
            "",
            ablation_line(Path(args.out)),
            "",
            "## Table 6.3's protocol",
            "",
            f"Table 6.2's liquids × {', '.join(f'{t:g}' for t in targets)} g × {pours} pours "
            "in a row (seeds 0…, one env per cell, so each pour sees the running average error "
            "of those before it) on `pourbench/Pour-v0` with its defaults (the training set's "
            "pouring container, 8 mm particles). Columns: `<policy>_g`, the mean absolute "
            "error over the pours, g; `<policy>_success`, the share that ended with an error "
            "of at most 10 g; `thesis_*_g`, Table 6.3's PourNet in FleX (– where ketchup's "
            "large targets were never reached); `flags`, episodes ended by a collision or a "
            "diverged liquid.",
            "",
            markdown_table(rows, columns),
            "",
            f"Mean over every cell ({len(rows)}): " + _averages(means["all"]) + " g.",
            "",
            f"Mean over the {n_thesis} cells the thesis filled (like with like): "
            + _averages(means["thesis_cells"])
            + " g.",
            "",
            "## Novel containers (Figure 6.13 / Table 6.1)",
            "",
            f"Each container of the `novel` set × water {NOVEL_TARGET_G:g} g × {novel_pours} "
            "pour(s) in a row (seeds 0…). Mean absolute error, g and ml; the thesis' PourNet "
            f"ranged over {THESIS_WATER_ML[0]}–{THESIS_WATER_ML[1]} ml on its real containers "
            "(Table 6.1), with the two bottles as outliers.",
            "",
            markdown_table(crows, ccolumns),
        ]
    )  # fmt: skip
    if not args.no_write:
        write_report(
            "pouring",
            rows,
            out=args.out,
            title="Table 6.3: pouring Table 6.2's liquids, and the novel containers",
            body_md=body,
            extra={
                "policies": list(names),
                "pours": pours,
                "means_g": means,
                "novel_containers": crows,
            },
            git_sha_at_start=sha,
        )
    if args.json:
        print(
            json.dumps(
                {"suite": "pouring", "rows": rows, "means_g": means, "novel_containers": crows}
            )
        )
    else:
        print(markdown_table(rows, columns))
        print(markdown_table(crows, ccolumns))
    return 0
