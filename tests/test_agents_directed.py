"""Directed tilt (pourbench.agents.directed): the policy's tilt output maps onto the half of
the tilt rate Algorithm 4 applies, so every output moves a container above the receiving one;
the map loses none of the handler's rates, runs in training's vector env, and a saved model
acts through it. The directed approach maps the approach output onto speeds toward the
receiving container only. The tilt target maps the tilt output onto the tilt the container
turns toward, holding it where the output's tilt is the container's."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pourbench.agents import load_policy
from pourbench.agents.directed import ActionMap, DirectedTiltVecEnv, TiltTarget, direct, mark
from pourbench.agents.loading import applied_mean
from pourbench.agents.models import make_model
from pourbench.agents.sb3 import SB3PourVecEnv
from pourbench.agents.train import TrainArgs
from pourbench.envs.action_handler import ActionLimits, handle_actions
from pourbench.envs.core import PourConfig

pytestmark = pytest.mark.usefixtures("one_torch_thread")

TOLERANCE = 2.0
DT = 0.1
ENV = {"workers": 1, "liquid": "water", "target_range_g": (50.0, 50.0), "max_steps": 60}


def _obs(remaining_g: np.ndarray) -> np.ndarray:
    """Observations whose only set feature is the remaining weight (target − reading)."""
    obs = np.zeros((len(remaining_g), 12), np.float32)
    obs[:, 9] = remaining_g
    return obs


def _tilt_change(actions: np.ndarray, weight_g: float, tilt: float = 1.0) -> np.ndarray:
    """Algorithm 4's tilt change, rad, for each action of a container above the receiving
    one at ``tilt`` rad, the scale reading ``weight_g`` of a 100 g target."""
    n = len(actions)
    _, new_tilt, above = handle_actions(
        actions,
        base=np.zeros((n, 3)),
        tilt=np.full(n, tilt),
        target_pos=np.zeros((n, 3)),
        above_half_extent=np.full(n, 0.01),
        receiving_height=0.1,
        weight_g=np.full(n, weight_g),
        target_g=np.full(n, 100.0),
        tolerance_g=TOLERANCE,
        dt=DT,
    )
    assert above.all()
    return new_tilt - tilt


def test_direct_maps_the_tilt_output_onto_the_allowed_half_and_passes_the_approach() -> None:
    u = np.array([-1.0, 0.0, 1.0, 3.0])  # 3 is clipped to 1 first
    actions = np.c_[u, [0.3, -0.7, 1.0, -1.0]]
    forward = direct(actions, _obs(np.full(4, 50.0)), TOLERANCE)
    backward = direct(actions, _obs(np.full(4, TOLERANCE)), TOLERANCE)  # at the tolerance
    np.testing.assert_allclose(forward[:, 0], [0.0, 0.5, 1.0, 1.0])
    np.testing.assert_allclose(backward[:, 0], [0.0, -0.5, -1.0, -1.0])
    np.testing.assert_allclose(forward[:, 1], [0.3, -0.7, 1.0, -1.0])
    np.testing.assert_array_equal(forward[:, 1], backward[:, 1])
    one = direct(np.array([0.0, 0.2]), _obs(np.array([50.0]))[0], TOLERANCE)
    assert one.shape == (2,) and one.dtype == np.float32


@pytest.mark.parametrize("weight_g", [40.0, 99.0])
def test_every_directed_tilt_output_moves_the_container_and_none_is_lost(weight_g) -> None:
    """Before the target (40 g of 100) and after it (99 g, within the 2 g tolerance):
    the plain action's half of the range pointing the wrong way leaves the tilt where it is,
    while through the map the tilt change grows strictly with the output, in the allowed
    direction, and covers every change the plain actions make, from none to the full rate."""
    u = np.linspace(-1.0, 1.0, 41)
    actions = np.c_[u, np.zeros_like(u)]
    remaining = np.full(len(u), 100.0 - weight_g)
    plain = _tilt_change(actions, weight_g)
    directed = _tilt_change(direct(actions, _obs(remaining), TOLERANCE), weight_g)
    sign = 1.0 if weight_g < 100.0 - TOLERANCE else -1.0
    dead = u * sign <= 0.0
    assert np.all(plain[dead] == 0.0) and dead.sum() == 21
    assert np.all(np.diff(sign * directed) > 0.0)
    full = ActionLimits().max_rate * DT
    np.testing.assert_allclose([directed[0], directed[-1]], [0.0, sign * full], atol=1e-12)
    live = actions[~dead]  # each rate the handler applies, reached through the map by 2|ω| − 1
    inverse = np.c_[2.0 * np.abs(live[:, 0]) - 1.0, live[:, 1]]
    mapped = direct(inverse, _obs(remaining[~dead]), TOLERANCE)
    np.testing.assert_allclose(_tilt_change(mapped, weight_g), plain[~dead], atol=1e-7)


TARGET = TiltTarget.of(PourConfig())


def test_the_tilt_target_scales_are_the_handlers() -> None:
    """u = 1 is the largest tilt the handler allows; the full rate turns 0.08 rad a step."""
    np.testing.assert_allclose(TARGET, (ActionLimits().max_tilt, ActionLimits().max_rate * DT))
    np.testing.assert_allclose(TARGET, (2.4, 0.08))


@pytest.mark.parametrize(("weight_g", "tilt"), [(40.0, 1.0), (99.0, 1.0), (40.0, 0.03)])
def test_the_tilt_target_turns_toward_the_outputs_tilt_and_holds_there(weight_g, tilt) -> None:
    """Through the map and Algorithm 4 a container at ``tilt`` lands on the output's tilt
    θ* = (u + 1) / 2 · 2.4 where that is within a full-rate step in the direction the handler
    allows (forward before the target, backward after), turns at the full rate toward it
    where it is farther, and holds where θ* is on the side the handler forbids: the change
    never moves away from θ*, and every change the plain actions make is one output's."""
    u = np.linspace(-1.0, 1.0, 241)
    goal = (u + 1.0) / 2.0 * TARGET.max_tilt
    actions = np.c_[u, np.zeros_like(u)]
    obs = _obs(np.full(len(u), 100.0 - weight_g))
    obs[:, 11] = tilt
    change = _tilt_change(direct(actions, obs, None, tilt_target=TARGET), weight_g, tilt)
    forward = weight_g < 100.0 - TOLERANCE
    allowed = goal > tilt if forward else goal < tilt
    expected = np.where(allowed, np.clip(goal - tilt, -TARGET.step, TARGET.step), 0.0)
    expected = np.maximum(expected, -tilt)  # the handler keeps the tilt at or above upright
    np.testing.assert_allclose(change, expected, atol=1e-6)
    assert np.all(np.diff(change) >= -1e-9)  # the change grows with u
    plain = _tilt_change(np.c_[np.linspace(-1, 1, 41), np.zeros(41)], weight_g, tilt)
    inverse = 2.0 * (tilt + plain) / TARGET.max_tilt - 1.0  # the output whose θ* is the end
    back = direct(np.c_[inverse, np.zeros(41)], obs[:41], None, tilt_target=TARGET)
    np.testing.assert_allclose(_tilt_change(back, weight_g, tilt), plain, atol=1e-6)


