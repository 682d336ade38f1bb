"""Warm start from the PD baseline: behaviour cloning before reinforcement learning.

The thesis trains PourNet from scratch on Algorithm 5's sparse reward, which a CPU budget of a
few hours may not reach. ``pourbench train --warm-start-steps N`` first rolls the PD baseline
(:mod:`pourbench.agents.pd`) in the training's own vector env for ``N`` environment steps
(:func:`demonstrate`), then fits the new model to them (:func:`clone`): the mean action to
the PD's and the value network to the discounted returns, so that PPO's first advantages are
not those of an untrained critic, and the spread to what the fit leaves, so that PPO explores
around the cloned actions rather than with the untrained network's unit deviation (gradient
steps alone move a log deviation by about the learning rate per step). Training then goes on
as without it.

Written by hand: the ``imitation`` library's behaviour cloning covers SB3's feed-forward
policies but not sb3-contrib's recurrent ones. Here both go through the policy's own
feature extractor, LSTMs and heads (the steps of its ``evaluate_actions``, without the
distribution); the LSTM runs over each demonstrated episode from a zero state, as it does
when it acts, a few episodes to a gradient step.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

from pourbench.errors import check_int

EPISODES_PER_BATCH = 4
"""Episodes in one gradient step of a recurrent policy's fit (why: `docs/training.md`)."""


@dataclass(frozen=True)
class Demonstrations:
    """The PD baseline's rollout in a vector env of ``n`` worlds over ``T`` steps."""

    obs: np.ndarray  # (T, n, 12) float32, what the PD saw
    actions: np.ndarray  # (T, n, 2) float32, what it did
    starts: np.ndarray  # (T, n) bool, obs[t, k] is its episode's first
    returns: np.ndarray  # (T, n) discounted reward from step t to its episode's end
    complete: np.ndarray  # (T, n) bool, step t's episode ended within the rollout
    # pouring error of each episode that ended without a collision or a diverged simulation
    # (at the step limit too), g
    errors_g: np.ndarray

    @property
    def mean_abs_error_g(self) -> float:
        """The PD's mean pouring error over the episodes of ``errors_g``, g (NaN if none)."""
        return float(np.mean(self.errors_g)) if len(self.errors_g) else float("nan")


def demonstrate(
    env: Any, steps: int, gamma: float, progress: bool = False, learner: Any = None
) -> Demonstrations:
    """Reset the SB3 VecEnv ``env`` (a :class:`~pourbench.agents.sb3.SB3PourVecEnv`) and run
    ``steps`` vector steps labelled with the PD baseline's actions; ``gamma`` discounts the
    returns; ``progress`` shows a progress bar.

    Without ``learner`` the PD acts. With ``learner`` (an SB3 model) the learner's
    deterministic action is taken and the PD, fed the same observations, only labels them:
    a DAgger round (Ross et al. 2011), which shows the PD the states the clone drifts into.
    ``errors_g`` are then the learner's."""
    from tqdm import tqdm

    from pourbench.agents.pd import PDPourer

    steps = check_int("steps", steps, minimum=1)
    n = env.num_envs
    pd = PDPourer(n)
    obs_all = np.zeros((steps, n, 12), np.float32)
    act_all = np.zeros((steps, n, 2), np.float32)
    rew = np.zeros((steps, n))
    done = np.zeros((steps, n), bool)
    starts = np.zeros((steps, n), bool)
    errors: list[float] = []
    obs = env.reset()
    starts[0] = True
    state = None
    desc = "PD demonstrations" if learner is None else "DAgger: the clone acts, the PD labels"
    for t in tqdm(range(steps), desc=desc, unit="step", disable=not progress):
        a = pd.act(obs)
        obs_all[t], act_all[t] = obs, a
        if learner is not None:
            a, state = learner.predict(
                obs, state=state, episode_start=starts[t], deterministic=True
            )
        obs, rew[t], done[t], infos = env.step(a)
        for k in np.flatnonzero(done[t]):
            if not infos[k]["sim_diverged"] and not infos[k]["collided"]:
                errors.append(float(infos[k]["error_g"]))
        pd.reset(done[t])
        if t + 1 < steps:
            starts[t + 1] = done[t]
    returns = np.zeros((steps, n))
    complete = np.zeros((steps, n), bool)
    after, ended = np.zeros(n), np.zeros(n, bool)
    for t in range(steps - 1, -1, -1):
        after = rew[t] + gamma * np.where(done[t], 0.0, after)
        ended = done[t] | ended
        returns[t], complete[t] = after, ended
    return Demonstrations(obs_all, act_all, starts, returns, complete, np.array(errors))


def join(*demos: Demonstrations) -> Demonstrations:
    """Demonstrations of the same length side by side, as if from one env of all their
    worlds (DAgger's aggregate)."""
    cat = lambda name: np.concatenate([getattr(d, name) for d in demos], axis=1)  # noqa: E731
    return Demonstrations(
        *(cat(f) for f in ("obs", "actions", "starts", "returns", "complete")),
        np.concatenate([d.errors_g for d in demos]),
    )


