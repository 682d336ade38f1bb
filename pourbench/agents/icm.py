"""Intrinsic Curiosity Module (Pathak et al. 2017; thesis §6.5.5) as an SB3 VecEnv wrapper.

Written by hand: no maintained Stable-Baselines3-compatible ICM exists (SB3 and sb3-contrib
have none; the thesis used Unity ML-Agents' built-in curiosity signal).

The module has three networks:

* a feature encoder ``φ(s)`` (observations normalised first by a running mean and variance,
  updated with every step's observations before its bonus is computed),
* an inverse model predicting the action from ``(φ(s), φ(s′))`` (continuous actions:
  squared error),
* a forward model predicting ``φ̂(s′)`` from ``(φ(s), a)``.

The intrinsic reward of a transition is ``η/2 · ‖φ̂(s′) − φ(s′)‖²``. The loss is
``(1 − β)·L_inverse + β·L_forward``; the forward loss takes ``φ(s′)`` as a fixed target, so
the encoder learns only from the inverse model (features of what the agent can influence).

:class:`ICMVecEnv` adds that reward to the environment's reward in ``step_wait``, so an
on-policy algorithm (PPO, RecurrentPPO) stores extrinsic + intrinsic reward in its rollout
buffer and computes returns and advantages from the sum: the bonus enters *before* GAE
(adding it in ``on_rollout_end`` would be too late). The same transitions train the ICM:
every ``update_every`` calls of ``step_wait`` (a rollout of ``n_steps`` when it equals the
algorithm's ``n_steps``) it makes ``epochs`` passes over them in minibatches.

The thesis gives no ICM hyper-parameters; the defaults are ML-Agents' curiosity settings
(strength η = 0.02, learning rate 3e-4, its 0.2 forward / 0.8 inverse loss weighting, which
is Pathak's β = 0.2) with an encoding of 64 features for the 12 observations and hidden
layers of 256 units as in the thesis' policy.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from torch import nn

from pourbench.errors import InvalidParameterError, check_finite, check_int, check_positive


@dataclass(frozen=True)
class ICMConfig:
    """ICM hyper-parameters.

    Attributes:
        eta: scale η of the intrinsic reward η/2·‖φ̂(s′) − φ(s′)‖² (reward units per
            squared feature unit).
        beta: weight β of the forward loss; the inverse loss gets 1 − β.
        feature_dim: size of the feature vector φ(s).
        hidden: units of each hidden layer (one per network).
        lr: Adam learning rate.
        epochs: passes over the stored transitions at each update.
        batch_size: transitions per gradient step.
        update_every: ``step_wait`` calls between updates (set it to the algorithm's
            ``n_steps``); 0 freezes the ICM: it rewards but neither trains nor updates its
            observation statistics.
    """

    eta: float = 0.02
    beta: float = 0.2
    feature_dim: int = 64
    hidden: int = 256
    lr: float = 3e-4
    epochs: int = 3
    batch_size: int = 256
    update_every: int = 64

    def __post_init__(self) -> None:
        check_finite("eta", self.eta, minimum=0.0)
        if not 0.0 <= check_finite("beta", self.beta) <= 1.0:
            raise InvalidParameterError(f"beta must be in [0, 1], got {self.beta!r}")
        check_positive("lr", self.lr)
        for name in ("feature_dim", "hidden", "epochs", "batch_size"):
            check_int(name, getattr(self, name), minimum=1)
        check_int("update_every", self.update_every, minimum=0)


class ICM(nn.Module):
    """Feature encoder, inverse and forward models for ``obs_dim`` observations and
    ``act_dim`` continuous actions."""

    def __init__(self, obs_dim: int, act_dim: int, config: ICMConfig | None = None) -> None:
        super().__init__()
        cfg = self.config = config or ICMConfig()
        h, f = cfg.hidden, cfg.feature_dim
        self.encoder = nn.Sequential(nn.Linear(obs_dim, h), nn.ReLU(), nn.Linear(h, f))
        self.inverse = nn.Sequential(nn.Linear(2 * f, h), nn.ReLU(), nn.Linear(h, act_dim))
        self.forward_model = nn.Sequential(nn.Linear(f + act_dim, h), nn.ReLU(), nn.Linear(h, f))
        # running observation statistics (saved with the weights)
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_var", torch.ones(obs_dim))
        self.register_buffer("obs_count", torch.tensor(1e-4))

    def update_normaliser(self, obs: torch.Tensor) -> None:
        """Fold a batch of observations into the running mean and variance (Chan et al.)."""
        m, v, n = obs.mean(0), obs.var(0, unbiased=False), obs.shape[0]
        delta, total = m - self.obs_mean, self.obs_count + n
        self.obs_mean += delta * n / total
        self.obs_var.copy_(
            (self.obs_var * self.obs_count + v * n + delta**2 * self.obs_count * n / total) / total
        )
        self.obs_count += n

    def features(self, obs: torch.Tensor) -> torch.Tensor:
        """φ(s) of a batch of observations."""
        z = ((obs - self.obs_mean) / torch.sqrt(self.obs_var + 1e-8)).clamp(-10.0, 10.0)
        return self.encoder(z)

    def losses(
        self, obs: torch.Tensor, actions: torch.Tensor, next_obs: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Mean inverse loss, mean forward loss, and each transition's intrinsic reward
        (detached; η/2·‖φ̂(s′) − φ(s′)‖²)."""
        phi, phi_next = self.features(obs), self.features(next_obs)
        pred_action = self.inverse(torch.cat([phi, phi_next], 1))
        inverse = ((pred_action - actions) ** 2).sum(1).mean()
        pred_next = self.forward_model(torch.cat([phi, actions], 1))
        sq = 0.5 * ((pred_next - phi_next.detach()) ** 2).sum(1)
        return inverse, sq.mean(), self.config.eta * sq.detach()

    @torch.no_grad()
    def intrinsic_reward(
        self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray
    ) -> np.ndarray:
        """(n,) float32 intrinsic reward of n transitions."""
        return self.losses(*_tensors(obs, actions, next_obs))[2].numpy().astype(np.float32)