def test_a_wrapper_with_both_tilt_maps_is_refused() -> None:
    env = SB3PourVecEnv(1, seed=0, **ENV)
    with pytest.raises(ValueError, match="both map the tilt"):
        DirectedTiltVecEnv(env, TOLERANCE, tilt_target=TARGET)
    env.close()


def test_the_directed_approach_maps_onto_speeds_toward_the_receiving_container() -> None:
    """v ↦ (v + 1) / 2 with the tilt untouched when only the approach is mapped; through
    Algorithm 4 every mapped output keeps or shortens the horizontal distance to the
    receiving container, growing with v, where the plain outputs below zero lengthen it."""
    v = np.linspace(-1.0, 1.0, 21)
    actions = np.c_[np.full_like(v, -0.3), v]
    mapped = direct(actions, _obs(np.full(len(v), 50.0)), None, approach=True)
    np.testing.assert_allclose(mapped[:, 0], -0.3, rtol=1e-6)
    np.testing.assert_allclose(mapped[:, 1], (v + 1.0) / 2.0, atol=1e-7)
    both = direct(actions, _obs(np.full(len(v), 50.0)), TOLERANCE, approach=True)
    np.testing.assert_allclose(both[:, 0], 0.35, rtol=1e-6)

    def distance(a: np.ndarray) -> np.ndarray:
        n = len(a)
        base, _, above = handle_actions(
            a,
            base=np.tile([0.3, 0.0, 0.05], (n, 1)),
            tilt=np.zeros(n),
            target_pos=np.zeros((n, 3)),
            above_half_extent=np.full(n, 0.04),
            receiving_height=0.1,
            weight_g=np.zeros(n),
            target_g=np.full(n, 100.0),
            tolerance_g=TOLERANCE,
            dt=DT,
        )
        assert not above.any()
        return np.linalg.norm(base[:, :2], axis=1)

    plain, directed = distance(actions), distance(mapped)
    assert np.all(plain[v < 0.0] > 0.3)
    assert np.all(directed <= 0.3) and np.all(np.diff(directed) < 0.0)
    np.testing.assert_allclose(directed[0], 0.3)
    np.testing.assert_allclose(directed[-1], 0.3 - ActionLimits().max_speed * DT)


