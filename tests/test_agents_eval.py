"""Evaluating a saved policy: a model written by training pours through ``pourbench eval`` with
the actions it takes in memory; files that are not Pour-v0 models are refused in one line."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest
from sb3_contrib import RecurrentPPO
from stable_baselines3 import PPO

from pourbench.agents.evaluate import evaluate, load_sb3_policy
from pourbench.agents.loading import clipped_mean, load_policy, model_policy
from pourbench.agents.sb3 import SB3PourVecEnv
from pourbench.cli import main


@pytest.fixture(scope="module")
def pour_env() -> SB3PourVecEnv:
    return SB3PourVecEnv(1, seed=0, liquid="water")


def _observations(env: SB3PourVecEnv, n: int) -> np.ndarray:
    space = env.observation_space
    space.seed(3)
    return np.stack([space.sample() for _ in range(n)])


def test_a_saved_ppo_model_acts_as_it_did_in_memory(tmp_path, pour_env) -> None:
    model = PPO("MlpPolicy", pour_env, n_steps=16, batch_size=16, seed=1, device="cpu")
    model.learn(16)
    path = tmp_path / "model.zip"
    model.save(path)
    act, in_memory = load_sb3_policy(path), model_policy(model)
    for obs in _observations(pour_env, 8):
        np.testing.assert_array_equal(act(obs, False), in_memory(obs, False))


def test_the_clipped_mean_is_the_mean_of_the_clipped_samples() -> None:
    """E[clip(u, −1, 1)] in closed form against the mean of a million clipped samples, for
    means inside, at and beyond the bounds."""
    import torch

    mean = torch.tensor([0.0, 0.5, 1.0, 1.6, -2.5, 0.3])
    std = torch.tensor([1.0, 0.3, 0.9, 0.9, 1.2, 1e-4])
    samples = torch.normal(mean.expand(1_000_000, -1), std.expand(1_000_000, -1))
    sampled = samples.clamp(-1.0, 1.0).mean(0)
    exact = clipped_mean(mean, std, torch.tensor(-1.0), torch.tensor(1.0))
    np.testing.assert_allclose(exact.numpy(), sampled.numpy(), atol=3e-3)
    assert exact[-1] == pytest.approx(0.3, abs=1e-6)  # no spread: the mean itself


def test_a_ppo_model_acts_with_the_mean_of_its_clipped_action(pour_env) -> None:
    """A PPO policy whose tilt mean lies beyond the bound with a wide spread: SB3's
    deterministic action clips the mean to the bound, the model's policy acts with what its
    samples apply on average, the mean of the clipped action (measured here by sampling)."""
    import torch

    model = PPO("MlpPolicy", pour_env, n_steps=16, batch_size=16, seed=1, device="cpu")
    with torch.no_grad():
        model.policy.action_net.weight.zero_()
        model.policy.action_net.bias.copy_(torch.tensor([0.2, -1.5]))
        model.policy.log_std.fill_(0.0)  # spread 1
    obs = _observations(pour_env, 1)[0]
    assert model.predict(obs, deterministic=True)[0].tolist() == pytest.approx([0.2, -1.0])
    sampled = np.mean([model.predict(obs, deterministic=False)[0] for _ in range(4000)], axis=0)
    acted = model_policy(model)(obs, True)
    np.testing.assert_allclose(acted, sampled, atol=0.03)
    # −Φ(0.5) + 1 − Φ(2.5) − 1.5 (Φ(2.5) − Φ(0.5)) + φ(0.5) − φ(2.5), where SB3 acts with −1
    assert acted[1] == pytest.approx(-0.8042, abs=1e-3)


def test_a_saved_recurrent_model_keeps_its_memory_within_an_episode(tmp_path, pour_env) -> None:
    """An LSTM policy's actions depend on what it saw earlier in the episode; the loaded policy
    carries its state from step to step and clears it when a new episode starts."""
    model = RecurrentPPO("MlpLstmPolicy", pour_env, n_steps=16, batch_size=16, seed=1)
    path = tmp_path / "lstm.zip"
    model.save(path)
    act, in_memory = load_sb3_policy(path), model_policy(model)
    obs = _observations(pour_env, 6)
    expected = [in_memory(o, k == 0) for k, o in enumerate(obs)]
    for _ in range(2):  # the second pass starts a new episode: the same actions again
        got = [act(o, k == 0) for k, o in enumerate(obs)]
        np.testing.assert_allclose(np.array(got), np.array(expected), rtol=0, atol=1e-6)
    fresh = [act(o, True) for o in obs]  # no memory carried: differs from the sequence
    assert not np.allclose(np.array(fresh[1:]), np.array(expected[1:]))


def test_pourbench_eval_pours_with_a_saved_model(tmp_path, pour_env, capsys) -> None:
    """The command's episode is the one the model in memory pours (same seed, same error)."""
    model = PPO("MlpPolicy", pour_env, n_steps=16, batch_size=16, seed=1, device="cpu")
    path = tmp_path / "model.zip"
    model.save(path)
    assert main(["eval", "--policy", str(path), "--episodes", "1", "--target-g", "100"]) == 0
    printed = float(re.search(r"episode 0: error\s+([-\d.]+) g", capsys.readouterr().out)[1])
    in_memory = evaluate(model_policy(model), 1, 100.0, liquid="water")
    assert printed == pytest.approx(in_memory.errors_g[0], abs=0.005)
    assert printed != pytest.approx(evaluate("pd", 1, 100.0, liquid="water").errors_g[0], abs=0.5)


