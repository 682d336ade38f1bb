"""The thesis' PourNet architectures (§6.5.8) as Stable-Baselines3 / sb3-contrib models.

* **FNN**: PPO with an MLP policy and value network of 3 × 256 (tanh, SB3's default).
* **LSTM**: RecurrentPPO with an LSTM of 256 units (the thesis' "memory size 256") followed by
  3 × 256 layers for the policy and the value (the thesis' "3 layers × 256 hidden units" are
  ML-Agents' dense layers around one recurrent memory; sb3-contrib puts the LSTM first, then
  ``net_arch``). The actor and the critic each have their own LSTM (sb3-contrib's default).
* **SAC** (the thesis' comparison, §6.5.2), **TQC** and **CrossQ** (sb3-contrib) and
  **TD3**, the off-policy learners: actor and critics of 3 × 256 (CrossQ's critics with its
  batch renormalisation, without target networks), a replay buffer of a million transitions,
  and ``utd`` gradient updates per environment step (the update-to-data ratio). TD3's policy
  is deterministic and explores with Gaussian noise of :data:`TD3_NOISE` added to its actions
  (clipped to the action bounds), the spread of the TD3 paper; the others learn their
  spread.

Sequence length: sb3-contrib has no such setting. It backpropagates through each world's
part of a rollout, ``n_steps`` steps, cut at episode starts and at minibatch edges, so a
sequence is at most ``n_steps`` long; ``n_steps = seq_len = 64`` gives the thesis' 64. The
training config refuses a recurrent run whose ``seq_len`` differs from ``n_steps``.

Inputs: every network sees the observation divided by :data:`OBS_SCALE`
(:class:`ScaledObservation`), a fixed scale per feature that brings grams, metres and FleX
coefficients to order one, so that a 150 g target does not saturate the first tanh layer. It
is part of the saved policy, so a loaded model needs no separate normaliser.

Discount 0.995 (Algorithm 5's reward is sparse and an episode is up to 250 steps); the other
hyper-parameters are SB3's defaults.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from pourbench.agents.loading import LR_SCHEDULES, NO_SDE, OFF_POLICY, check_ent_coef
from pourbench.errors import InvalidParameterError

HIDDEN = (256, 256, 256)
"""Hidden layers of every PourNet network (thesis §6.5.8)."""
LSTM_UNITS = 256
"""LSTM memory of the recurrent PourNet (thesis §6.5.8.1)."""
GAMMA = 0.995
REPLAY_SIZE = 1_000_000
"""Transitions an off-policy learner's replay buffer holds."""
TD3_NOISE = 0.1
"""Standard deviation of TD3's exploration noise on each action in [-1, 1]."""

OBS_SCALE = (1.0, 0.0025, 0.0075, 1.0, 0.1, 0.1, 0.1, 100.0, 100.0, 100.0, 100.0, 1.0)
"""The unit each Pour-v0 observation feature is divided by before the networks: density g/ml,
cohesion and surface tension at the curriculum's largest, log10 viscosity in mPa·s, adhesion
at the curriculum's largest, the container's diameter and depth in 10 cm, the four weights in
100 g, the tilt in rad."""


class ScaledObservation(BaseFeaturesExtractor):
    """The observation divided by :data:`OBS_SCALE`, feature by feature (no parameters)."""

    def __init__(self, observation_space: gym.spaces.Box) -> None:
        super().__init__(observation_space, features_dim=len(OBS_SCALE))
        if observation_space.shape != (len(OBS_SCALE),):
            raise InvalidParameterError(
                f"ScaledObservation takes Pour-v0's {len(OBS_SCALE)} observations, got shape "
                f"{observation_space.shape}"
            )
        self.register_buffer("inverse", 1.0 / torch.tensor(OBS_SCALE, dtype=torch.float32))

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return observations * self.inverse