def _directed_model(
    tmp_path, mean: tuple[float, float], approach: bool = False, target: bool = False
) -> str:
    """A SAC model on a directed (or with ``target`` a tilt-target) vector env whose
    deterministic action is ``mean`` everywhere, saved with its map."""
    env = SB3PourVecEnv(1, seed=0, **ENV)
    tolerance, tilt_target = (None, TARGET) if target else (TOLERANCE, None)
    model = make_model("sac", DirectedTiltVecEnv(env, tolerance, approach, tilt_target), verbose=0)
    mark(model, tolerance, approach, tilt_target)
    with torch.no_grad():
        model.policy.actor.mu.weight.zero_()
        model.policy.actor.mu.bias.copy_(torch.atanh(torch.tensor(mean)))
    path = str(tmp_path / "directed.zip")
    model.save(path)
    env.close()
    return path


def test_a_saved_directed_model_acts_through_its_map(tmp_path) -> None:
    act = load_policy(_directed_model(tmp_path, (0.2, -0.4)))
    obs = _obs(np.array([50.0, 1.0]))
    np.testing.assert_allclose(act(obs[0], True), [0.6, -0.4], atol=1e-5)
    np.testing.assert_allclose(act(obs[1], False), [-0.6, -0.4], atol=1e-5)
    act = load_policy(_directed_model(tmp_path, (0.2, -0.4), approach=True))
    np.testing.assert_allclose(act(obs[0], True), [0.6, 0.3], atol=1e-5)
    act = load_policy(_directed_model(tmp_path, (0.2, -0.4), target=True))
    obs[:, 11] = [1.42, 1.5]  # θ* = 1.44 rad: a quarter of the full rate forward, then back
    np.testing.assert_allclose(act(obs[0], True), [0.25, -0.4], atol=1e-5)
    np.testing.assert_allclose(act(obs[1], False), [-0.75, -0.4], atol=1e-5)


def test_the_wrapper_tilts_only_above_the_receiving_container_and_at_the_mapped_rate() -> None:
    """In Pour-v0's real worlds: approaching at full speed with the output −1 the container
    stays upright (the map's zero rate), and once above it tilts by (u + 1) / 2 of the full
    rate each step."""
    env = DirectedTiltVecEnv(SB3PourVecEnv(1, seed=5, **ENV), TOLERANCE)
    obs = env.reset()
    for _ in range(40):
        obs, _, done, _ = env.step(np.array([[-1.0, 1.0]], np.float32))
        assert not done[0] and obs[0, 11] == 0.0
    rate = ActionLimits().max_rate * DT
    tilts = [float(obs[0, 11])]
    for _ in range(3):
        obs, _, done, _ = env.step(np.array([[0.0, 1.0]], np.float32))
        tilts.append(float(obs[0, 11]))
    env.close()
    np.testing.assert_allclose(np.diff(tilts), 0.5 * rate, rtol=1e-6)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"directed_tilt": 1}, "directed_tilt must be True or False"),
        ({"directed_tilt": True, "residual": 0.3}, "does not go with a PD residual"),
        ({"directed_tilt": True, "warm_start_steps": 64}, "does not go with a PD residual"),
        ({"directed_approach": "yes"}, "directed_approach must be True or False"),
        ({"directed_approach": True, "residual": 0.3}, "does not go with a PD residual"),
        ({"tilt_target": 1}, "tilt_target must be True or False"),
        ({"tilt_target": True, "residual": 0.3}, "does not go with a PD residual"),
        ({"tilt_target": True, "directed_tilt": True}, "both map the policy's tilt output"),
    ],
)
def test_bad_directed_tilt_settings_are_refused(kw, match) -> None:
    with pytest.raises(ValueError, match=match):
        TrainArgs(**kw)


