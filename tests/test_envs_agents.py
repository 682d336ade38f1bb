"""Agents on Pour-v0: the PD baseline's control law, its accuracy on water (slow), and the
Stable-Baselines3 adapter."""

from __future__ import annotations

import numpy as np
import pytest
from world_probes import poison

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


def test_pd_noise_during_the_approach_is_not_a_flow_onset() -> None:
    pd = PDPourer(1, PDConfig())
    for w in (0.0, 6.0, 7.0, 0.0):  # noisy readings above detect_g before any rotation
        a = pd.act(_obs(w, 100.0, 0.0))
        np.testing.assert_allclose(a, [1.0, 1.0])  # still approaching


def _plant_episode(seed: int, target: float = 100.0, steps: int = 250) -> tuple[int, float]:
    """One pour of the PD baseline on a lumped plant: a container holding 160 g whose
    capacity shrinks with tilt, its excess draining with a 0.3 s time constant, 0.3 s of
    stream delay, a low-passed scale with correlated noise of 2 g, and Algorithm 4's rules
    (approach first; rotate forward only below target − tolerance, backward only above).
    Returns the steps until the container is upright again with the stream over (``steps``
    if never) and the poured grams."""
    rng = np.random.default_rng(seed)
    c = PDConfig()
    pd = PDPourer(1, c)
    rate, approach = 0.8, 6  # rad/s at |ω| = 1, approach steps
    tilt, inside, poured, scale, noise, weight = 0.0, 160.0, 0.0, 0.0, 0.0, 0.0
    stream = [0.0, 0.0, 0.0]
    for k in range(steps):
        omega, r = pd.act(_obs(weight, target, tilt))
        if approach > 0:
            approach -= int(r > 0)
        elif (omega >= 0.0) == (weight < target - c.tolerance_g):
            tilt = float(np.clip(tilt + omega * rate * c.control_dt, 0.0, 2.4))
        capacity = 180.0 * max(0.0, 1.0 - tilt / 2.2) ** 1.5
        out = max(0.0, inside - capacity) * (1.0 - np.exp(-c.control_dt / 0.3))
        inside -= out
        stream.append(out)
        poured += stream.pop(0)
        scale += 0.45 * (poured - scale)
        noise = 0.6 * noise + 1.6 * rng.standard_normal()
        weight = scale + noise
        if poured > 1.0 and tilt <= 0.05 and sum(stream) + out < 0.1:
            return k + 1, poured
    return steps, poured


def test_pd_pours_on_when_the_stream_stops_short() -> None:
    """A stream that stops a few grams short of target − tolerance, with the noisy weight
    around it, does not trap the baseline (hold, return, re-pour only to the same tilt)
    until the step limit."""
    outcomes = [_plant_episode(seed) for seed in range(100)]
    steps = np.array([n for n, _ in outcomes])
    errors = np.array([abs(p - 100.0) for _, p in outcomes])
    assert np.all(steps < 250), np.flatnonzero(steps >= 250)
    assert errors.max() <= 10.0 and errors.mean() <= 4.0, (errors.max(), errors.mean())


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

    venv = SB3PourVecEnv(2, seed=0, liquid="water", max_steps=3, workers=2)
    obs = venv.reset()
    assert obs.shape == (2, 12)
    for _ in range(3):
        venv.step_async(np.zeros((2, 2), np.float32))
        obs, _, done, infos = venv.step_wait()
    assert done.all()
    for info in infos:
        assert info["terminal_observation"].shape == (12,)
        assert not info["TimeLimit.truncated"]  # the step limit ends the task: no bootstrap
    # one world ends (a diverged simulation, in the parent's group), the other goes on
    venv.venv.call_world(0, poison)
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


