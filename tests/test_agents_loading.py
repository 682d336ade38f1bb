"""load_policy: the same call serves "pd", "random", a shipped name and a saved model (PPO,
RecurrentPPO, SAC, TQC, CrossQ), each as f(obs, new_episode) -> action; unknown names list
what exists."""

from __future__ import annotations

import numpy as np
import pytest

from pourbench.agents import load_policy
from pourbench.agents.pd import PDConfig, PDPourer
from pourbench.agents.sb3 import SB3PourVecEnv
from pourbench.argtypes import shipped_policies
from pourbench.cli import main

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _observations(n: int) -> np.ndarray:
    env = SB3PourVecEnv(1, seed=0, workers=1, liquid="water")
    space = env.observation_space
    env.close()
    space.seed(5)
    return np.stack([space.sample() for _ in range(n)])


def test_pd_and_random_by_name() -> None:
    obs = _observations(5)
    pd, ref = load_policy("pd"), PDPourer(1, PDConfig())
    for k, o in enumerate(obs):
        if k == 0:
            ref.reset()
        np.testing.assert_array_equal(pd(o, k == 0), ref.act(o))
    a = [load_policy("random", seed=3)(o, False) for o in obs[:1]]
    b = [load_policy("random", seed=3)(o, False) for o in obs[:1]]
    np.testing.assert_array_equal(a, b)
    acts = np.array([load_policy("random", seed=4)(o, False) for o in obs])
    assert acts.shape == (5, 2) and np.all(np.abs(acts) <= 1.0)


@pytest.mark.parametrize("algorithm", ["sac", "tqc", "crossq", "td3"])
def test_a_saved_off_policy_model_acts_as_in_memory(tmp_path, algorithm) -> None:
    """Each off-policy learner ``pourbench train`` builds, trained a few updates (two per
    environment step for TQC and CrossQ), saved and read back by name of its algorithm."""
    from pourbench.agents.loading import algorithm_of
    from pourbench.agents.models import make_model

    env = SB3PourVecEnv(2, seed=0, workers=1, liquid="water")
    model = make_model(algorithm, env, batch_size=8, seed=2, utd=1.0, verbose=0)
    assert model.gradient_steps == 2  # utd 1 on 2 worlds
    model.learning_starts = 0
    model.learn(8)
    model.save(tmp_path / f"{algorithm}.zip")
    env.close()
    assert algorithm_of(tmp_path / f"{algorithm}.zip") == algorithm
    act = load_policy(tmp_path / f"{algorithm}.zip")
    for o in _observations(4):
        np.testing.assert_array_equal(act(o, False), model.predict(o, deterministic=True)[0])


@pytest.mark.parametrize("algorithm", ["sac", "tqc", "crossq"])
def test_a_fixed_entropy_coefficient_stays_through_training_and_saving(tmp_path, algorithm):
    """``ent_coef`` > 0 holds the entropy coefficient (no tuning optimizer) through updates and
    a save; 0 leaves SB3's automatic tuning; td3 and ppo, which have no such coefficient,
    refuse one."""
    from pourbench.agents.loading import load_model
    from pourbench.agents.models import make_model

    env = SB3PourVecEnv(2, seed=0, workers=1, liquid="water")
    auto = make_model(algorithm, env, batch_size=8, verbose=0)
    assert auto.ent_coef_optimizer is not None
    model = make_model(algorithm, env, batch_size=8, seed=2, utd=1.0, ent_coef=0.015, verbose=0)
    assert model.ent_coef_optimizer is None
    model.learning_starts = 0
    model.learn(8)
    model.save(tmp_path / "fixed.zip")
    for other in ("td3", "ppo"):
        with pytest.raises(ValueError, match=f"{other} has none to fix"):
            make_model(other, env, ent_coef=0.015, verbose=0)
    env.close()
    loaded = load_model(tmp_path / "fixed.zip")
    assert loaded.ent_coef_optimizer is None
    assert float(loaded.ent_coef_tensor) == pytest.approx(0.015)


def test_unknown_names_say_which_exist(capsys) -> None:
    with pytest.raises(ValueError, match=r"unknown policy 'pournet-gru'; known: pd, random"):
        load_policy("pournet-gru")
    with pytest.raises(SystemExit):
        main(["eval", "--policy", "pournet-gru"])
    err = capsys.readouterr().err
    assert "'pournet-gru' is neither a policy (pd, random" in err
    with pytest.raises(ValueError, match=r"policy must be one of .* got 7"):
        load_policy(7)


@pytest.mark.parametrize("name", shipped_policies())
def test_each_shipped_policy_pours_100_g_of_water_within_10_g(name) -> None:
    """The bar for a shipped policy, one cell of Table 6.3: the mean absolute error of ten
    100 g pours of water in a row (seeds 0…9) within 10 g. The mean of ten, not each pour nor
    a few: a single pour's outcome follows the CPU's floating-point path (docs/training.md,
    "Shipping a run")."""
    from pourbench.agents.evaluate import evaluate

    result = evaluate(name, episodes=10, target_g=100.0, seed=0, liquid="water")
    assert result.mean_abs_error_g <= 10.0, result.summary()