def make_model(
    algorithm: str,
    env: Any,
    *,
    n_steps: int = 64,
    batch_size: int = 256,
    seed: int = 0,
    learning_rate: float = 3e-4,
    lr_schedule: str = "constant",
    target_kl: float | None = None,
    sde: bool = False,
    utd: float = 0.0,
    ent_coef: float = 0.0,
    verbose: int = 1,
) -> Any:
    """A new model of ``algorithm`` ("ppo": FNN, "recurrent_ppo": LSTM, or an off-policy
    learner of :data:`OFF_POLICY`) on ``env``.

    Args:
        env: the SB3 VecEnv it trains on.
        n_steps: PPO / RecurrentPPO rollout length per world (also the LSTM sequence bound).
        batch_size: minibatch size in samples (at most the rollout, ``n_steps × num_envs``,
            for PPO; SAC's batch from its replay buffer).
        seed: seed of the networks and the sampling.
        learning_rate: Adam's step size (SB3's default 3e-4).
        lr_schedule: one of :data:`LR_SCHEDULES`: ``"constant"``, or ``"linear"``, the step
            size falling linearly from ``learning_rate`` at the start to zero at the end of
            the ``total_timesteps`` that SB3's ``learn`` is given (SB3 counts a resumed run's
            earlier steps into them, so a resumed run continues the same line).
        target_kl: PPO and RecurrentPPO stop an update's epochs once the policy's KL
            divergence from the rollout's passes this (None: no limit, SB3's default).
        sde: generalized state-dependent exploration (SB3's ``use_sde``), its noise drawn
            once per rollout.
        utd: the off-policy learners' gradient updates per environment step (one world's
            step): each vector step of ``env.num_envs`` worlds is followed by
            ``max(1, round(utd × num_envs))`` updates; 0: one update per vector step (SB3's
            default).
        ent_coef: SAC, TQC and CrossQ: the entropy coefficient, held fixed (0: tuned
            toward SB3's target entropy, its default).
        verbose: SB3's verbosity.

    Raises:
        InvalidParameterError: an unknown algorithm or schedule, or ``ent_coef`` for a learner
            without an entropy coefficient.
    """
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.utils import LinearSchedule

    if lr_schedule not in LR_SCHEDULES:
        raise InvalidParameterError(
            f"lr_schedule must be one of {list(LR_SCHEDULES)}, got {lr_schedule!r}"
        )
    check_ent_coef(algorithm, ent_coef)
    rate: Any = learning_rate
    if lr_schedule == "linear":
        rate = LinearSchedule(start=learning_rate, end=0.0, end_fraction=1.0)

    common: dict[str, Any] = {
        "seed": seed,
        "device": "cpu",
        "verbose": verbose,
        "gamma": GAMMA,
        "learning_rate": rate,
        "use_sde": sde,
    }
    extractor = {"features_extractor_class": ScaledObservation}
    if algorithm in ("ppo", "recurrent_ppo"):
        common.update(n_steps=n_steps, batch_size=min(batch_size, n_steps * env.num_envs))
        arch = {"net_arch": {"pi": list(HIDDEN), "vf": list(HIDDEN)}, **extractor}
        if algorithm == "ppo":
            return PPO("MlpPolicy", env, target_kl=target_kl, policy_kwargs=arch, **common)
        from sb3_contrib import RecurrentPPO

        lstm = {"lstm_hidden_size": LSTM_UNITS, "n_lstm_layers": 1, **arch}
        return RecurrentPPO("MlpLstmPolicy", env, target_kl=target_kl, policy_kwargs=lstm, **common)
    if algorithm in OFF_POLICY:
        from sb3_contrib import TQC, CrossQ

        cls = {"sac": SAC, "tqc": TQC, "crossq": CrossQ, "td3": TD3}[algorithm]
        if algorithm in NO_SDE:
            if sde:
                raise InvalidParameterError(
                    f"sde: {NO_SDE[algorithm]} explores with its own noise only"
                )
            del common["use_sde"]
        if ent_coef:
            common["ent_coef"] = float(ent_coef)
        if algorithm == "td3":
            from stable_baselines3.common.noise import NormalActionNoise

            dim = env.action_space.shape[0]
            common["action_noise"] = NormalActionNoise(np.zeros(dim), np.full(dim, TD3_NOISE))
        arch = {"net_arch": list(HIDDEN), **extractor}
        return cls(
            "MlpPolicy",
            env,
            batch_size=batch_size,
            buffer_size=REPLAY_SIZE,
            gradient_steps=gradient_steps(utd, env.num_envs),
            policy_kwargs=arch,
            **common,
        )
    raise InvalidParameterError(
        f"algorithm must be one of {['ppo', 'recurrent_ppo', *OFF_POLICY]}, got {algorithm!r}"
    )


def set_policy_std(model: Any, std: float) -> None:
    """Set the new PPO or RecurrentPPO ``model``'s standard deviation to ``std`` per action
    dimension. With gSDE (``use_sde``), whose spread per action is
    ``‖features‖ · exp(log_std)`` over the policy's last hidden layer of d units (each in
    [-1, 1]), ``exp(log_std)`` is ``std / √d``: the spread is at most ``std`` in any state."""
    log_std = model.policy.log_std
    d = log_std.shape[0] if model.use_sde else 1
    with torch.no_grad():
        log_std.fill_(math.log(std / math.sqrt(d)))


def gradient_steps(utd: float, num_envs: int) -> int:
    """Gradient updates after each vector step of ``num_envs`` worlds for ``utd`` updates per
    environment step (0: one, SB3's default)."""
    return 1 if utd == 0 else max(1, round(utd * num_envs))