def test_pd_refuses_bad_observations_and_keeps_its_state() -> None:
    """A wrong-shaped or non-finite observation is refused before any state changes: the
    pourer then acts exactly as one that never saw it, and still resets."""
    obs = [_obs(0.0, 100.0, 0.0), _obs(0.0, 100.0, 0.7), _obs(20.0, 100.0, 1.2)]
    ref, pd = PDPourer(1), PDPourer(1)
    expected = [ref.act(o) for o in obs]
    got = [pd.act(obs[0])]
    bad = [np.zeros((2, 12)), np.zeros(11), np.zeros(24), np.full(12, np.nan), "x"]
    for o in bad:
        with pytest.raises(ValueError, match="obs must"):
            pd.act(o)
    got += [pd.act(o) for o in obs[1:]]
    np.testing.assert_array_equal(np.array(got), np.array(expected))
    pd.reset()
    np.testing.assert_allclose(pd.act(obs[0]), [1.0, 1.0])
    two = PDPourer(2)
    with pytest.raises(ValueError, match=r"obs must have shape \(2, 12\)"):
        two.act(np.zeros(12))  # one world's observation for two worlds
    with pytest.raises(ValueError, match="mask must be 2 booleans"):
        two.reset(np.array([True]))
    with pytest.raises(ValueError, match="mask must be 2 booleans"):
        two.reset([0, 1])  # indices, not booleans
    two.reset(np.array([True, False]))
    assert two.act(np.zeros((2, 12))).shape == (2, 2)


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda: PDPourer(2.7), "num_envs must be an integer"),
        (lambda: PDPourer(0), "num_envs must be >= 1"),
        (lambda: PDPourer(float("nan")), "num_envs must be an integer"),
        (lambda: PDConfig(control_dt=0.0), "control_dt must be > 0"),
        (lambda: PDConfig(control_dt=-0.1), "control_dt must be >= 0"),
        (lambda: PDConfig(control_dt=float("nan")), "control_dt must be finite"),
        (lambda: PDConfig(kp=float("nan")), "kp must be finite"),
        (lambda: PDConfig(search_rate="x"), "search_rate must be a number"),
        (lambda: PDConfig(search_rate=2.0), r"search_rate must be in \[0, 1\]"),
        (lambda: PDConfig(flow_smoothing=2.0), r"flow_smoothing must be in \(0, 1\]"),
        (lambda: PDConfig(min_flow=40.0, max_flow=30.0), "min_flow must be <= max_flow"),
    ],
)
def test_pd_bad_settings_are_refused(make, words) -> None:
    with pytest.raises(ValueError, match=words):
        make()


def test_pd_takes_inf_as_no_cap_and_no_stall_rule() -> None:
    cfg = PDConfig(max_flow=float("inf"), stall_time=float("inf"))
    assert cfg.max_flow == cfg.stall_time == float("inf")
    with pytest.raises(ValueError, match="kp must be finite"):
        PDConfig(kp=float("inf"))


def test_sb3_adapter_indices_and_close() -> None:
    """``env_method("reset", indices=[0])`` resets world 0 only; ``set_attr`` and other
    methods take every world or nothing; indices out of range and use after close are
    refused."""
    from pourbench.agents.sb3 import SB3PourVecEnv

    venv, ref = (SB3PourVecEnv(2, seed=0, liquid="water", max_steps=50) for _ in range(2))
    first, _ = venv.reset(), ref.reset()
    for _ in range(5):
        venv.step(np.ones((2, 2), np.float32))
        ref.step(np.ones((2, 2), np.float32))
    (reset0,) = venv.env_method("reset", indices=[0])
    assert reset0[0].shape == (12,)
    after, *_ = venv.step(np.zeros((2, 2), np.float32))
    expected, *_ = ref.step(np.zeros((2, 2), np.float32))
    np.testing.assert_array_equal(after[1], expected[1])  # world 1 went on, not reset
    assert not np.array_equal(after[1], first[1])
    assert not np.array_equal(after[0], expected[0])  # world 0 started over
    ref.close()
    with pytest.raises(ValueError, match="indices 7 not in"):
        venv.get_attr("num_envs", indices=[7, 8, 9])
    with pytest.raises(ValueError, match="indices 2 not in"):
        venv.env_method("reset", indices=2)
    with pytest.raises(ValueError, match=r"set_attr.*acts on all 2 worlds"):
        venv.set_attr("foo", 1, indices=[1])
    with pytest.raises(ValueError, match=r"env_method.*acts on all 2 worlds"):
        venv.env_method("set_lesson", 0, indices=[0])
    assert venv.get_attr("num_envs", indices=[1]) == [2]
    venv.set_attr("foo", 1, indices=[0, 1])  # every world: allowed
    assert venv.get_attr("foo") == [1, 1]
    venv.close()
    with pytest.raises(ValueError, match="closed"):
        venv.step(np.zeros((2, 2), np.float32))
    venv.close()  # a second close is harmless
