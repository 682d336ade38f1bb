"""``pourbench bench transfer``: thesis Table 6.4 in simulation, the sim-to-sim transfer gap.

A pouring policy of Pour-v0 pours, with no retraining, on ``pourbench/PourRobot-v0``: the
Movo (the thesis' robot) and the Panda, with NMPC-MP executing its end-effector motion. Table
6.4's seven liquids × 50 / 100 / 150 g × three pours (seeds 0, 1, 2), and the same episodes
on Pour-v0. The table gives, per liquid and target, the mean absolute error on each beside
the thesis' real-robot error, and the gap: the robot's error less Pour-v0's.

The policy is the shipped ``pournet-lstm`` once it exists, the PD baseline until then.
Episodes run one after another in this process, or on Ray workers with ``--ray``
(:mod:`pourbench.bench._jobs`). They are logged as they finish
(``runs/transfer/episodes.jsonl``, keyed by the git SHA, the policy and the episode), so a run
that stops resumes where it was.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from pourbench.agents.loading import load_policy
from pourbench.argtypes import shipped_policies
from pourbench.bench._jobs import flag_counts, run_jobs
from pourbench.bench._report import git_sha, markdown_table, write_report

LIQUIDS = ("water", "milk", "cola", "orange juice", "rapeseed oil", "dish soap", "honey")
"""Table 6.4's liquids, in its column order."""

HAS_RAY = True
"""``--ray`` spreads the episodes over Ray workers (:mod:`pourbench.bench._jobs`)."""

TARGETS_G = (50.0, 100.0, 150.0)
POURS = 3

THESIS_TABLE_6_4 = {
    "water": (6.33, 3.55, 7.33),
    "milk": (3.33, 3.66, 5.53),
    "cola": (6.00, 7.55, 6.00),
    "orange juice": (2.67, 2.33, 4.67),
    "rapeseed oil": (8.55, 5.67, 8.55),
    "dish soap": (3.33, 1.67, 2.12),
    "honey": (9.33, 8.66, 5.23),
}
"""Thesis Table 6.4: PourNet on the real Movo, deviation from the target (g) per liquid at
50 / 100 / 150 g, three pours each."""

ENVS = ("pour", "movo", "panda")
"""Pour-v0, then PourRobot-v0 with each robot."""
FLAGS = ("collided", "planner_failed", "sim_diverged")

SHIPPED = "pournet-lstm"
LOG = Path("runs") / "transfer" / "episodes.jsonl"


def policy_name() -> str:
    """The shipped PourNet policy once it exists, the PD baseline until then."""
    return SHIPPED if SHIPPED in shipped_policies() else "pd"


def episode(policy: str, env_name: str, liquid: str, target_g: float, seed: int) -> dict:
    """One pour of ``target_g`` of ``liquid`` by ``policy`` on ``env_name`` (:data:`ENVS`)."""
    from pourbench.agents.evaluate import pour_episode

    if env_name == "pour":
        from pourbench.envs.pour_v0 import PourEnv

        env = PourEnv(liquid=liquid)
    else:
        from pourbench.envs.robot_pour import RobotPourEnv

        env = RobotPourEnv(robot=env_name, liquid=liquid)
    act = load_policy(policy, seed)
    start = time.perf_counter()
    info, steps = pour_episode(env, act, seed, {"target_g": target_g})
    env.close()
    return {
        "error_g": float(info["error_g"]),
        "spilled_g": float(info["spilled_g"]),
        "success": bool(info["is_success"]),
        "collided": bool(info.get("collided", False)),
        "planner_failed": bool(info.get("planner_failed", False)),
        "sim_diverged": bool(info.get("sim_diverged", False)),
        "steps": steps,
        "wall_s": time.perf_counter() - start,
    }