def test_files_that_are_not_pour_models_are_refused(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["eval", "--policy", str(tmp_path / "missing.zip")])
    assert exc.value.code == 2 and "argument --policy:" in capsys.readouterr().err

    text = tmp_path / "notes.zip"
    text.write_text("not a model")
    assert main(["eval", "--policy", str(text), "--episodes", "1"]) == 2
    assert "not a saved Stable-Baselines3 model" in capsys.readouterr().err

    other = PPO("MlpPolicy", gym.make("Pendulum-v1"), n_steps=16, batch_size=16, device="cpu")
    other.save(tmp_path / "pendulum.zip")
    assert main(["eval", "--policy", str(tmp_path / "pendulum.zip"), "--episodes", "1"]) == 2
    assert "observations (3,) and actions (1,)" in capsys.readouterr().err


def _still(obs: np.ndarray, new: bool) -> np.ndarray:
    return np.zeros(2, np.float32)


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda: evaluate(_still, 0), "episodes must be >= 1, got 0"),
        (lambda: evaluate(_still, -1), "episodes must be >= 1, got -1"),
        (lambda: evaluate(_still, 1.5), "episodes must be an integer, got 1.5"),
        (lambda: evaluate(5, 1), "policy must be one of .* or a callable .* got 5"),
        (lambda: evaluate(None, 1), "policy must be one of .* got None"),
        (lambda: evaluate(_still, 1, seed=None), "seed must be an integer, got None"),
        (lambda: evaluate(_still, 1, seed=-1), "seed must be >= 0, got -1"),
        (lambda: evaluate(_still, 1, liquidd="water"), "unknown environment setting 'liquidd'"),
        (lambda: load_policy("random", float("nan")), "seed must be an integer, got nan"),
        (lambda: load_policy("random", -1), "seed must be >= 0"),
    ],
)
def test_bad_evaluation_settings_are_refused_before_any_episode(call, words) -> None:
    with pytest.raises(ValueError, match=words):
        call()


def test_unknown_env_setting_lists_the_valid_ones() -> None:
    with pytest.raises(ValueError, match=r"PourConfig fields: .*max_steps") as exc:
        evaluate(_still, 1, liquidd="water")
    assert "liquid" in str(exc.value).split("fields:")[1]


def test_results_join_episode_by_episode() -> None:
    """Two evaluations joined are their episodes in order; the summary weighs each episode
    alike, so a longer evaluation counts more than a shorter one."""
    from pourbench.agents.evaluate import EvalResult

    a = EvalResult(np.array([2.0, 4.0]), np.zeros(2), np.array([True, True]), np.array([9, 8]))
    b = EvalResult(np.array([30.0]), np.array([1.5]), np.array([False]), np.array([250]))
    both = EvalResult.join(a, b)
    assert both.errors_g.tolist() == [2.0, 4.0, 30.0] and both.steps.tolist() == [9, 8, 250]
    assert both.mean_abs_error_g == pytest.approx(12.0) and both.success_rate == pytest.approx(
        2 / 3
    )


@pytest.mark.parametrize(
    "target, words",
    [
        ("100", "target_g must be a number, got '100'"),
        (True, "target_g must be a number, got True"),
        (0, "target_g must be > 0, got 0"),
        (-5.0, "target_g must be > 0, got -5.0"),
        (float("nan"), "target_g must be finite"),
    ],
)
def test_a_bad_target_is_refused_as_the_env_refuses_it(monkeypatch, target, words) -> None:
    """The env's own check, before any env is built: a string or a bool is not converted."""
    import pourbench.agents.evaluate as evaluate_module
    from pourbench.errors import InvalidParameterError

    def no_env(**kwargs):
        raise AssertionError("an env was built")

    monkeypatch.setattr(evaluate_module, "PourEnv", no_env)
    with pytest.raises(InvalidParameterError, match=re.escape(words)):
        evaluate(_still, 1, target_g=target)
