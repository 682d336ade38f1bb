"""Training callbacks for ``pourbench train``: pouring statistics and ICM losses to the
logger, a wall-clock budget with its progress bar, checkpoints, and periodic evaluation.

Logged keys (TensorBoard and ``progress.csv``), besides SB3's own ``rollout/ep_rew_mean``,
``rollout/ep_len_mean`` (from the VecMonitor; extrinsic reward) and
``rollout/success_rate`` (from ``info["is_success"]``):

* ``pour/error_g``: mean |poured − target| of the episodes ended since the last dump, g;
* ``pour/average_error_g``: the env's running average pouring error (thesis §6.5.1), g,
  averaged over the worlds that have completed an episode (absent until one has);
* ``icm/inverse_loss``, ``icm/forward_loss``, ``icm/intrinsic_reward`` (mean per step);
* ``eval/mean_abs_error_g``, ``eval/success_rate``: each periodic evaluation.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm


class PourStatsCallback(BaseCallback):
    """Pouring error of finished episodes, and the ICM's stats when ``icm`` (an
    :class:`~pourbench.agents.icm.ICMVecEnv`) is given, recorded at each rollout's end."""

    def __init__(self, icm: Any = None) -> None:
        super().__init__()
        self.icm = icm
        self.errors: list[float] = []
        self.averages: dict[int, float] = {}  # world -> its latest running average, g

    def _on_step(self) -> bool:
        infos = self.locals["infos"]
        for world, (done, info) in enumerate(zip(self.locals["dones"], infos, strict=True)):
            if done and "error_g" in info:
                self.errors.append(float(info["error_g"]))
                if info["completed_episodes"] > 0:  # else the world has no average yet
                    self.averages[world] = float(info["average_error_g"])
        return True

    def _on_rollout_end(self) -> None:
        if self.errors:
            self.logger.record("pour/error_g", float(np.mean(self.errors)))
            self.errors.clear()
        if self.averages:
            self.logger.record("pour/average_error_g", float(np.mean(list(self.averages.values()))))
        if self.icm is not None:
            for key, value in self.icm.stats.items():
                self.logger.record(f"icm/{key}", value)


class BudgetCallback(BaseCallback):
    """Stops training after ``budget_s`` seconds of this session (None: no time limit; a
    step budget is ``learn``'s ``total_timesteps``), shows a progress bar of those seconds,
    and calls ``checkpoint()`` every ``checkpoint_s`` seconds."""

    def __init__(
        self, budget_s: float | None, checkpoint_s: float, checkpoint: Callable[[], None]
    ) -> None:
        super().__init__()
        self.budget_s, self.checkpoint_s, self.checkpoint = budget_s, checkpoint_s, checkpoint
        self.t0 = self.saved = time.perf_counter()
        self.bar: tqdm | None = None

    def _on_training_start(self) -> None:
        self.t0 = self.saved = time.perf_counter()
        if self.budget_s is not None:
            self.bar = tqdm(total=round(self.budget_s), unit="s", desc="training (wall clock)")

    def _on_step(self) -> bool:
        now = time.perf_counter()
        if now - self.saved >= self.checkpoint_s:
            self.checkpoint()
            self.saved = now
        if self.bar is not None and int(now - self.t0) != self.bar.n:  # once a second
            self.bar.n = min(int(now - self.t0), self.bar.total)
            self.bar.set_postfix(steps=self.num_timesteps, refresh=False)
            self.bar.refresh()
        return self.budget_s is None or now - self.t0 < self.budget_s

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.close()


class EvalCallback(BaseCallback):
    """Every ``every_steps`` environment steps, ``evaluate(policy())`` (a callable that
    returns an :class:`~pourbench.agents.evaluate.EvalResult`, with its own progress bar),
    record its mean absolute error and success rate, and write them out at once with the
    step count: an off-policy learner writes its log only every few episodes, and a short
    run's evaluations would otherwise never reach ``progress.csv``."""

    def __init__(self, every_steps: int, evaluate: Callable[[], Any]) -> None:
        super().__init__()
        self.every_steps, self.evaluate = every_steps, evaluate
        self.next_at = every_steps

    def _on_training_start(self) -> None:
        self.next_at = (self.num_timesteps // self.every_steps + 1) * self.every_steps

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next_at:
            self.next_at += self.every_steps
            result = self.evaluate()
            self.logger.record("eval/mean_abs_error_g", result.mean_abs_error_g)
            self.logger.record("eval/success_rate", result.success_rate)
            self.logger.record("time/total_timesteps", self.num_timesteps)
            self.logger.dump(self.num_timesteps)
            print(f"evaluation at {self.num_timesteps} steps: {result.summary()}")
        return True
