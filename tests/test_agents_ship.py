"""Shipping a finished training run as a named policy: the same actions, a smaller file
(no optimiser moments, for PPO and for SAC), and the metadata the training issue asks
for."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pourbench.errors import InvalidParameterError


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """A RecurrentPPO run after one update (so its optimiser holds moments), with the
    state.json and result.json a finished ``pourbench train`` leaves, and the model before
    the update kept as its best-evaluated one."""
    from pourbench.agents.models import make_model
    from pourbench.agents.sb3 import SB3PourVecEnv

    run = tmp_path_factory.mktemp("run")
    env = SB3PourVecEnv(1, seed=0, workers=1, liquid="water")
    try:
        model = make_model("recurrent_ppo", env, n_steps=8, batch_size=8, verbose=0)
        model.save(run / "best_model.zip")
        model.learn(8)
        model.save(run / "model.zip")
    finally:
        env.close()
    session = {"command": "pourbench train --x", "git_sha": "abc1234", "machine": "m",
               "date": "2026-12-02 08:00 UTC", "timesteps": 8, "session_s": 3.0}  # fmt: skip
    state = {
        "args": {"algorithm": "recurrent_ppo", "policy": "lstm", "seed": 0},
        "timesteps": 8,
        "train_s": 3.0,
        "sessions": 1,
        "history": [session],
        "warm_start": {"steps": 64, "std": 0.2},
    }
    (run / "state.json").write_text(json.dumps(state))
    result = {
        "mean_abs_error_g": 7.5,
        "policy": "mean abs error 7.5 g",
        "random_mean_abs_error_g": 99.0,
        "best": {"timesteps": 0, "eval_mean_abs_error_g": 6.5, "eval_success_rate": 0.8},
    }
    (run / "result.json").write_text(json.dumps(result))
    return run, model


def test_a_shipped_policy_acts_as_the_run_and_says_where_it_came_from(finished_run, tmp_path):
    from pourbench.agents.loading import load_sb3_policy, model_policy
    from pourbench.agents.ship import ship

    run, model = finished_run
    meta_path = ship(run, "pournet-test", policy_dir=tmp_path, last=True)
    shipped = tmp_path / "pournet-test.zip"
    assert shipped.stat().st_size < 0.6 * (run / "model.zip").stat().st_size
    meta = json.loads(meta_path.read_text())
    assert meta["commands"] == ["pourbench train --x"] and meta["git_sha"] == ["abc1234"]
    assert (meta["steps"], meta["seed"], meta["wall_time_s"]) == (8, 0, 3.0)
    assert meta["machine"] == ["m"] and meta["warm_start"]["steps"] == 64
    assert meta["final_evaluation"]["mean_abs_error_g"] == 7.5
    assert meta["checkpoint"] == {"file": "model.zip", "timesteps": 8}
    original, copy = model_policy(model), load_sb3_policy(shipped)
    rng = np.random.default_rng(0)
    for t in range(5):  # a sequence, so the LSTM's state carries over as it does in a pour
        obs = rng.uniform(0.0, 100.0, 12).astype(np.float32)
        assert np.array_equal(original(obs, t == 0), copy(obs, t == 0))


def test_the_best_evaluated_model_ships_by_default(finished_run, tmp_path) -> None:
    from pourbench.agents.loading import load_model, load_sb3_policy, model_policy
    from pourbench.agents.ship import ship

    run, model = finished_run
    meta_path = ship(run, "pournet-test", policy_dir=tmp_path)
    meta = json.loads(meta_path.read_text())
    assert meta["checkpoint"]["file"] == "best_model.zip"
    assert meta["checkpoint"]["eval_mean_abs_error_g"] == 6.5
    best, last = model_policy(load_model(run / "best_model.zip")), model_policy(model)
    shipped = load_sb3_policy(tmp_path / "pournet-test.zip")
    obs = np.random.default_rng(1).uniform(0.0, 100.0, 12).astype(np.float32)
    assert np.array_equal(shipped(obs, True), best(obs, True))
    assert not np.array_equal(shipped(obs, True), last(obs, True))


@pytest.mark.parametrize("name", ["PourNet", "a b", "", "-x", None])
def test_a_bad_name_is_refused(finished_run, tmp_path, name) -> None:
    from pourbench.agents.ship import ship

    with pytest.raises(InvalidParameterError, match="lowercase letters, digits and dashes"):
        ship(finished_run[0], name, policy_dir=tmp_path)  # type: ignore[arg-type]
    assert not list(tmp_path.iterdir())


def test_an_unfinished_run_is_refused(tmp_path) -> None:
    from pourbench.agents.ship import ship

    (tmp_path / "model.zip").write_bytes(b"")
    with pytest.raises(InvalidParameterError, match="not a finished training run: no state"):
        ship(tmp_path, "pournet-lstm", policy_dir=tmp_path / "out")


@pytest.mark.parametrize("name", ["pd", "random"])
def test_a_builtin_policy_name_is_refused(finished_run, tmp_path, name) -> None:
    """``load_policy("pd")`` is the built-in PD, so a model shipped as "pd" could never load."""
    from pourbench.agents.ship import ship

    with pytest.raises(InvalidParameterError, match=f"'{name}' is a built-in policy"):
        ship(finished_run[0], name, policy_dir=tmp_path)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "file, content, words",
    [
        ("result.json", {"mean_abs_error_g": 1, "random_mean_abs_error_g": 2}, "has no policy"),
        ("result.json", "{", "is unreadable (JSONDecodeError"),
        ("result.json", b"\xff", "is unreadable (UnicodeDecodeError"),
        ("result.json", [], "holds a list, not an object"),
        ("state.json", {"args": [], "timesteps": 8, "train_s": 3.0}, "'args' must be an object"),
        ("state.json", {"args": {}, "timesteps": 8, "train_s": 3.0}, "algorithm, policy, seed"),
        ("state.json", {"timesteps": 8}, "has no args, train_s"),
    ],
)
def test_a_malformed_run_file_is_refused_with_nothing_written(
    finished_run, tmp_path, file, content, words
) -> None:
    import shutil

    from pourbench.agents.ship import ship

    run = tmp_path / "run"
    shutil.copytree(finished_run[0], run)
    if isinstance(content, bytes):
        (run / file).write_bytes(content)
    else:
        (run / file).write_text(content if isinstance(content, str) else json.dumps(content))
    policies = tmp_path / "policies"
    with pytest.raises(InvalidParameterError, match=file) as err:
        ship(run, "mine", policy_dir=policies)
    assert words in str(err.value)
    assert not policies.exists()


def test_a_failed_save_leaves_no_partial_file(finished_run, tmp_path, monkeypatch) -> None:
    from stable_baselines3.common.base_class import BaseAlgorithm

    from pourbench.agents.ship import ship

    def save_then_fail(self, path, *args, **kwargs) -> None:
        Path(path).write_bytes(b"half a model")
        raise OSError("disk full")

    monkeypatch.setattr(BaseAlgorithm, "save", save_then_fail)
    with pytest.raises(OSError, match="disk full"):
        ship(finished_run[0], "mine", policy_dir=tmp_path)
    assert not list(tmp_path.iterdir())


def test_a_shipped_sac_model_acts_as_the_run_without_its_optimisers_moments(tmp_path) -> None:
    """SAC keeps Adam's moments for its actor and its critic; the shipped file keeps neither
    and acts as the run's model, its map and handler tolerance included."""
    from pourbench.agents.directed import DirectedTiltVecEnv, TiltTarget, mark
    from pourbench.agents.loading import load_model, load_sb3_policy, model_policy
    from pourbench.agents.models import make_model
    from pourbench.agents.sb3 import SB3PourVecEnv
    from pourbench.agents.ship import ship
    from pourbench.envs.core import PourConfig

    run = tmp_path / "run"
    run.mkdir()
    env = SB3PourVecEnv(1, seed=0, workers=1, liquid="water")
    target = TiltTarget.of(PourConfig())
    try:
        venv = DirectedTiltVecEnv(env, None, True, target)
        model = make_model("sac", venv, batch_size=8, verbose=0)
        model.learning_starts = 0
        mark(model, None, True, target, handler_tolerance_g=2.0)
        model.learn(16)
        model.save(run / "model.zip")
    finally:
        env.close()
    state = {
        "args": {"algorithm": "sac", "policy": "mlp", "seed": 0},
        "timesteps": 16,
        "train_s": 1.0,
        "history": [],
    }
    (run / "state.json").write_text(json.dumps(state))
    result = {"mean_abs_error_g": 50.0, "policy": "x", "random_mean_abs_error_g": 99.0}
    (run / "result.json").write_text(json.dumps(result))

    ship(run, "sac-test", policy_dir=tmp_path)
    shipped = tmp_path / "sac-test.zip"
    assert shipped.stat().st_size < 0.6 * (run / "model.zip").stat().st_size
    loaded = load_model(shipped)
    assert not loaded.actor.optimizer.state and not loaded.critic.optimizer.state
    original, copy = model_policy(model), load_sb3_policy(shipped)
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs = rng.uniform(0.0, 100.0, 12).astype(np.float32)
        obs[11] = rng.uniform(0.0, 2.4)
        assert np.array_equal(original(obs, True), copy(obs, True))
