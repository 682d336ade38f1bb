"""Residual policies over the PD baseline (residual reinforcement learning: Johannink et al.
2019, Silver et al. 2018).

``pourbench train --residual S`` trains a policy whose action ``a`` in [-1, 1]² is added to
the PD baseline's (:mod:`pourbench.agents.pd`), which sees the same observations:

    action = clip(PD(obs) + S · a, -1, 1)

The policy's action head starts at zero, so the untrained policy pours exactly as the PD
does, and PPO learns a correction of at most ``S`` per action dimension. The scale is the
model's attribute :data:`ATTRIBUTE` and is saved in its ``.zip`` (SB3 saves a model's
attributes), so :func:`pourbench.agents.loading.load_policy` runs a saved residual model
with its PD without any other file.

:class:`ResidualVecEnv` is the training side (an SB3 VecEnv wrapper: one PD for every world,
reset with its world's episode); :func:`residual_policy` the acting side
(``f(obs, new_episode)``). Written by hand: neither SB3 nor sb3-contrib has residual
policies.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecEnvWrapper

from pourbench.agents.models import set_policy_std
from pourbench.agents.pd import PDPourer

ATTRIBUTE = "pd_residual"
"""The model attribute that holds the residual scale S (absent or 0: a plain policy)."""


def combine(pd_action: np.ndarray, residual: np.ndarray, scale: float) -> np.ndarray:
    """``clip(pd_action + scale · clip(residual, -1, 1), -1, 1)`` as float32."""
    total = pd_action + scale * np.clip(residual, -1.0, 1.0)
    return np.clip(total, -1.0, 1.0).astype(np.float32)


class ResidualVecEnv(VecEnvWrapper):
    """``venv`` acted on by ``PD(obs) + scale · action`` (see the module docstring); the
    observations, rewards and infos are ``venv``'s. ``scale`` in (0, 1]; it is checked by
    the training config."""

    def __init__(self, venv: Any, scale: float) -> None:
        super().__init__(venv)
        self.scale = float(scale)
        self.pd = PDPourer(venv.num_envs)
        self._obs: Any = None  # the observations the PD acts on next (set by reset)

    def reset(self) -> np.ndarray:
        self._obs = self.venv.reset()
        self.pd.reset()
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        self.venv.step_async(combine(self.pd.act(self._obs), actions, self.scale))

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        self.pd.reset(np.asarray(dones, bool))  # a done world's obs is its next episode's
        self._obs = obs
        return obs, rewards, dones, infos


def residual_policy(act: Any, scale: float) -> Any:
    """The policy ``f(obs, new_episode)`` that adds ``scale ·`` ``act(obs, new_episode)`` (a
    residual policy's own action) to a fresh PD's, which is reset with each episode."""
    pd = PDPourer(1)

    def policy(obs: np.ndarray, new: bool) -> np.ndarray:
        if new:
            pd.reset()
        return combine(pd.act(obs), act(obs, new), scale)

    return policy


def start_residual(model: Any, scale: float, std: float | None = None) -> None:
    """Make the new PPO or RecurrentPPO ``model`` a residual policy of ``scale``: record the
    scale (:data:`ATTRIBUTE`, saved with the model), set its action head to zero, weights
    and bias, so its mean action is 0 in every state and it starts as the PD, and its
    standard deviation to ``std`` per action dimension when given
    (:func:`~pourbench.agents.models.set_policy_std`)."""
    setattr(model, ATTRIBUTE, scale)
    with torch.no_grad():
        model.policy.action_net.weight.zero_()
        model.policy.action_net.bias.zero_()
    if std is not None:
        set_policy_std(model, std)
