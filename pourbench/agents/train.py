"""Train PPO (SB3, MLP policy) on ``pourbench/Pour-v0`` for a wall-clock budget, then compare
it with a random policy on the same evaluation episodes.

``python -m pourbench.agents.train --budget-s 900 --liquid water --target-g 100``
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np


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


def train(args: TrainArgs) -> dict:
    """Train for ``args.budget_s`` seconds and evaluate PPO and a random policy."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    from pourbench.agents.evaluate import evaluate
    from pourbench.agents.sb3 import SB3PourVecEnv

    torch.set_num_threads(args.threads)
    target = (args.target_g, args.target_g)
    venv = SB3PourVecEnv(args.num_envs, seed=args.seed, liquid=args.liquid, target_range_g=target)

    class Budget(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.t0 = time.perf_counter()

        def _on_step(self) -> bool:
            return time.perf_counter() - self.t0 < args.budget_s

    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=args.n_steps,
        batch_size=64,
        n_epochs=10,
        gamma=0.995,
        seed=args.seed,
        device="cpu",
        verbose=1,
    )
    t0 = time.perf_counter()
    model.learn(total_timesteps=10**9, callback=Budget())
    train_s = time.perf_counter() - t0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "model")

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
    (out / "result.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for name, value in asdict(TrainArgs()).items():
        parser.add_argument(f"--{name.replace('_', '-')}", type=type(value), default=value)
    result = train(TrainArgs(**vars(parser.parse_args())))
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
