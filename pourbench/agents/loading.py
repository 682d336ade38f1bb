"""Pouring policies by name or path: :func:`load_policy` returns ``f(obs, new_episode) ->
action`` for the PD baseline ("pd"), a uniform random policy ("random"), a shipped policy
(``pourbench/agents/policies/<name>.zip`` beside ``<name>.json``, its metadata), or the path
of a model saved by ``pourbench train`` (PPO, RecurrentPPO, SAC, TQC, CrossQ or TD3; the
algorithm is read from the file).

``obs`` is one Pour-v0 observation (12 values), the action two values in [-1, 1];
``new_episode`` is True on an episode's first step. A recurrent policy keeps its LSTM state
from call to call and starts afresh when ``new_episode`` is True. Saved models act
deterministically, each with the mean of what its stochastic policy applies:

* a PPO or RecurrentPPO model with the mean of its Gaussian's action after the action
  bounds' clip (:func:`clipped_mean`);
* a SAC, TQC or CrossQ model (a squashed Gaussian) with the mean of the tilt rate Algorithm 4
  applies and of the approach speed, through its action map, over its Gaussian
  (:func:`applied_mean`), when it records the handler's tolerance (every model
  ``pourbench train`` saves does); with SB3's deterministic action, the squashed mean,
  otherwise and with gSDE;
* a TD3 model (deterministic already) with its action.

A residual model (``pourbench train --residual``) acts on top of its own PD baseline, a
model trained through an action map (``--directed-tilt``, ``--tilt-target``,
``--directed-approach``) through that map.
"""

from __future__ import annotations

import functools
import json
import os
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pourbench.argtypes import BUILTIN_POLICIES, POLICY_DIR, policy_choices, shipped_policies
from pourbench.errors import InvalidParameterError, UnknownNameError, check_int

Policy = Callable[[np.ndarray, bool], np.ndarray]


class UnknownPolicyError(UnknownNameError):
    """A policy name that is neither built in, shipped, nor an existing file; the message
    lists the names that exist (and says when no trained policy ships)."""

    def __init__(self, name: str) -> None:
        super().__init__("policy", name, known_policies())
        self.args = (
            f"unknown policy {name!r}; known: {policy_choices()}, or a saved model's .zip path",
        )

    def __reduce__(self) -> tuple:
        return (type(self), (self.name,))


OFF_POLICY = ("sac", "tqc", "crossq", "td3")
"""The off-policy learners ``pourbench train`` builds (replay buffer, update-to-data ratio)."""
NO_SDE = {"crossq": "CrossQ", "td3": "TD3"}
"""The off-policy learners without gSDE, by their written names."""
ENTROPY_TUNED = ("sac", "tqc", "crossq")
"""The off-policy learners with an entropy coefficient (tuned by SB3 unless ``ent_coef`` fixes
it)."""
QUANTILES = 64
"""The equally likely values of each action dimension's Gaussian that :func:`applied_mean`
averages over (the midpoints of as many equal slices of its probability)."""
LR_SCHEDULES = ("constant", "linear")
"""How a learner's step size moves over its run (``pourbench train --lr-schedule``)."""

# a saved model's policy class module -> its algorithm
_ALGORITHMS = {
    "stable_baselines3.common.policies": "ppo",
    "sb3_contrib.common.recurrent.policies": "recurrent_ppo",
    "stable_baselines3.sac.policies": "sac",
    "sb3_contrib.tqc.policies": "tqc",
    "sb3_contrib.crossq.policies": "crossq",
    "stable_baselines3.td3.policies": "td3",
}


def check_ent_coef(algorithm: str, ent_coef: float) -> None:
    """Raise an :class:`InvalidParameterError` when ``ent_coef`` (> 0: a fixed entropy
    coefficient) is given to a learner without one (not in :data:`ENTROPY_TUNED`)."""
    if ent_coef and algorithm not in ENTROPY_TUNED:
        raise InvalidParameterError(
            f"ent_coef={ent_coef!r} fixes the entropy coefficient of {', '.join(ENTROPY_TUNED)}; "
            f"{algorithm} has none to fix"
        )


