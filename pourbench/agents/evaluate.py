"""Evaluate a pouring policy on ``pourbench/Pour-v0``: error, spill and success per episode.

Used by ``pourbench eval`` (the thesis' Table 6.3 protocol: a liquid, a target, n pours). A
policy is "pd", "random", or the path of a Stable-Baselines3 model saved by training
(``runs/ppo_pour/model.zip`` from ``python -m pourbench.agents.train``; PPO or RecurrentPPO).
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from pourbench.agents.pd import PDConfig, PDPourer
from pourbench.argtypes import BUILTIN_POLICIES
from pourbench.envs.pour import PourEnv, check_settings
from pourbench.errors import InvalidParameterError, check_int

POLICIES = BUILTIN_POLICIES


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

    def summary(self) -> str:
        """One line: mean absolute error ± std, mean spill, success rate."""
        return (
            f"mean abs error {self.mean_abs_error_g:.2f} ± {np.std(self.errors_g):.2f} g, "
            f"spill {np.mean(self.spilled_g):.2f} g, success {100 * self.success_rate:.0f} % "
            f"over {len(self.errors_g)} episodes"
        )


def load_sb3_policy(path: str | Path) -> Callable[[np.ndarray, bool], np.ndarray]:
    """A trained Stable-Baselines3 model (``.zip``) as a policy ``f(obs, new_episode)``, acting
    deterministically; a recurrent policy's memory is cleared at each new episode.

    Raises:
        ValueError: the file is missing, is not a PPO / RecurrentPPO model, or its spaces are
            not Pour-v0's (12 observations, 2 actions).
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no policy file at {str(p)!r}; policies: {list(POLICIES)} or a model.zip")
    if not zipfile.is_zipfile(p):
        raise ValueError(f"{str(p)!r} is not a saved Stable-Baselines3 model (not a zip file)")
    from sb3_contrib import RecurrentPPO
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
    from stable_baselines3 import PPO

    try:  # PPO's loader also reads a RecurrentPPO file, whose policy class tells them apart
        model = PPO.load(p, device="cpu")
    except Exception as exc:  # any unreadable file is the same bad input
        raise ValueError(
            f"{str(p)!r} is not a PPO or RecurrentPPO model ({type(exc).__name__}: {exc})"
        ) from None
    if isinstance(model.policy, RecurrentActorCriticPolicy):
        model = RecurrentPPO.load(p, device="cpu")
    obs_shape = tuple(model.observation_space.shape or ())
    act_shape = tuple(model.action_space.shape or ())
    if obs_shape != (12,) or act_shape != (2,):
        raise ValueError(
            f"{str(p)!r} was trained on observations {obs_shape} and actions {act_shape}; "
            "Pour-v0 has (12,) and (2,)"
        )
    recurrent = isinstance(model, RecurrentPPO)
    state: list[Any] = [None]

    def act(obs: np.ndarray, new: bool) -> np.ndarray:
        if not recurrent:
            return model.predict(obs, deterministic=True)[0]
        action, state[0] = model.predict(
            obs, state=None if new else state[0], episode_start=np.array([new]), deterministic=True
        )
        return action

    return act


def make_policy(name: str, seed: int = 0) -> Callable[[np.ndarray, bool], np.ndarray]:
    """A policy ``f(obs, new_episode) -> action`` by name ("pd" or "random") or the path of a
    saved model (:func:`load_sb3_policy`); ``seed`` (an integer >= 0) seeds "random"."""
    if isinstance(name, os.PathLike):
        name = os.fspath(name)
    if not isinstance(name, str):
        raise InvalidParameterError(
            f"policy must be one of {list(POLICIES)}, a saved model's path or a callable "
            f"f(obs, new_episode), got {name!r}"
        )
    seed = check_int("seed", seed, minimum=0)
    if name == "pd":
        pd = PDPourer(1, PDConfig())

        def act(obs: np.ndarray, new: bool) -> np.ndarray:
            if new:
                pd.reset()
            return pd.act(obs)

        return act
    if name == "random":
        rng = np.random.default_rng(seed)
        return lambda obs, new: rng.uniform(-1.0, 1.0, 2).astype(np.float32)
    if name.endswith(".zip") or Path(name).is_file():
        return load_sb3_policy(name)
    raise ValueError(f"unknown policy {name!r}; known: {list(POLICIES)} or a saved model.zip")


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
        policy: "pd", "random", a saved model's path, or a callable
            ``f(obs, new_episode) -> action``.
        episodes: number of episodes.
        target_g: target of every episode (None: drawn by the env), g.
        seed: first episode's seed.
        progress: show a progress bar.
        **env_kwargs: :class:`~pourbench.envs.core.PourConfig` fields (e.g. ``liquid``),
            or :class:`~pourbench.envs.pour.PourEnv`'s ``render_mode`` / ``record_path``.

    Raises:
        InvalidParameterError: ``episodes`` not an integer >= 1, ``seed`` not an integer
            >= 0, a policy that is neither a name, a path nor a callable, or an unknown
            ``env_kwargs`` name; all checked before any episode runs.
    """
    episodes = check_int("episodes", episodes, minimum=1)
    seed = check_int("seed", seed, minimum=0)
    check_settings(env_kwargs, also=("render_mode", "record_path"))
    act = policy if callable(policy) else make_policy(policy, seed)  # type: ignore[arg-type]
    env = PourEnv(**env_kwargs)
    errors, spills, success, steps = [], [], [], []
    options = {} if target_g is None else {"target_g": float(target_g)}
    for ep in tqdm(range(episodes), desc="episodes", disable=not progress):
        obs, _ = env.reset(seed=seed + ep, options=options)
        new, done, n = True, False, 0
        while not done:
            obs, _, term, trunc, info = env.step(act(obs, new))
            new, done, n = False, term or trunc, n + 1
        errors.append(info["error_g"])
        spills.append(info["spilled_g"])
        success.append(bool(info["is_success"]))
        steps.append(n)
    env.close()
    return EvalResult(np.array(errors), np.array(spills), np.array(success), np.array(steps))
