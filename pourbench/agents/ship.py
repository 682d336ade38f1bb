"""Ship a finished ``pourbench train`` run as a named policy.

``python -m pourbench.agents.ship runs/pournet-lstm pournet-lstm`` writes
``pourbench/agents/policies/pournet-lstm.zip`` (the model, with a fresh optimiser: Adam's
moments are two thirds of a saved LSTM model and acting needs none of them) beside
``pournet-lstm.json``: the command of each training session, steps, seed, wall time, git
SHA, machine and date, the warm start's numbers, which checkpoint shipped with its own
evaluation, and the evaluation of the model at the end of training (``final_evaluation``).
The shipped model is the run's best-evaluated one (``best_model.zip``, the usual choice, as
SB3's ``EvalCallback`` keeps it), or with ``--last`` the model at the end of training.
``load_policy("pournet-lstm")`` and ``pourbench eval --policy pournet-lstm`` then find it.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from typing import Any

from pourbench.argtypes import POLICY_DIR
from pourbench.errors import InvalidParameterError, PourbenchError
from pourbench.outputs import write_text_atomic

_NAME = re.compile(r"^[a-z0-9][a-z0-9-]*$")


def ship(
    run_dir: str | Path, name: str, policy_dir: str | Path = POLICY_DIR, last: bool = False
) -> Path:
    """Copy the finished run in ``run_dir`` to ``<policy_dir>/<name>.zip`` with its
    metadata ``<name>.json``; the metadata's path. The model is the run's best-evaluated
    one when it kept one, unless ``last``: then the model at the end of training.

    Raises:
        InvalidParameterError: a name that is not lowercase letters, digits and dashes, or a
            run without ``model.zip``, ``state.json`` and ``result.json`` (an unfinished run).
    """
    from pourbench.agents.loading import load_model

    if not isinstance(name, str) or not _NAME.match(name):
        raise InvalidParameterError(
            f"a policy name is lowercase letters, digits and dashes, got {name!r}"
        )
    run = Path(run_dir)
    missing = [f for f in ("model.zip", "state.json", "result.json") if not (run / f).is_file()]
    if missing:
        raise InvalidParameterError(
            f"{str(run)!r} is not a finished training run: no {', '.join(missing)}"
        )
    state = json.loads((run / "state.json").read_text())
    result = json.loads((run / "result.json").read_text())
    best = result.get("best")
    use_best = best is not None and not last and (run / "best_model.zip").is_file()
    checkpoint = {"file": "best_model.zip", **best} if use_best else {
        "file": "model.zip", "timesteps": state["timesteps"]
    }  # fmt: skip
    model = load_model(run / checkpoint["file"])
    policy = model.policy
    policy.optimizer = policy.optimizer_class(
        policy.parameters(), lr=model.lr_schedule(1.0), **policy.optimizer_kwargs
    )
    out = Path(policy_dir)
    out.mkdir(parents=True, exist_ok=True)
    zip_path = out / f"{name}.zip"
    partial = out / f"{name}.partial.zip"
    model.save(partial)
    sessions = state.get("history", [])
    meta: dict[str, Any] = {
        "name": name,
        "algorithm": state["args"]["algorithm"],
        "policy": state["args"]["policy"],
        "commands": [s.get("command") for s in sessions],
        "steps": state["timesteps"],
        "seed": state["args"]["seed"],
        "wall_time_s": state["train_s"],
        "git_sha": [s.get("git_sha") for s in sessions],
        "machine": [s.get("machine") for s in sessions],
        "date": [s.get("date") for s in sessions],
        "settings": state["args"],
        "warm_start": state.get("warm_start"),
        "checkpoint": checkpoint,
        "final_evaluation": {  # the model at the end of training, not the checkpoint
            "timesteps": state["timesteps"],
            "mean_abs_error_g": result["mean_abs_error_g"],
            "summary": result["policy"],
            "random_mean_abs_error_g": result["random_mean_abs_error_g"],
            "pd_mean_abs_error_g": result.get("pd_mean_abs_error_g"),
        },
    }
    partial.replace(zip_path)
    meta_path = out / f"{name}.json"
    write_text_atomic(meta_path, json.dumps(meta, indent=2) + "\n")
    return meta_path


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    last = "--last" in args
    args = [a for a in args if a != "--last"]
    if len(args) != 2:
        print("usage: python -m pourbench.agents.ship RUN_DIR NAME [--last]", file=sys.stderr)
        return 2
    try:
        path = ship(args[0], args[1], last=last)
    except PourbenchError as exc:
        print(f"pourbench.agents.ship: error: {exc}", file=sys.stderr)
        return 2
    print(f"shipped {args[1]}: {path.with_suffix('.zip')} and {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