def algorithm_of(path: str | Path) -> str:
    """ "ppo", "recurrent_ppo", "sac", "tqc", "crossq" or "td3": the algorithm a saved SB3 model
    file was made by.

    Raises:
        InvalidParameterError: missing file, not a zip, or not one of those.
    """
    p = Path(path)
    if not p.is_file():
        raise InvalidParameterError(
            f"no policy file at {str(p)!r}; policies: {policy_choices()}, or a model.zip"
        )
    try:
        with zipfile.ZipFile(p) as z:
            module = json.loads(z.read("data"))["policy_class"]["__module__"]
    except Exception as exc:
        raise InvalidParameterError(
            f"{str(p)!r} is not a saved Stable-Baselines3 model ({type(exc).__name__}: {exc})"
        ) from None
    if module not in _ALGORITHMS:
        raise InvalidParameterError(
            f"{str(p)!r} holds a {module} policy; PPO, RecurrentPPO, SAC, TQC, CrossQ or TD3 "
            "models are read"
        )
    return _ALGORITHMS[module]


def load_model(path: str | Path, env: Any = None, device: str = "cpu") -> Any:
    """The SB3 model saved at ``path`` (PPO, RecurrentPPO, SAC, TQC, CrossQ or TD3), on ``env``
    if given.

    Raises:
        InvalidParameterError: the file is not such a model, or its spaces are not Pour-v0's
            (12 observations, 2 actions).
    """
    from sb3_contrib import TQC, CrossQ, RecurrentPPO
    from stable_baselines3 import PPO, SAC, TD3

    classes = {
        "ppo": PPO,
        "recurrent_ppo": RecurrentPPO,
        "sac": SAC,
        "tqc": TQC,
        "crossq": CrossQ,
        "td3": TD3,
    }
    cls = classes[algorithm_of(path)]
    try:
        model = cls.load(path, env=env, device=device)
    except Exception as exc:  # any unreadable file is the same bad input
        raise InvalidParameterError(
            f"{str(path)!r} is not a readable {cls.__name__} model ({type(exc).__name__}: {exc})"
        ) from None
    obs_shape = tuple(model.observation_space.shape or ())
    act_shape = tuple(model.action_space.shape or ())
    if obs_shape != (12,) or act_shape != (2,):
        raise InvalidParameterError(
            f"{str(path)!r} was trained on observations {obs_shape} and actions {act_shape}; "
            "Pour-v0 has (12,) and (2,)"
        )
    return model


def clipped_mean(mean: Any, std: Any, low: Any, high: Any) -> Any:
    """E[clip(u, low, high)] for u ~ N(mean, std²), element by element (torch tensors):
    low Φ(a) + high (1 − Φ(b)) + mean (Φ(b) − Φ(a)) + std (φ(a) − φ(b)) with
    a = (low − mean) / std, b = (high − mean) / std."""
    import torch

    unit = torch.distributions.Normal(0.0, 1.0)
    a, b = (low - mean) / std, (high - mean) / std
    cdf_a, cdf_b = unit.cdf(a), unit.cdf(b)
    pdf_a, pdf_b = unit.log_prob(a).exp(), unit.log_prob(b).exp()
    return low * cdf_a + high * (1.0 - cdf_b) + mean * (cdf_b - cdf_a) + std * (pdf_a - pdf_b)


