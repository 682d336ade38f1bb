"""Residual policies over the PD baseline (pourbench.agents.residual): a zero residual pours
exactly as the PD does, in training's vector env and through load_policy, and a saved model
keeps its scale."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pourbench.agents import load_policy
from pourbench.agents.evaluate import evaluate
from pourbench.agents.models import make_model
from pourbench.agents.pd import PDPourer
from pourbench.agents.residual import ATTRIBUTE, ResidualVecEnv, combine, start_residual
from pourbench.agents.sb3 import SB3PourVecEnv
from pourbench.agents.train import TrainArgs

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ENV = {"workers": 1, "liquid": "water", "target_range_g": (50.0, 50.0), "max_steps": 60}


def _rollout(residual: float | None, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Observations and dones of 2 worlds over ``steps`` steps: the PD acting on the plain
    env (``residual`` None), or a zero action on a ResidualVecEnv of that scale."""
    base = SB3PourVecEnv(2, seed=11, **ENV)
    env = base if residual is None else ResidualVecEnv(base, residual)
    pd = PDPourer(2)
    obs, seen, dones = env.reset(), [], []
    for _ in range(steps):
        action = pd.act(obs) if residual is None else np.zeros((2, 2), np.float32)
        obs, _, done, _ = env.step(action)
        pd.reset(done)
        seen.append(obs)
        dones.append(done)
    env.close()
    return np.array(seen), np.array(dones)


def test_a_zero_residual_pours_as_the_pd_across_episode_ends() -> None:
    ref_obs, ref_done = _rollout(None, 75)
    obs, done = _rollout(0.3, 75)
    assert ref_done.any(), "the rollout must cross an episode end (max_steps 60)"
    np.testing.assert_array_equal(done, ref_done)
    np.testing.assert_array_equal(obs, ref_obs)


def test_combine_adds_the_scaled_residual_and_clips() -> None:
    pd = np.array([[0.5, -0.2], [0.95, 1.0]], np.float32)
    res = np.array([[1.0, -3.0], [1.0, 0.5]], np.float32)  # -3 is clipped to -1 first
    np.testing.assert_allclose(
        combine(pd, res, 0.25), [[0.75, -0.45], [1.0, 1.0]], rtol=0, atol=1e-7
    )


def _residual_model(tmp_path, scale: float, bias: tuple[float, float]) -> str:
    env = SB3PourVecEnv(1, seed=0, **ENV)
    model = make_model("recurrent_ppo", ResidualVecEnv(env, scale), n_steps=4, verbose=0)
    start_residual(model, scale)
    with torch.no_grad():
        model.policy.action_net.bias.copy_(torch.tensor(bias))
    path = str(tmp_path / "residual.zip")
    model.save(path)
    env.close()
    return path


def test_a_saved_zero_residual_model_pours_as_the_pd(tmp_path) -> None:
    path = _residual_model(tmp_path, 0.2, (0.0, 0.0))
    kw = {"episodes": 2, "target_g": 50.0, "seed": 3, "liquid": "water", "max_steps": 80}
    model, pd = evaluate(path, **kw), evaluate("pd", **kw)
    np.testing.assert_array_equal(model.errors_g, pd.errors_g)
    np.testing.assert_array_equal(model.steps, pd.steps)


def test_a_loaded_residual_model_adds_its_scaled_action_to_the_pd(tmp_path) -> None:
    """A head whose Gaussian has mean (0.5, -0.5) and spread 1 everywhere: the action is
    PD + 0.2 · the mean of the head's clipped samples (how a saved PPO model acts)."""
    from pourbench.agents.loading import clipped_mean

    act = load_policy(_residual_model(tmp_path, 0.2, (0.5, -0.5)))
    env = SB3PourVecEnv(1, seed=4, **ENV)
    obs = env.reset()
    env.close()
    pd = PDPourer(1)
    head = clipped_mean(torch.tensor([0.5, -0.5]), torch.ones(2), -1.0, 1.0).numpy()
    expected = np.clip(pd.act(obs[0]) + 0.2 * head, -1, 1)
    np.testing.assert_allclose(act(obs[0], True), expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"residual": -0.1}, "residual must be >= 0"),
        ({"residual": 1.5}, r"residual=1.5: .* must be in \(0, 1\]"),
        (
            {"residual": 0.2, "algorithm": "sac", "icm": False, "curriculum": False},
            "residual=0.2 trains PPO or RecurrentPPO",
        ),
        ({"residual": 0.2, "warm_start_steps": 64, "dagger_rounds": 1}, "without DAgger"),
        ({"clone_std": 0.1}, "needs warm_start_steps > 0 or residual > 0"),
        ({"sde": True, "warm_start_steps": 100}, "sde=True with warm_start_steps=100"),
    ],
)
def test_bad_residual_settings_are_refused(kw, match) -> None:
    with pytest.raises(ValueError, match=match):
        TrainArgs(**kw)


@pytest.mark.parametrize("algorithm", ["ppo", "recurrent_ppo"])
def test_a_new_residual_model_acts_zero_with_its_spread_and_keeps_its_scale(
    algorithm, tmp_path
) -> None:
    """start_residual (what train --residual S --clone-std X does to a new model): mean
    action 0 in any state, standard deviation X, scale S saved in the zip."""
    from pourbench.agents.loading import load_model

    assert TrainArgs(residual=0.2, clone_std=0.15).clone_std == 0.15  # no warm start needed
    env = SB3PourVecEnv(1, seed=0, **ENV)
    model = make_model(algorithm, env, n_steps=4, verbose=0)
    start_residual(model, 0.2, 0.15)
    obs = env.reset()
    env.close()
    states = np.stack([obs[0] * f for f in (0.5, 1.0, 2.0)])  # any states, not just one
    kw = {"episode_start": np.ones(3, bool)} if algorithm == "recurrent_ppo" else {}
    action, _ = model.predict(states, deterministic=True, **kw)
    np.testing.assert_array_equal(action, np.zeros((3, 2)))
    np.testing.assert_allclose(model.policy.log_std.exp().detach().numpy(), [0.15, 0.15])
    model.save(tmp_path / "m.zip")
    assert getattr(load_model(tmp_path / "m.zip"), ATTRIBUTE) == 0.2


def test_a_new_gsde_residual_model_acts_zero_and_spreads_at_most_its_std() -> None:
    """With gSDE the spread is ‖features‖ · exp(log_std), features the last hidden layer's
    tanh units: start_residual bounds it by the given std in every state, and the noise
    drawn for a rollout is a function of the state (the same state, the same action)."""
    assert TrainArgs(residual=0.3, sde=True).sde
    env = SB3PourVecEnv(1, seed=0, **ENV)
    model = make_model("ppo", env, n_steps=4, sde=True, verbose=0)
    start_residual(model, 0.3, 0.2)
    obs = env.reset()
    env.close()
    states = np.stack([obs[0] * f for f in (0.5, 1.0, 2.0, 4.0)])
    action, _ = model.predict(states, deterministic=True)
    np.testing.assert_array_equal(action, np.zeros((4, 2)))
    policy = model.policy
    dist = policy.get_distribution(policy.obs_to_tensor(states)[0])
    spread = dist.distribution.stddev.detach().numpy()
    assert np.all(spread > 0.02) and np.all(spread <= 0.2)  # tanh features: ‖·‖ ≤ √d
    policy.reset_noise()
    twice = [model.predict(states[:1])[0] for _ in range(2)]
    np.testing.assert_array_equal(*twice)
    assert np.abs(twice[0]).max() > 0