def clone(
    model: Any,
    demos: Demonstrations,
    epochs: int,
    lr: float = 1e-3,
    seed: int = 0,
    std: float | None = None,
    progress: bool = False,
) -> dict[str, float]:
    """Fit ``model``'s policy (PPO or RecurrentPPO) to ``demos`` for ``epochs`` passes: the
    mean action's squared distance to the PD's plus half the value network's squared error
    on the returns of the episodes that ended; then set the policy's standard deviation to
    the mean's root-mean-square residual per action dimension, at least 0.1, or to
    ``std`` when given. Returns the last epoch's mean action error (the squared distance,
    summed over the action, of the mean clipped to the action bounds), its value error and
    the standard deviation set (``std``, the mean over the action's dimensions).
    ``progress`` shows a progress bar over the epochs."""
    import torch
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
    from sb3_contrib.common.recurrent.type_aliases import RNNStates
    from tqdm import tqdm

    epochs = check_int("epochs", epochs, minimum=1)
    policy = model.policy
    policy.set_training_mode(True)
    optimiser = torch.optim.Adam(policy.parameters(), lr=lr)
    rng = np.random.default_rng(seed)
    recurrent = isinstance(policy, RecurrentActorCriticPolicy)
    T, n = demos.starts.shape

    if recurrent:
        # each episode is its own sequence from a zero state, as the policy meets it (a
        # rollout's first step starts one); EPISODES_PER_BATCH of them, padded, a step
        segments = [
            (k, a, b)
            for k in range(n)
            for a, b in itertools.pairwise([*np.flatnonzero(demos.starts[:, k]), T])
        ]
        units = len(segments)
        size = EPISODES_PER_BATCH
    else:
        units = T * n
        size = min(256, units)

    stats: dict[str, float] = {}
    residual, count = torch.zeros(demos.actions.shape[-1], dtype=torch.float64), 0
    bar = tqdm(range(epochs), desc="cloning the PD", unit="epoch", disable=not progress)
    for _ in bar:
        perm = rng.permutation(units)
        order = [perm[i : i + size] for i in range(0, units, size)]
        sums = np.zeros(2)
        residual.zero_()
        count = 0
        for idx in order:
            if recurrent:
                items = [segments[i] for i in idx]
                obs, act, ret, done, valid, start = episode_batch(demos, items)
                mask = done * valid
                shape = (policy.lstm_actor.num_layers, len(items), policy.lstm_actor.hidden_size)
                zero = (torch.zeros(shape), torch.zeros(shape))
                mean, values = _mean_and_value(policy, obs, RNNStates(zero, zero), start)
                keep = valid > 0
                mean, act, values, ret, mask = (
                    t[keep] for t in (mean, act, values.flatten(), ret, mask)
                )
            else:
                flat = [a.reshape(-1, *a.shape[2:])[idx] for a in (demos.obs, demos.actions)]
                obs, act = (torch.as_tensor(a, dtype=torch.float32) for a in flat)
                ret = torch.as_tensor(demos.returns.reshape(-1)[idx], dtype=torch.float32)
                mask = torch.as_tensor(demos.complete.reshape(-1)[idx], dtype=torch.float32)
                mean, values = _mean_and_value(policy, obs)
            err = ((values.flatten() - ret) ** 2 * mask).sum() / mask.sum().clamp(min=1.0)
            fit = ((mean - act) ** 2).sum(1).mean()
            loss = fit + 0.5 * err
            optimiser.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
            optimiser.step()
            with torch.no_grad():
                residual += ((mean - act) ** 2).sum(0).double()
                count += len(act)
                mse = float(((mean.clamp(-1.0, 1.0) - act) ** 2).sum(1).mean())
            sums += (mse, float(err.detach()))
        stats = dict(zip(("action_mse", "value_mse"), sums / len(order), strict=True))
        bar.set_postfix(stats)
    # the last epoch's residual, per action dimension: the Gaussian's maximum-likelihood spread
    std_set = (residual / max(count, 1)).sqrt().clamp(min=0.1)
    if std is not None:
        std_set = torch.full_like(std_set, std)
    with torch.no_grad():
        policy.log_std.copy_(std_set.log().to(policy.log_std.dtype))
    policy.set_training_mode(False)
    return {**stats, "std": float(std_set.mean())}


def episode_batch(demos: Demonstrations, items: list[tuple[int, int, int]]) -> tuple:
    """The episodes ``items`` (world, first step, end step) of ``demos`` one after another,
    each padded with zeros to the longest (sb3-contrib's sequence layout), as float tensors:
    observations, actions, returns, completeness, validity (0 on padding) and episode
    starts (1 at each episode's first step)."""
    import torch

    length = max(b - a for _, a, b in items)

    def padded(src: np.ndarray) -> torch.Tensor:
        out = np.zeros((len(items), length, *src.shape[2:]), np.float32)
        for row, (k, a, b) in enumerate(items):
            out[row, : b - a] = src[a:b, k]
        return torch.as_tensor(out.reshape(len(items) * length, *src.shape[2:]))

    valid = (np.arange(length) < np.array([[b - a] for _, a, b in items])).astype(np.float32)
    start = np.zeros((len(items), length), np.float32)
    start[:, 0] = 1.0
    fields = (demos.obs, demos.actions, demos.returns, demos.complete)
    flat = (torch.as_tensor(a.reshape(-1)) for a in (valid, start))
    return (*(padded(f) for f in fields), *flat)


def _mean_and_value(policy: Any, obs: Any, states: Any = None, starts: Any = None) -> tuple:
    """The policy's mean action and its value for ``obs`` (a recurrent policy: over its
    sequences from ``states``, reset at ``starts``), both differentiable."""
    features = policy.extract_features(obs)
    if states is None:
        latent_pi, latent_vf = policy.mlp_extractor(features)
    else:
        latent_pi, _ = policy._process_sequence(features, states.pi, starts, policy.lstm_actor)
        if policy.lstm_critic is not None:
            latent_vf, _ = policy._process_sequence(features, states.vf, starts, policy.lstm_critic)
        elif policy.shared_lstm:
            latent_vf = latent_pi.detach()
        else:
            latent_vf = policy.critic(features)
        latent_pi = policy.mlp_extractor.forward_actor(latent_pi)
        latent_vf = policy.mlp_extractor.forward_critic(latent_vf)
    return policy.action_net(latent_pi), policy.value_net(latent_vf)