def _expected_action(model: Any) -> Policy:
    """A PPO or RecurrentPPO ``model`` acting with the mean of its clipped action.

    Its Gaussian policy samples u around a mean, and the environment receives clip(u) to the
    action bounds. SB3's deterministic action, clip(mean), is not what the policy does on
    average once the mean lies near or past a bound: a policy trained from scratch under
    Algorithm 4 holds its tilt output's mean beyond the bound, where clip(mean) never tilts
    while its samples pour (docs/training.md). E[clip(u)] is the action the stochastic
    policy applies on average."""
    import torch
    from sb3_contrib import RecurrentPPO

    policy = model.policy
    low = torch.as_tensor(model.action_space.low, dtype=torch.float32)
    high = torch.as_tensor(model.action_space.high, dtype=torch.float32)
    recurrent = isinstance(model, RecurrentPPO)
    state: list[Any] = [None]

    def act(obs: np.ndarray, new: bool) -> np.ndarray:
        tensor, _ = policy.obs_to_tensor(obs)
        with torch.no_grad():
            if recurrent:
                if new or state[0] is None:
                    zeros = torch.zeros(policy.lstm_hidden_state_shape)
                    state[0] = (zeros, zeros.clone())
                starts = torch.tensor([float(new)])
                dist, state[0] = policy.get_distribution(tensor, state[0], starts)
            else:
                dist = policy.get_distribution(tensor)
            normal = dist.distribution
            action = clipped_mean(normal.mean, normal.stddev, low, high)
        return action.numpy().reshape(model.action_space.shape)

    return act


def applied_mean(
    mean: np.ndarray,
    std: np.ndarray,
    obs: np.ndarray,
    action_map: Any,
    tolerance_g: float,
) -> np.ndarray:
    """The mean of what Pour-v0 applies for a squashed Gaussian policy's action in the
    observed state ``obs`` (12 values): the action is tanh(x), x ~ N(``mean``, ``std``²) per
    dimension (2 values each), mapped through ``action_map`` (a
    :class:`~pourbench.agents.directed.ActionMap`) and its tilt rate cut to the direction
    Algorithm 4 allows at ``tolerance_g``. Both act on each dimension alone, so the mean is
    taken over each Gaussian on its own, as the average over :data:`QUANTILES` equally likely
    values (the quantiles at the midpoints of equal slices of probability), a rule that stays
    accurate over the kinks where the handler cuts the rate and the maps clip it, unlike a
    Gauss–Hermite rule (docs/training.md, "The tilt as a target").

    The squashed mean tanh(``mean``) is not what such a policy does on average: under
    Algorithm 4 a SAC policy trained from scratch holds its tilt mean where the handler
    applies nothing and pours through the spread around it (docs/training.md, "The tilt as a
    target"). The returned action lies in the allowed direction, so the handler applies it
    as it is."""
    from pourbench.agents import directed
    from pourbench.envs.action_handler import allowed_rates

    z = _unit_quantiles()
    squashed = np.tanh(np.asarray(mean, float) + np.asarray(std, float) * z[:, None])
    mapped = directed.direct(squashed, np.broadcast_to(obs, (QUANTILES, len(obs))), *action_map)
    mapped = mapped.astype(float)
    mapped[:, 0] = allowed_rates(mapped[:, 0], obs[directed.REMAINING] > tolerance_g)
    return mapped.mean(axis=0).astype(np.float32)


@functools.cache
def _unit_quantiles() -> np.ndarray:
    """The standard normal's quantiles at the midpoints of :data:`QUANTILES` equal slices of
    probability."""
    from scipy.special import ndtri

    return ndtri((np.arange(QUANTILES) + 0.5) / QUANTILES)


def _applied_mean_policy(model: Any, action_map: Any, tolerance_g: float) -> Policy:
    """A SAC, TQC or CrossQ ``model`` acting with :func:`applied_mean` of its actor's
    Gaussian, its map included."""
    import torch

    actor = model.policy.actor

    def act(obs: np.ndarray, new: bool) -> np.ndarray:
        tensor, _ = model.policy.obs_to_tensor(obs)
        with torch.no_grad():
            mean, log_std, _ = actor.get_action_dist_params(tensor)
        return applied_mean(mean.numpy()[0], log_std.exp().numpy()[0], obs, action_map, tolerance_g)

    return act