@pytest.mark.parametrize(
    "action_map, remaining_g, tilt, mean, std",
    [
        (ActionMap(), 50.0, 1.0, (-0.5, -0.2), (0.8, 0.3)),  # the mean tilts back: no pour
        (ActionMap(), 1.0, 1.0, (0.4, 0.9), (1.2, 0.05)),  # after the target, the mean tilts on
        (ActionMap(TOLERANCE, True), 50.0, 1.0, (0.3, -1.0), (0.6, 0.7)),
        (ActionMap(tilt_target=TARGET), 50.0, 1.0, (-0.2, 0.0), (0.5, 1.5)),  # θ* under θ
        (ActionMap(approach=True, tilt_target=TARGET), 1.0, 1.0, (0.0, 0.5), (1.0, 0.2)),
    ],
)
def test_the_applied_mean_is_the_mean_of_what_algorithm_4_applies_to_the_samples(
    action_map, remaining_g, tilt, mean, std
) -> None:
    """applied_mean's quadrature against 400 000 sampled actions, each tanh-squashed, mapped
    and applied by the real handler: the mean tilt change and approach output agree within
    their sampling error (about 0.002 of the full rate), and the handler applies the
    returned action unchanged (its tilt rate is in the allowed direction)."""
    rng = np.random.default_rng(0)
    n = 400_000
    obs = _obs(np.array([remaining_g]))[0]
    obs[11] = tilt
    expected = applied_mean(np.array(mean), np.array(std), obs, action_map, TOLERANCE)
    samples = np.tanh(rng.normal(mean, std, size=(n, 2)))
    mapped = direct(samples, np.broadcast_to(obs, (n, 12)), *action_map)
    full = ActionLimits().max_rate * DT
    weight_g = 100.0 - remaining_g
    sampled_tilt = _tilt_change(mapped, weight_g, tilt).mean() / full
    np.testing.assert_allclose(expected[0], sampled_tilt, atol=0.005)
    np.testing.assert_allclose(expected[1], mapped[:, 1].mean(), atol=0.005)
    applied = _tilt_change(expected[None], weight_g, tilt)[0] / full
    np.testing.assert_allclose(applied, expected[0], atol=1e-6)


def test_a_model_that_records_the_handler_acts_with_the_applied_mean(tmp_path) -> None:
    """A SAC model whose actor's Gaussian is the same everywhere, saved with the handler's
    tolerance, acts with applied_mean of that Gaussian through its map; one saved without it
    (before the tolerance was recorded) acts with the squashed mean, as SB3 does."""
    env = SB3PourVecEnv(1, seed=0, **ENV)
    model = make_model("sac", DirectedTiltVecEnv(env, None, True, TARGET), verbose=0)
    mean, std = np.array([-0.3, 0.2]), np.array([0.7, 0.4])
    actor = model.policy.actor
    with torch.no_grad():
        actor.mu.weight.zero_()
        actor.mu.bias.copy_(torch.tensor(mean))
        actor.log_std.weight.zero_()
        actor.log_std.bias.copy_(torch.tensor(np.log(std)))
    mark(model, None, True, TARGET)
    model.save(tmp_path / "plain.zip")
    mark(model, None, True, TARGET, handler_tolerance_g=TOLERANCE)
    model.save(tmp_path / "recorded.zip")
    env.close()
    obs = _obs(np.array([50.0, 1.0]))
    obs[:, 11] = 1.0
    recorded, plain = load_policy(tmp_path / "recorded.zip"), load_policy(tmp_path / "plain.zip")
    for o in obs:
        want = applied_mean(mean, std, o, ActionMap(None, True, TARGET), TOLERANCE)
        np.testing.assert_allclose(recorded(o, True), want, atol=1e-5)
        np.testing.assert_allclose(
            plain(o, True), direct(np.tanh(mean), o, None, True, TARGET), atol=1e-5
        )
    assert recorded(obs[0], True)[0] > 0.0 > plain(obs[0], True)[0]  # the samples pour
