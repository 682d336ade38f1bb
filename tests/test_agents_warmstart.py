"""The PD warm start: its demonstrations keep the episodes' bookkeeping, and cloning fits
both PourNet policies to the PD's actions and their critics to its returns."""

from __future__ import annotations

import numpy as np
import pytest

GAMMA = 0.9


@pytest.fixture(scope="module")
def demos():
    from pourbench.agents.sb3 import SB3PourVecEnv
    from pourbench.agents.warmstart import demonstrate

    env = SB3PourVecEnv(4, seed=0, workers=1, liquid="water", target_range_g=(50.0, 50.0))
    try:
        yield demonstrate(env, 150, GAMMA), env
    finally:
        env.close()


def test_demonstrations_keep_each_episode_apart(demos) -> None:
    """Episodes start after each end; a return is its episode's discounted reward to go, and
    only steps whose episode ended within the rollout count as complete."""
    d, _ = demos
    T, n = d.starts.shape
    assert d.obs.shape == (T, n, 12) and d.actions.shape == (T, n, 2)
    assert d.starts[0].all()
    assert len(d.errors_g) >= 1 and np.all(d.errors_g <= 25.0)  # the PD pours 50 g
    for k in range(n):
        ends = np.flatnonzero(d.starts[1:, k])  # step t ended an episode when t + 1 starts one
        last_end = ends[-1] if len(ends) else -1
        assert d.complete[: last_end + 1, k].all() and not d.complete[last_end + 1 :, k].any()
        for t in range(T - 1):
            if d.complete[t, k] and not d.starts[t + 1, k]:  # same episode goes on at t + 1
                reward = d.returns[t, k] - GAMMA * d.returns[t + 1, k]
                assert reward == pytest.approx(-1.0 / 250.0, abs=1e-9) or reward == 0.0
        # the PD turns the cup back at the end of its first pour: the action's sign changes
        assert (d.actions[:, k, 0] < 0).any() and (d.actions[:, k, 0] > 0).any()


@pytest.mark.parametrize("algorithm", ["ppo", "recurrent_ppo"])
def test_cloning_fits_the_pd_actions_and_returns(demos, algorithm) -> None:
    """After cloning, the policy's deterministic action is several times closer to the PD's
    than the untrained network's, the critic's error on the returns falls, and the policy's
    spread is the fit's residual instead of the untrained unit deviation."""
    import torch

    from pourbench.agents.models import make_model
    from pourbench.agents.warmstart import clone

    d, env = demos
    torch.manual_seed(0)
    untrained = clone(make_model(algorithm, env, n_steps=64, verbose=0), d, 1, lr=0.0)
    torch.manual_seed(0)
    model = make_model(algorithm, env, n_steps=64, verbose=0)
    assert torch.exp(model.policy.log_std).tolist() == [1.0, 1.0]
    fitted = clone(model, d, 30)
    assert fitted["action_mse"] < untrained["action_mse"] / 2.5
    assert fitted["value_mse"] < untrained["value_mse"] / 2.0
    std = torch.exp(model.policy.log_std.detach())
    assert float(std.mean()) == pytest.approx(fitted["std"], rel=1e-6)
    assert bool((std >= 0.1 - 1e-6).all()) and float(std.max()) < 0.5
    assert fitted["std"] < untrained["std"]
    # a spread given instead of the residual, with the fit otherwise alike
    torch.manual_seed(0)
    model = make_model(algorithm, env, n_steps=64, verbose=0)
    given = clone(model, d, 1, std=0.03)
    assert given["std"] == pytest.approx(0.03)
    assert torch.exp(model.policy.log_std.detach()).tolist() == pytest.approx([0.03, 0.03])


def test_a_dagger_round_follows_the_learner_and_keeps_the_pd_labels(demos) -> None:
    """With a learner the learner acts and the PD only labels: the labels are what the PD
    gives when fed the recorded observations, the visited states are not the PD's own, and
    rollouts of one length join side by side into one set of demonstrations."""
    import torch

    from pourbench.agents.models import make_model
    from pourbench.agents.pd import PDPourer
    from pourbench.agents.warmstart import demonstrate, join

    d, env = demos
    torch.manual_seed(0)
    learner = make_model("ppo", env, n_steps=64, verbose=0)  # untrained: far from the PD
    steps = d.starts.shape[0]
    got = demonstrate(env, steps, GAMMA, learner=learner)
    pd = PDPourer(env.num_envs)
    for t in range(steps):
        pd.reset(got.starts[t])
        np.testing.assert_array_equal(pd.act(got.obs[t]), got.actions[t])
    taken, _ = learner.predict(got.obs[0], deterministic=True)
    assert not np.allclose(taken, got.actions[0])  # the learner's action, not the label
    assert not np.allclose(got.obs[5:], d.obs[5:])  # so the states drift from the PD's
    both = join(d, got)
    assert both.obs.shape == (steps, 2 * env.num_envs, 12)
    np.testing.assert_array_equal(both.actions[:, env.num_envs :], got.actions)
    assert len(both.errors_g) == len(d.errors_g) + len(got.errors_g)


def test_the_lstm_is_fitted_on_each_episode_as_it_meets_it(demos) -> None:
    """In a padded batch of episodes the recurrent policy's mean action at each real step is
    the action it takes when it plays that episode from its start (SB3's predict), so the
    fit sees what the acting policy sees; the padding reaches no real step."""
    import torch
    from sb3_contrib.common.recurrent.type_aliases import RNNStates

    from pourbench.agents.models import make_model
    from pourbench.agents.warmstart import _mean_and_value, episode_batch

    d, env = demos
    torch.manual_seed(0)
    model = make_model("recurrent_ppo", env, n_steps=64, verbose=0)
    policy = model.policy
    bounds = [[*np.flatnonzero(d.starts[:, k]).tolist(), len(d.starts)] for k in range(2)]
    short = (0, bounds[0][0], bounds[0][1])  # world 0's first episode
    long = (1, bounds[1][-2], bounds[1][-1])  # world 1's last, possibly cut by the rollout
    items = sorted([short, long], key=lambda s: s[1] - s[2])  # the longer one first
    obs, _, _, _, valid, start = episode_batch(d, items)
    shape = (policy.lstm_actor.num_layers, 2, policy.lstm_actor.hidden_size)
    zero = (torch.zeros(shape), torch.zeros(shape))
    with torch.no_grad():
        mean, _ = _mean_and_value(policy, obs, RNNStates(zero, zero), start)
    length = len(valid) // 2
    for row, (k, a, b) in enumerate(items):
        state, acted = None, []
        for t in range(a, b):
            act, state = model.predict(
                d.obs[t, k][None], state=state, episode_start=np.array([t == a]),
                deterministic=True,
            )  # fmt: skip
            acted.append(act[0])
        got = mean[row * length : row * length + (b - a)].clamp(-1, 1).numpy()
        np.testing.assert_allclose(got, np.array(acted), atol=1e-5)
        assert valid[row * length : (row + 1) * length].sum() == b - a