def model_policy(model: Any) -> Policy:
    """An SB3 model in memory as ``f(obs, new_episode)`` acting deterministically (the
    module docstring); a recurrent model's state is kept between calls and cleared when
    ``new_episode``; a residual model (:mod:`pourbench.agents.residual`) acts on top of its
    PD baseline, and a directed-tilt model (:mod:`pourbench.agents.directed`) through its
    map."""
    from sb3_contrib import TQC, CrossQ, RecurrentPPO
    from stable_baselines3 import PPO, SAC

    from pourbench.agents import directed, residual

    scale = getattr(model, residual.ATTRIBUTE, 0.0)
    action_map = directed.model_map(model)
    tolerance_g = getattr(model, directed.HANDLER_ATTRIBUTE, None)
    squashed = isinstance(model, SAC | TQC | CrossQ) and not model.use_sde
    if squashed and tolerance_g is not None and not scale:
        return _applied_mean_policy(model, action_map, tolerance_g)

    act: Policy
    if isinstance(model, PPO | RecurrentPPO):
        act = _expected_action(model)
    else:
        act = lambda obs, new: model.predict(obs, deterministic=True)[0]  # noqa: E731
    if scale:
        return residual.residual_policy(act, scale)
    if action_map.identity:
        return act
    return directed.directed_policy(act, action_map)


def load_sb3_policy(path: str | Path) -> Policy:
    """A saved model (``.zip``) as a policy (see :func:`load_model` for what is refused)."""
    return model_policy(load_model(path))


def known_policies() -> list[str]:
    """Names :func:`load_policy` takes: the built-in ones, then the shipped ones."""
    return [*BUILTIN_POLICIES, *shipped_policies()]


def policy_metadata(name: str) -> dict[str, Any]:
    """A shipped policy's metadata (command, steps, seed, wall time, git SHA, machine).

    Raises:
        UnknownPolicyError: no such shipped policy (the message lists those that exist).
    """
    if name not in shipped_policies():
        raise UnknownPolicyError(name)
    return json.loads((POLICY_DIR / f"{name}.json").read_text())


def load_policy(name_or_path: str | os.PathLike[str], seed: int = 0) -> Policy:
    """A pouring policy ``f(obs, new_episode) -> action`` (see the module docstring).

    Args:
        name_or_path: "pd", "random", a shipped policy's name, or a saved model's path.
        seed: seed of "random" (an integer >= 0).

    Raises:
        InvalidParameterError: not a string or path, a bad seed, or a file that is not a
            Pour-v0 model.
        UnknownPolicyError: a name that is neither built in, shipped, nor an existing file
            (an :class:`~pourbench.errors.UnknownNameError`); the message lists the names
            that exist.
    """
    name = os.fspath(name_or_path) if isinstance(name_or_path, os.PathLike) else name_or_path
    if not isinstance(name, str):
        raise InvalidParameterError(
            f"policy must be one of {known_policies()}, a saved model's path or a callable "
            f"f(obs, new_episode), got {name_or_path!r}"
        )
    seed = check_int("seed", seed, minimum=0)
    if name == "pd":
        from pourbench.agents.pd import PDConfig, PDPourer

        pd = PDPourer(1, PDConfig())

        def act(obs: np.ndarray, new: bool) -> np.ndarray:
            if new:
                pd.reset()
            return pd.act(obs)

        return act
    if name == "random":
        rng = np.random.default_rng(seed)
        return lambda obs, new: rng.uniform(-1.0, 1.0, 2).astype(np.float32)
    if name in shipped_policies():
        return load_sb3_policy(POLICY_DIR / f"{name}.zip")
    if name.endswith(".zip") or Path(name).is_file():
        return load_sb3_policy(name)
    raise UnknownPolicyError(name)