def run_episodes(
    liquids: tuple[str, ...],
    targets: tuple[float, ...],
    pours: int,
    policy: str,
    log: Path,
    sha: str,
    ray_address: str | None = None,
) -> dict[tuple[str, str, float, int], dict]:
    """Every (env, liquid, target, seed) episode by ``policy``: taken from ``log`` where the
    code at git SHA ``sha`` ran it already, otherwise run in this process or on Ray
    (``ray_address``) and appended to it (:func:`pourbench.bench._jobs.run_jobs`)."""
    jobs = [
        (policy, env, liquid, target, seed)
        for liquid in liquids
        for target in targets
        for seed in range(pours)
        for env in ENVS
    ]
    results = run_jobs(episode, jobs, log, sha, "transfer episodes", ray_address=ray_address)
    return {job[1:]: result for job, result in results.items()}


def table(
    results: dict[tuple[str, str, float, int], dict],
    liquids: tuple[str, ...],
    targets: tuple[float, ...],
    pours: int,
) -> list[dict[str, Any]]:
    """One row per liquid and target: mean absolute errors (g) on each env, the thesis' real
    Movo, and the robots' gaps to Pour-v0."""
    rows = []
    for liquid in liquids:
        for target in targets:
            eps = {e: [results[(e, liquid, target, s)] for s in range(pours)] for e in ENVS}
            err = {e: float(np.mean([x["error_g"] for x in eps[e]])) for e in ENVS}
            thesis = THESIS_TABLE_6_4[liquid][TARGETS_G.index(target)]
            rows.append(
                {
                    "liquid": liquid,
                    "target_g": target,
                    "thesis_movo_g": thesis,
                    "pour_v0_g": err["pour"],
                    "movo_g": err["movo"],
                    "gap_movo_g": err["movo"] - err["pour"],
                    "panda_g": err["panda"],
                    "gap_panda_g": err["panda"] - err["pour"],
                    "movo_flags": flag_counts(eps["movo"], FLAGS),
                    "panda_flags": flag_counts(eps["panda"], FLAGS),
                }
            )
    return rows


def run(args: argparse.Namespace) -> int:
    quick = args.quick
    liquids = ("water",) if quick else LIQUIDS
    targets = (100.0,) if quick else TARGETS_G
    pours = 1 if quick else POURS
    policy = policy_name()
    sha = git_sha()
    log = LOG.with_name("episodes-quick.jsonl") if quick else LOG
    results = run_episodes(liquids, targets, pours, policy, log, sha, getattr(args, "ray", None))
    rows = table(results, liquids, targets, pours)
    mean_of = ("thesis_movo_g", "pour_v0_g", "movo_g", "panda_g")
    means = {c: float(np.mean([r[c] for r in rows])) for c in mean_of}
    body = "\n".join(
        [
            f"Policy: `{policy}`"
            + (
                " (the PD baseline: `pournet-lstm` is not shipped yet; the table switches to it "
                "when it is)."
                if policy == "pd"
                else "."
            ),
            "",
            f"Thesis Table 6.4's liquids × {', '.join(f'{t:g}' for t in targets)} g × {pours} "
            "pour(s) (seeds 0…), each on Pour-v0 (no robot) and on PourRobot-v0 with the Movo "
            "(right arm pours, the left wrist's F/T sensor weighs the tray) and the Panda (tray "
            "on a table scale), NMPC-MP executing the end-effector motion; no retraining. "
            "Columns: mean absolute error (g) over the pours; `thesis_movo_g`: PourNet on the "
            "real Movo (Table 6.4); `gap_*`: the robot's error less Pour-v0's (the sim-to-sim "
            "transfer gap); `*_flags`: episodes ended by a collision, a planner that missed "
            "its target, or a diverged liquid.",
            "",
            markdown_table(rows),
            "",
            "Mean over the table: " + ", ".join(f"{c} {v:.2f} g" for c, v in means.items()) + ".",
        ]
    )
    if not args.no_write:
        write_report(
            "transfer",
            rows,
            out=args.out,
            title="Table 6.4 in simulation: a Pour-v0 policy with the robot in the loop",
            body_md=body,
            extra={"policy": policy, "pours": pours},
            git_sha_at_start=sha,
        )
    if args.json:
        print(json.dumps({"suite": "transfer", "policy": policy, "rows": rows}))
    else:
        print(markdown_table(rows))
    return 0