def _tensors(*arrays: np.ndarray) -> tuple[torch.Tensor, ...]:
    return tuple(torch.as_tensor(np.asarray(a, np.float32)) for a in arrays)


class ICMTrainer:
    """An :class:`ICM` and its Adam optimiser; :meth:`update` trains on transitions."""

    def __init__(self, obs_dim: int, act_dim: int, config: ICMConfig | None = None) -> None:
        self.icm = ICM(obs_dim, act_dim, config)
        self.config = self.icm.config
        self.optimizer = torch.optim.Adam(self.icm.parameters(), lr=self.config.lr)

    def update(
        self,
        obs: np.ndarray,
        actions: np.ndarray,
        next_obs: np.ndarray,
        rng: np.random.Generator,
        normalise: bool = True,
    ) -> dict[str, float]:
        """``epochs`` passes over the transitions in shuffled minibatches (first folding
        their observations into the normaliser when ``normalise``); the mean inverse and
        forward losses of the passes."""
        o, a, o2 = _tensors(obs, actions, next_obs)
        if normalise:
            self.icm.update_normaliser(torch.cat([o, o2]))
        cfg, n = self.config, len(o)
        inv_sum = fwd_sum = 0.0
        steps = 0
        for _ in range(cfg.epochs):
            order = torch.as_tensor(rng.permutation(n))
            for start in range(0, n, cfg.batch_size):
                idx = order[start : start + cfg.batch_size]
                inverse, forward, _ = self.icm.losses(o[idx], a[idx], o2[idx])
                loss = (1.0 - cfg.beta) * inverse + cfg.beta * forward
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
                inv_sum += inverse.item()
                fwd_sum += forward.item()
                steps += 1
        return {"inverse_loss": inv_sum / steps, "forward_loss": fwd_sum / steps}

    def state_dict(self) -> dict[str, Any]:
        return {
            "config": asdict(self.config),
            "icm": self.icm.state_dict(),
            "optimizer": self.optimizer.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.icm.load_state_dict(state["icm"])
        self.optimizer.load_state_dict(state["optimizer"])


class ICMVecEnv(VecEnvWrapper):
    """A VecEnv whose rewards carry the ICM's intrinsic reward (see the module docstring).

    ``infos[k]["intrinsic_reward"]`` holds world k's bonus of the step. For a world whose
    episode ended, the transition's next observation is ``infos[k]["terminal_observation"]``
    (SB3's convention), not the first observation of the next episode it returns.

    Attributes:
        trainer: the ICM and its optimiser.
        stats: after each update, ``inverse_loss``, ``forward_loss`` (of the update) and
            ``intrinsic_reward`` (mean bonus per step since the previous update).
    """

    def __init__(self, venv: VecEnv, config: ICMConfig | None = None, seed: int = 0) -> None:
        super().__init__(venv)
        obs_shape = venv.observation_space.shape or ()
        act_shape = venv.action_space.shape or ()
        if len(obs_shape) != 1 or len(act_shape) != 1:
            raise InvalidParameterError(
                f"ICMVecEnv needs flat Box observations and actions, got {obs_shape} and "
                f"{act_shape}"
            )
        self.trainer = ICMTrainer(obs_shape[0], act_shape[0], config)
        self.stats: dict[str, float] = {}
        self._rng = np.random.default_rng(seed)
        self._obs: np.ndarray | None = None
        self._actions: np.ndarray | None = None
        self._buffer: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._bonus_sum, self._bonus_count, self._calls = 0.0, 0, 0

    def reset(self) -> np.ndarray:
        self._obs = np.asarray(self.venv.reset(), np.float32)
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        low, high = self.action_space.low, self.action_space.high
        self._actions = np.clip(np.asarray(actions, np.float32), low, high)
        self.venv.step_async(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        obs, rew, done, infos = self.venv.step_wait()
        if self._obs is None or self._actions is None:
            raise InvalidParameterError("ICMVecEnv.step_wait() before reset() and step_async()")
        next_obs = np.array(obs, np.float32, copy=True)
        for k in np.flatnonzero(done):
            next_obs[k] = infos[k]["terminal_observation"]
        every = self.trainer.config.update_every
        if every:  # the bonus of the very first steps already sees normalised observations
            self.trainer.icm.update_normaliser(torch.as_tensor(next_obs))
        bonus = self.trainer.icm.intrinsic_reward(self._obs, self._actions, next_obs)
        for k, info in enumerate(infos):
            info["intrinsic_reward"] = float(bonus[k])
        self._buffer.append((self._obs, self._actions, next_obs))
        self._bonus_sum += float(bonus.sum())
        self._bonus_count += len(bonus)
        self._obs, self._actions = np.asarray(obs, np.float32), None
        self._calls += 1
        if every and self._calls % every == 0:
            self.update()
        return obs, (np.asarray(rew, np.float32) + bonus), done, infos

    def update(self) -> dict[str, float]:
        """Train the ICM on the stored transitions and clear them; the new :attr:`stats`."""
        if not self._buffer:
            return self.stats
        o, a, o2 = (np.concatenate(parts) for parts in zip(*self._buffer, strict=True))
        self._buffer.clear()
        self.stats = {
            **self.trainer.update(o, a, o2, self._rng, normalise=False),
            "intrinsic_reward": self._bonus_sum / max(self._bonus_count, 1),
        }
        self._bonus_sum, self._bonus_count = 0.0, 0
        return self.stats

    def save(self, path: str | Path) -> None:
        """The ICM's weights, normaliser and optimiser to ``path`` (``torch.save``)."""
        torch.save(self.trainer.state_dict(), path)

    def load(self, path: str | Path) -> None:
        """Weights, normaliser and optimiser saved by :meth:`save`.

        Raises:
            InvalidParameterError: the file does not hold an ICM of this size and config.
        """
        try:
            state = torch.load(path, weights_only=True)
            if state["config"] != asdict(self.trainer.config):
                raise ValueError(f"saved with {state['config']}, not {asdict(self.trainer.config)}")
            self.trainer.load_state_dict(state)
        except Exception as exc:
            raise InvalidParameterError(
                f"{str(path)!r} is not this run's ICM state ({type(exc).__name__}: {exc})"
            ) from exc
