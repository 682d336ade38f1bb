"""The curiosity module: its losses fall on fixed transitions, its bonus reaches PPO's rewards
before returns and advantages are computed, and episode ends use the terminal observation."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv
from toy_envs import Toy

from pourbench.agents.icm import ICMConfig, ICMTrainer, ICMVecEnv

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_icm_losses_fall_on_a_fixed_set_of_transitions() -> None:
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(512, 6)).astype(np.float32)
    act = rng.uniform(-1, 1, size=(512, 2)).astype(np.float32)
    mix = rng.normal(size=(2, 6)).astype(np.float32)
    next_obs = (obs + act @ mix).astype(np.float32)  # the action is readable from (s, s')
    torch.manual_seed(0)
    trainer = ICMTrainer(6, 2, ICMConfig(epochs=1, batch_size=128))
    first = trainer.update(obs, act, next_obs, rng)
    for _ in range(60):
        last = trainer.update(obs, act, next_obs, rng)
    assert last["inverse_loss"] < 0.2 * first["inverse_loss"]
    assert last["forward_loss"] < 0.5 * first["forward_loss"]
    # the bonus is eta/2 |phi_hat(s') - phi(s')|^2 per transition
    icm = trainer.icm
    with torch.no_grad():
        o, a, o2 = (torch.as_tensor(x[:4]) for x in (obs, act, next_obs))
        pred = icm.forward_model(torch.cat([icm.features(o), a], 1))
        expected = 0.02 / 2 * ((pred - icm.features(o2)) ** 2).sum(1)
    np.testing.assert_allclose(icm.intrinsic_reward(obs[:4], act[:4], next_obs[:4]), expected)


def _gae(rewards, values, starts, last_values, last_dones, gamma, lam) -> np.ndarray:
    """Generalised advantage estimation by hand: rewards (T, n), values (T, n), starts (T, n)
    (1 where the step begins an episode)."""
    T = len(rewards)
    adv = np.zeros_like(rewards)
    running = np.zeros(rewards.shape[1])
    for t in reversed(range(T)):
        if t == T - 1:
            alive, next_v = 1.0 - last_dones, last_values
        else:
            alive, next_v = 1.0 - starts[t + 1], values[t + 1]
        delta = rewards[t] + gamma * next_v * alive - values[t]
        running = delta + gamma * lam * alive * running
        adv[t] = running
    return adv


def test_the_intrinsic_reward_enters_before_the_advantages() -> None:
    """PPO's rollout buffer holds extrinsic + intrinsic rewards, and its advantages are GAE
    of that sum (computed here by hand), not of the extrinsic reward alone."""
    envs = [Toy(5, 0.0), Toy(3, 1.0)]
    venv = ICMVecEnv(DummyVecEnv([lambda e=e: e for e in envs]), ICMConfig(eta=5.0, update_every=0))
    gamma, lam = 0.9, 0.8
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=16, n_epochs=1, gamma=gamma,
                gae_lambda=lam, seed=3, device="cpu")  # fmt: skip
    seen = {}

    class Grab(BaseCallback):
        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            buf = self.model.rollout_buffer
            seen.update(rewards=buf.rewards.copy(), values=buf.values.copy())
            seen.update(advantages=buf.advantages.copy(), starts=buf.episode_starts.copy())
            seen["last_values"] = self.locals["values"].numpy().ravel()
            seen["last_dones"] = self.locals["dones"].astype(float)

    model.learn(8 * 2, callback=Grab())
    # the toy worlds' own record of every transition, replayed through the (untrained) ICM
    extrinsic = np.array([[e.log[t][3] for e in envs] for t in range(8)])
    bonus = np.array(
        [
            venv.trainer.icm.intrinsic_reward(
                np.stack([e.log[t][0] for e in envs]),
                np.stack([e.log[t][1] for e in envs]),
                np.stack([e.log[t][2] for e in envs]),  # terminal observation at episode ends
            )
            for t in range(8)
        ]
    )
    assert bonus.min() > 1e-3  # a bonus large enough to matter
    np.testing.assert_allclose(seen["rewards"], extrinsic + bonus, rtol=1e-5)
    args = (seen["values"], seen["starts"], seen["last_values"], seen["last_dones"], gamma, lam)
    np.testing.assert_allclose(seen["advantages"], _gae(extrinsic + bonus, *args), rtol=1e-4,
                               atol=1e-5)  # fmt: skip
    assert not np.allclose(seen["advantages"], _gae(extrinsic, *args), atol=1e-3)


def test_icm_trains_every_rollout_and_reports_its_stats(tmp_path) -> None:
    venv = ICMVecEnv(DummyVecEnv([Toy, Toy]), ICMConfig(update_every=8, batch_size=8))
    venv.reset()
    before = [p.detach().clone() for p in venv.trainer.icm.parameters()]
    for k in range(8):
        *_, infos = venv.step(np.full((2, 1), 0.5, np.float32))
        assert all(info["intrinsic_reward"] >= 0 for info in infos)
        if k < 7:
            assert venv.stats == {}
    assert set(venv.stats) == {"inverse_loss", "forward_loss", "intrinsic_reward"}
    assert venv.stats["intrinsic_reward"] > 0
    after = list(venv.trainer.icm.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(before, after, strict=True))
    # save and load: the same bonus
    venv.save(tmp_path / "icm.pt")
    other = ICMVecEnv(DummyVecEnv([Toy, Toy]), ICMConfig(update_every=8, batch_size=8))
    other.load(tmp_path / "icm.pt")
    x = np.ones((1, 3), np.float32)
    a = np.zeros((1, 1), np.float32)
    assert other.trainer.icm.intrinsic_reward(x, a, x) == venv.trainer.icm.intrinsic_reward(x, a, x)
    wrong = ICMVecEnv(DummyVecEnv([Toy]), ICMConfig(feature_dim=8))
    with pytest.raises(ValueError, match=r"icm\.pt.*is not this run's ICM state"):
        wrong.load(tmp_path / "icm.pt")


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"eta": -1.0}, "eta must be >= 0"),
        ({"beta": 1.5}, "beta must be in \\[0, 1\\], got 1.5"),
        ({"lr": 0.0}, "lr must be > 0"),
        ({"feature_dim": 0}, "feature_dim must be >= 1"),
    ],
)
def test_bad_icm_settings_are_refused(kw, words) -> None:
    with pytest.raises(ValueError, match=words):
        ICMConfig(**kw)


def test_recurrent_ppo_trains_on_the_rewards_with_the_bonus() -> None:
    """RecurrentPPO (sb3-contrib) through the same wrapper: its rollout buffer's rewards are
    the extrinsic ones plus each transition's intrinsic reward."""
    from sb3_contrib import RecurrentPPO

    envs = [Toy(5, 0.0), Toy(3, 1.0)]
    venv = ICMVecEnv(DummyVecEnv([lambda e=e: e for e in envs]), ICMConfig(eta=5.0, update_every=8))
    model = RecurrentPPO("MlpLstmPolicy", venv, n_steps=8, batch_size=16, n_epochs=1, seed=0,
                         device="cpu", policy_kwargs={"lstm_hidden_size": 16})  # fmt: skip
    bonuses: list[list[float]] = []

    class Grab(BaseCallback):
        def _on_step(self) -> bool:
            bonuses.append([i["intrinsic_reward"] for i in self.locals["infos"]])
            return True

        def _on_rollout_end(self) -> None:
            self.rewards = self.model.rollout_buffer.rewards.copy()

    grab = Grab()
    model.learn(32, callback=grab)  # two rollouts: the second after an ICM update
    extrinsic = np.array([[e.log[8 + t][3] for e in envs] for t in range(8)])
    np.testing.assert_allclose(grab.rewards, extrinsic + np.array(bonuses[8:]), rtol=1e-5)
    assert set(venv.stats) == {"inverse_loss", "forward_loss", "intrinsic_reward"}
