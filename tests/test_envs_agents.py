"""Agents on Pour-v0: the PD baseline's control law, its accuracy on water (slow), and the
Stable-Baselines3 adapter."""

from __future__ import annotations

import numpy as np
import pytest

from pourbench.agents.pd import TARGET, TILT, WEIGHT, PDConfig, PDPourer


def _obs(weight: float, target: float, tilt: float) -> np.ndarray:
    o = np.zeros(12, np.float32)
    o[WEIGHT], o[TARGET], o[TILT] = weight, target, tilt
    return o


def test_pd_control_law() -> None:
    c = PDConfig()
    pd = PDPourer(1, c)
    a = pd.act(_obs(0.0, 100.0, 0.0))
    np.testing.assert_allclose(a, [1.0, 1.0])  # approach, rotate as soon as above
    a = pd.act(_obs(0.0, 100.0, c.fast_tilt + 0.1))
    np.testing.assert_allclose(a, [c.search_rate, 0.0])  # no flow yet: slow search
    pd.act(_obs(20.0, 100.0, 1.2))  # flow onset
    a = pd.act(_obs(25.0, 100.0, 1.2))  # ~125 g/s: far above the desired flow: hold
    assert a[0] == 0.0
    a = pd.act(_obs(90.0, 100.0, 1.2))  # predicted past the target: hold
    assert a[0] == 0.0
    for _ in range(25):  # no flow for 2.5 s, short of the target: pour again
        a = pd.act(_obs(90.0, 100.0, 1.2))
    assert a[0] > 0.0
    for _ in range(10):  # the smoothed weight within the tolerance: full speed back
        a = pd.act(_obs(98.5, 100.0, 1.2))
    assert a[0] == -1.0
    a = pd.act(_obs(97.5, 100.0, 1.0))  # one low (noisy) sample does not stop the return
    assert a[0] == -1.0
    for _ in range(25):  # but a weight that stays clearly short: back to the pouring tilt
        a = pd.act(_obs(93.0, 100.0, 1.0))
    assert a[0] == 1.0
    pd.reset()
    assert pd.act(_obs(0.0, 100.0, 0.0))[0] == 1.0


@pytest.mark.slow
def test_pd_pours_water_to_100g() -> None:
    from pourbench.agents.evaluate import evaluate

    result = evaluate("pd", episodes=10, target_g=100.0, seed=0, liquid="water")
    assert result.mean_abs_error_g <= 10.0, result.summary()
    assert np.all(result.steps < 250)  # every pour ended normally, not at the step limit


def test_sb3_adapter() -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from pourbench.agents.sb3 import SB3PourVecEnv

    venv = SB3PourVecEnv(2, seed=0, liquid="water", max_steps=3)
    obs = venv.reset()
    assert obs.shape == (2, 12)
    for _ in range(3):
        venv.step_async(np.zeros((2, 2), np.float32))
        obs, _, done, infos = venv.step_wait()
    assert done.all()
    for info in infos:
        assert info["terminal_observation"].shape == (12,)
        assert info["TimeLimit.truncated"]
    # one world ends (a diverged simulation), the other goes on
    solver = venv.venv.batch.solver
    x = solver.positions()
    x[solver.world_slice(0)][:3] = np.nan
    solver.x.assign(x.astype(np.float32))
    venv.step_async(np.zeros((2, 2), np.float32))
    obs, _, done, infos = venv.step_wait()
    assert done.tolist() == [True, False]
    assert infos[0]["sim_diverged"] and infos[0]["TimeLimit.truncated"]
    assert "terminal_observation" not in infos[1] and not infos[1]["sim_diverged"]
    assert np.all(np.isfinite(obs))
    model = PPO("MlpPolicy", venv, n_steps=4, batch_size=8, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=8)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (2, 2)
