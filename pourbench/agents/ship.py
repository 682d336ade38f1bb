"""Ship a finished ``pourbench train`` run as a named policy.

``python -m pourbench.agents.ship runs/pournet-lstm pournet-lstm`` writes
``pourbench/agents/policies/pournet-lstm.zip`` (the model without its optimisers' state:
Adam's moments are two thirds of a saved LSTM model, and of a SAC model's actor and critic,
and acting needs none of them) beside
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

from pourbench.argtypes import BUILTIN_POLICIES, POLICY_DIR
from pourbench.errors import InvalidParameterError, PourbenchError
from pourbench.outputs import write_text_atomic

_NAME = re.compile(r"^[a-z0-9][a-z0-9-]*$")
_ARGS_KEYS = ("algorithm", "policy", "seed")


def _read_run_json(path: Path, keys: tuple[str, ...]) -> dict[str, Any]:
    """The JSON object in ``path``, which must hold ``keys``; an
    :class:`InvalidParameterError` naming the file otherwise."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: not JSON, not UTF-8
        raise InvalidParameterError(
            f"{str(path)!r} is unreadable ({type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(data, dict):
        raise InvalidParameterError(f"{str(path)!r} holds a {type(data).__name__}, not an object")
    missing = [k for k in keys if k not in data]
    if missing:
        raise InvalidParameterError(
            f"{str(path)!r} has no {', '.join(missing)}: not what pourbench train writes"
        )
    return data


def _drop_optimiser_state(model: Any) -> None:
    """Empty the state (Adam's moments) of every optimiser of the SB3 ``model``: its
    policy's (PPO), its actor's and critic's (SAC, TQC, CrossQ, TD3) and its entropy
    coefficient's. What the model computes is unchanged."""
    import torch

    owners = [*model.policy.modules(), model]
    for owner in owners:
        for name in ("optimizer", "ent_coef_optimizer"):
            optimizer = getattr(owner, name, None)
            if isinstance(optimizer, torch.optim.Optimizer):
                optimizer.state.clear()


def ship(
    run_dir: str | Path, name: str, policy_dir: str | Path = POLICY_DIR, last: bool = False
) -> Path:
    """Copy the finished run in ``run_dir`` to ``<policy_dir>/<name>.zip`` with its
    metadata ``<name>.json``; the metadata's path. The model is the run's best-evaluated
    one when it kept one, unless ``last``: then the model at the end of training.

    Raises:
        InvalidParameterError: a name that is not lowercase letters, digits and dashes, or
            that of a built-in policy (``load_policy`` would never find the shipped one); a
            run without ``model.zip``, ``state.json`` and ``result.json`` (an unfinished run),
            or whose JSON files are not what ``pourbench train`` writes. Nothing is written
            then, nor when the model cannot be saved.
    """
    from pourbench.agents.loading import load_model

    if not isinstance(name, str) or not _NAME.match(name):
        raise InvalidParameterError(
            f"a policy name is lowercase letters, digits and dashes, got {name!r}"
        )
    if name in BUILTIN_POLICIES:
        raise InvalidParameterError(
            f"{name!r} is a built-in policy ({', '.join(BUILTIN_POLICIES)}); give another name"
        )
    run = Path(run_dir)
    missing = [f for f in ("model.zip", "state.json", "result.json") if not (run / f).is_file()]
    if missing:
        raise InvalidParameterError(
            f"{str(run)!r} is not a finished training run: no {', '.join(missing)}"
        )
    state_path, result_path = run / "state.json", run / "result.json"
    state = _read_run_json(state_path, ("args", "timesteps", "train_s"))
    settings = state["args"]
    if not isinstance(settings, dict) or any(k not in settings for k in _ARGS_KEYS):
        raise InvalidParameterError(
            f"{str(state_path)!r}: 'args' must be an object with "
            f"{', '.join(_ARGS_KEYS)}, got {settings!r}"
        )
    sessions = state.get("history", [])
    if not isinstance(sessions, list) or not all(isinstance(s, dict) for s in sessions):
        raise InvalidParameterError(
            f"{str(state_path)!r}: 'history' must be a list of objects, got {sessions!r}"
        )
    result = _read_run_json(result_path, ("mean_abs_error_g", "policy", "random_mean_abs_error_g"))
    best = result.get("best")
    if best is not None and not isinstance(best, dict):
        raise InvalidParameterError(f"{str(result_path)!r}: 'best' must be an object, got {best!r}")
    use_best = best is not None and not last and (run / "best_model.zip").is_file()
    checkpoint = {"file": "best_model.zip", **best} if use_best else {
        "file": "model.zip", "timesteps": state["timesteps"]
    }  # fmt: skip
    model = load_model(run / checkpoint["file"])
    _drop_optimiser_state(model)
    meta: dict[str, Any] = {
        "name": name,
        "algorithm": settings["algorithm"],
        "policy": settings["policy"],
        "commands": [s.get("command") for s in sessions],
        "steps": state["timesteps"],
        "seed": settings["seed"],
        "wall_time_s": state["train_s"],
        "git_sha": [s.get("git_sha") for s in sessions],
        "machine": [s.get("machine") for s in sessions],
        "date": [s.get("date") for s in sessions],
        "settings": settings,
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
    out = Path(policy_dir)
    out.mkdir(parents=True, exist_ok=True)
    partial = out / f"{name}.partial.zip"
    try:
        model.save(partial)
        partial.replace(out / f"{name}.zip")
    finally:
        partial.unlink(missing_ok=True)
    return write_text_atomic(out / f"{name}.json", json.dumps(meta, indent=2) + "\n")


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
