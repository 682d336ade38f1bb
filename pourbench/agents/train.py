"""Train PPO (SB3, MLP policy) on ``pourbench/Pour-v0`` for a wall-clock budget, then compare
it with a random policy on the same evaluation episodes.

``pourbench train --budget-s 900 --liquid water --target-g 100`` (or
``python -m pourbench.agents.train …``, the same flags)

The model is saved to ``<out>/model.zip`` every ``--checkpoint-s`` seconds and at the end
(through a temporary file, so an interrupted run keeps its last checkpoint); ``--resume``
continues from it, step counter included. A run into a folder that already holds a model
without ``--resume`` is refused rather than overwriting it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pourbench.errors import InvalidParameterError, check_int, check_positive


@dataclass
class TrainArgs:
    """Training settings.

    Attributes:
        budget_s: wall-clock training budget, s.
        num_envs: parallel worlds in the one vector env.
        liquid: liquid of every episode.
        target_g: target of every episode, g.
        n_steps: PPO rollout length per world.
        seed: seed of PPO and of the worlds (evaluation uses seeds 1000…).
        eval_episodes: evaluation episodes per policy.
        threads: torch threads.
        out: folder for the model and the result JSON.
        checkpoint_s: seconds between checkpoints of the model.
        resume: continue from ``<out>/model.zip``.
    """

    budget_s: float = 900.0
    num_envs: int = 4
    liquid: str = "water"
    target_g: float = 100.0
    n_steps: int = 64
    seed: int = 0
    eval_episodes: int = 10
    threads: int = 1
    out: str = "runs/ppo_pour"
    checkpoint_s: float = 60.0
    resume: bool = False

    def __post_init__(self) -> None:
        """Every setting checked at construction, before any training: a run that trains is
        not lost to a bad setting its evaluation would meet only at the end."""
        for name in ("budget_s", "target_g", "checkpoint_s"):
            check_positive(name, getattr(self, name))
        for name in ("num_envs", "n_steps", "eval_episodes", "threads"):
            check_int(name, getattr(self, name), minimum=1)
        check_int("seed", self.seed, minimum=0)
        # PPO's minibatch is min(64, n_steps * num_envs) samples and SB3 needs more than one
        if self.n_steps * self.num_envs < 2:
            raise InvalidParameterError(
                "n_steps * num_envs (the PPO rollout, and its minibatch size up to 64) must be "
                f">= 2, got n_steps={self.n_steps!r} and num_envs={self.num_envs!r}"
            )
        if not isinstance(self.liquid, str) or not self.liquid:
            raise InvalidParameterError(f"liquid must be a liquid name, got {self.liquid!r}")
        if not isinstance(self.resume, bool):
            raise InvalidParameterError(f"resume must be True or False, got {self.resume!r}")
        if not isinstance(self.out, str | os.PathLike) or not os.fspath(self.out):
            raise InvalidParameterError(f"out must be a non-empty folder path, got {self.out!r}")
        self.out = os.fspath(self.out)  # a str, as result.json records it


def _save(model, path: Path) -> None:
    """``model`` to ``path`` (``.zip``) through a temporary file."""
    partial = path.with_name(path.stem + ".partial.zip")
    model.save(partial)
    os.replace(partial, path)


def train(args: TrainArgs) -> dict:
    """Train for ``args.budget_s`` seconds and evaluate PPO and a random policy."""
    from pourbench.envs.core import _known_liquid
    from pourbench.outputs import OutputPathError, check_output_folder, write_text_atomic

    _known_liquid(args.liquid)  # before any work: a typo fails in a second
    out = check_output_folder(args.out)
    model_path = out / "model.zip"
    if args.resume and not model_path.exists():
        raise OutputPathError(f"--resume: no model to resume from at {str(model_path)!r}")
    if not args.resume and model_path.exists():
        raise OutputPathError(
            f"{str(model_path)!r} exists; pass --resume to continue it or another --out"
        )

    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    from pourbench.agents.evaluate import evaluate
    from pourbench.agents.sb3 import SB3PourVecEnv

    torch.set_num_threads(args.threads)
    target = (args.target_g, args.target_g)
    venv = SB3PourVecEnv(args.num_envs, seed=args.seed, liquid=args.liquid, target_range_g=target)

    class BudgetAndCheckpoints(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.t0 = self.saved = time.perf_counter()

        def _on_step(self) -> bool:
            now = time.perf_counter()
            if now - self.saved >= args.checkpoint_s:
                _save(self.model, model_path)
                self.saved = now
            return now - self.t0 < args.budget_s

    if args.resume:
        try:
            model = PPO.load(model_path, env=venv, device="cpu")
        except Exception as exc:  # a corrupt or foreign file: name it, say what is wrong
            venv.close()
            raise InvalidParameterError(
                f"--resume: {str(model_path)!r} is not a readable PPO model "
                f"({type(exc).__name__}: {exc})"
            ) from exc
        print(f"resuming {model_path} at {model.num_timesteps} timesteps")
    else:
        model = PPO(
            "MlpPolicy",
            venv,
            n_steps=args.n_steps,
            batch_size=min(64, args.n_steps * args.num_envs),
            n_epochs=10,
            gamma=0.995,
            seed=args.seed,
            device="cpu",
            verbose=1,
        )
    t0 = time.perf_counter()
    model.learn(
        total_timesteps=10**9,
        callback=BudgetAndCheckpoints(),
        reset_num_timesteps=not args.resume,
    )
    train_s = time.perf_counter() - t0
    _save(model, model_path)

    def ppo_policy(obs: np.ndarray, new: bool) -> np.ndarray:
        return model.predict(obs, deterministic=True)[0]

    kw = {"liquid": args.liquid}
    ppo = evaluate(ppo_policy, args.eval_episodes, args.target_g, seed=1000, **kw)
    rnd = evaluate("random", args.eval_episodes, args.target_g, seed=1000, **kw)
    result = {
        "args": asdict(args),
        "train_s": train_s,
        "timesteps": int(model.num_timesteps),
        "ppo_mean_abs_error_g": ppo.mean_abs_error_g,
        "random_mean_abs_error_g": rnd.mean_abs_error_g,
        "ppo": ppo.summary(),
        "random": rnd.summary(),
    }
    write_text_atomic(out / "result.json", json.dumps(result, indent=2) + "\n")
    return result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """One ``--flag`` per :class:`TrainArgs` field (``pourbench train`` and ``main`` share it)."""
    helps = _field_help()
    for name, value in asdict(TrainArgs()).items():
        flag = f"--{name.replace('_', '-')}"
        if isinstance(value, bool):
            parser.add_argument(flag, action="store_true", help=helps[name])
        else:
            parser.add_argument(flag, type=type(value), default=value, help=helps[name])


def _field_help() -> dict[str, str]:
    """Each field's line of :class:`TrainArgs`' ``Attributes:`` section."""
    doc = (TrainArgs.__doc__ or "").split("Attributes:", 1)[-1]
    helps: dict[str, str] = {}
    for line in doc.splitlines():
        name, sep, text = line.strip().partition(": ")
        if sep and name in TrainArgs.__dataclass_fields__:
            helps[name] = text.replace("``", "")
        elif helps and line.strip():  # a wrapped description goes on
            last = next(reversed(helps))
            helps[last] += " " + line.strip()
    return {k: v.rstrip(".") for k, v in helps.items()}


def run(args: argparse.Namespace) -> int:
    """Train with the parsed flags and print the result JSON (``ValueError`` on bad input)."""
    fields = TrainArgs.__dataclass_fields__
    result = train(TrainArgs(**{k: v for k, v in vars(args).items() if k in fields}))
    print(json.dumps(result, indent=2))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    try:
        return run(parser.parse_args(argv))
    except ValueError as exc:  # bad input: one clear line, no traceback
        print(f"pourbench.agents.train: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
