"""Evaluate a pouring policy on ``pourbench/Pour-v0``: error, spill and success per episode.

Used by ``pourbench eval`` (the thesis' Table 6.3 protocol: a liquid, a target, n pours). A
policy is anything :func:`~pourbench.agents.loading.load_policy` takes ("pd", "random", a
shipped policy's name, or the path of a model saved by ``pourbench train``: PPO,
RecurrentPPO or SAC) or a callable ``f(obs, new_episode) -> action``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from tqdm import tqdm

from pourbench.agents.loading import load_policy, load_sb3_policy
from pourbench.envs.pour_v0 import PourEnv, check_settings
from pourbench.errors import check_int, check_positive

__all__ = ["EvalResult", "evaluate", "load_sb3_policy", "pour_episode"]


TABLE_6_2 = ("water", "ink", "oil", "glycerine", "honey", "ketchup")
"""The thesis' Table 6.2 liquids, PourNet's evaluation set, in Table 6.3's column order."""


@dataclass(frozen=True)
class EvalResult:
    """Per-episode outcomes (grams) and their summary.

    Attributes:
        errors_g: |poured − target| per episode, g.
        spilled_g: liquid on the table per episode, g.
        success: episode ended normally with error ≤ 10 g.
        steps: environment steps per episode.
    """

    errors_g: np.ndarray
    spilled_g: np.ndarray
    success: np.ndarray
    steps: np.ndarray

    @property
    def mean_abs_error_g(self) -> float:
        return float(np.mean(self.errors_g))

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.success))

    @classmethod
    def join(cls, *results: EvalResult) -> EvalResult:
        """The episodes of ``results`` as one result."""
        return cls(*(np.concatenate([getattr(r, f.name) for r in results]) for f in fields(cls)))

    def summary(self) -> str:
        """One line: mean absolute error ± std, mean spill, success rate."""
        return (
            f"mean abs error {self.mean_abs_error_g:.2f} ± {np.std(self.errors_g):.2f} g, "
            f"spill {np.mean(self.spilled_g):.2f} g, success {100 * self.success_rate:.0f} % "
            f"over {len(self.errors_g)} episodes"
        )


def pour_episode(
    env: Any, act: Callable[[np.ndarray, bool], np.ndarray], seed: int, options: dict
) -> tuple[dict[str, Any], int]:
    """Reset ``env`` (a pouring env: Pour-v0 or PourRobot-v0) with ``seed`` and ``options``
    and let ``act`` pour until the episode ends; the last step's info and the step count."""
    obs, info = env.reset(seed=seed, options=options)
    new, done, steps = True, False, 0
    while not done:
        obs, _, term, trunc, info = env.step(act(obs, new))
        new, done, steps = False, term or trunc, steps + 1
    return info, steps


def evaluate(
    policy: str | Callable[[np.ndarray, bool], np.ndarray],
    episodes: int = 10,
    target_g: float | None = 100.0,
    seed: int = 0,
    progress: bool = False,
    **env_kwargs: Any,
) -> EvalResult:
    """Run ``episodes`` episodes (seeds ``seed``, ``seed + 1``, …) and collect the outcomes.

    Args:
        policy: "pd", "random", a shipped policy's name, a saved model's path, or a
            callable ``f(obs, new_episode) -> action``.
        target_g: target of every episode, a number > 0 (None: drawn by the env), g.
        progress: show a progress bar.
        **env_kwargs: :class:`~pourbench.envs.core.PourConfig` fields (e.g. ``liquid``),
            or :class:`~pourbench.envs.pour_v0.PourEnv`'s ``render_mode`` / ``record_path``.

    Raises:
        InvalidParameterError: ``episodes`` not an integer >= 1, ``seed`` not an integer
            >= 0, ``target_g`` neither None nor a finite number > 0 (a bool or a string such
            as ``"100"`` is refused, not converted), a policy that is neither a name, a path
            nor a callable, or an unknown ``env_kwargs`` name; all checked before any episode
            runs.
    """
    episodes = check_int("episodes", episodes, minimum=1)
    seed = check_int("seed", seed, minimum=0)
    options = {} if target_g is None else {"target_g": check_positive("target_g", target_g)}
    check_settings(env_kwargs, also=("render_mode", "record_path"))
    act = policy if callable(policy) else load_policy(policy, seed)
    env = PourEnv(**env_kwargs)
    errors, spills, success, steps = [], [], [], []
    for ep in tqdm(range(episodes), desc="episodes", disable=not progress):
        info, n = pour_episode(env, act, seed + ep, options)
        errors.append(info["error_g"])
        spills.append(info["spilled_g"])
        success.append(bool(info["is_success"]))
        steps.append(n)
    env.close()
    return EvalResult(np.array(errors), np.array(spills), np.array(success), np.array(steps))
