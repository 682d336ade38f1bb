"""Pour-v0 with the liquid simulation: Gymnasium's checker, determinism, vector/single
equivalence, mass accounting, collisions, divergence, bad input, autoreset, curriculum."""

from __future__ import annotations

import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.utils.env_checker import check_env
from world_probes import poison, world_steps

from pourbench import POUR_ID, ROBOT_POUR_ID
from pourbench.containers import container_names
from pourbench.envs.action_handler import ActionLimits
from pourbench.envs.core import PourBatch, PourConfig
from pourbench.envs.pour_v0 import PourEnv
from pourbench.envs.reward import RewardConfig
from pourbench.envs.vector import PourVectorEnv
from pourbench.errors import InvalidParameterError, UnknownNameError
from pourbench.fluids.params import liquid_profile
from pourbench.geometry.rotation import inverse_transform_points

ABOVE = (-0.02, 0.0, 0.12)  # start just above the receiving tray: pours within ~20 steps


def _rollout(env: gym.Env, seed: int, actions: np.ndarray, options=None):
    obs, _ = env.reset(seed=seed, options=options)
    out = [obs]
    infos = []
    for a in actions:
        obs, rew, term, trunc, info = env.step(a)
        out.append(obs)
        infos.append((rew, term, trunc, info["poured_g"], info["remaining_g"]))
    return np.array(out), infos


def test_gymnasium_env_checker() -> None:
    env = gym.make("pourbench/Pour-v0", max_steps=10)
    check_env(env.unwrapped, skip_render_check=True)
    assert isinstance(env.unwrapped, PourEnv)


def test_same_seed_same_episode() -> None:
    acts = np.tile([[1.0, 1.0]], (12, 1))
    env = PourEnv()
    a, ia = _rollout(env, 3, acts)
    b, ib = _rollout(PourEnv(), 3, acts)
    np.testing.assert_array_equal(a, b)
    assert ia == ib
    c, _ = _rollout(env, 4, acts[:1])
    assert not np.array_equal(a[0], c[0])  # another seed: another liquid/target


def test_vector_world_equals_single_env() -> None:
    n, seed, steps = 2, 10, 24
    rng = np.random.default_rng(0)
    acts = np.stack([np.tile([[1.0, 1.0]], (steps, 1)), rng.uniform(-1, 1, (steps, 2))], 1)
    venv = gym.make_vec(
        "pourbench/Pour-v0",
        num_envs=n,
        vectorization_mode="vector_entry_point",
        liquid="water",
        max_steps=steps // 2,  # world resets mid-rollout
    )
    assert isinstance(venv, PourVectorEnv)
    obs, _ = venv.reset(seed=seed, options={"start": ABOVE})
    vec = [obs]
    for t in range(steps):
        obs, *_ = venv.step(acts[t])
        vec.append(obs)
    vec = np.array(vec)
    for k in range(n):
        single = PourEnv(liquid="water", max_steps=steps // 2)
        obs, _ = single.reset(seed=seed + k, options={"start": ABOVE})
        got, done = [obs], False
        for t in range(steps):
            if done:  # next-step autoreset: the vector env resets, ignoring the action
                obs, _ = single.reset()
                done = False
            else:
                obs, _, term, trunc, _ = single.step(acts[t, k])
                done = term or trunc
            got.append(obs)
        np.testing.assert_array_equal(np.array(got), vec[:, k])


def centres_inside_a_wall(solver) -> int:
    """Particles whose centre lies inside a collider's solid (signed distance < 0)."""
    x = solver.positions()
    inside = 0
    for c, col in enumerate(solver.colliders):
        local = inverse_transform_points(col.pose, x[solver.world_slice(col.world)])
        inside += int((solver.collider_sdf(c, local)[:, 0] < 0.0).sum())
    return inside


def test_no_particle_crosses_a_wall_and_every_gram_is_placed() -> None:
    """While the cup pours into the tray: no particle's centre inside any solid, and the
    grams in the two containers, spilled and in flight add up to what was filled (150 g
    requested, within one particle)."""
    env = PourEnv(liquid="water")
    _, info = env.reset(seed=1, options={"start": ABOVE, "target_g": 60.0, "initial_g": 150.0})
    solver = env.unwrapped.batch.solver
    assert info["initial_g"] == pytest.approx(150.0, abs=solver.particle_mass(0) * 1e3)
    for _ in range(30):
        _, _, _, trunc, info = env.step(np.array([1.0, 0.0]))
        assert centres_inside_a_wall(solver) == 0
        total = info["poured_g"] + info["spilled_g"] + info["remaining_g"] + info["in_flight_g"]
        assert total == pytest.approx(info["initial_g"], rel=0.005)
        assert not trunc
    assert info["poured_g"] > 30.0  # the liquid did move into the receiving container


def test_liquid_poured_onto_the_table_is_spilled_and_the_episode_ends() -> None:
    """Free mode, the cup tipped away from the tray for 30 steps and righted for 30: all the
    liquid lands on the table, where it counts as spilled, not in flight, so the episode ends
    as the cup comes upright with the stream stopped (before settle_time's fallback)."""
    env = PourEnv(liquid="water", action_mode="free", max_steps=120)
    env.reset(seed=1)
    for t in range(120):
        _, _, term, trunc, info = env.step(np.array([1.0 if t < 30 else -1.0, 0.0]))
        if term or trunc:
            break
    assert term and not trunc and info["tilt"] == pytest.approx(0.0, abs=0.05)
    assert info["poured_g"] == 0.0 and info["remaining_g"] == 0.0
    assert info["spilled_g"] == pytest.approx(info["initial_g"], rel=0.005)
    assert info["in_flight_g"] < env.unwrapped.config.stream_stop_g
    fallback = 60 + env.unwrapped.config.settle_time / env.unwrapped.batch.control_dt
    assert t + 1 < fallback  # upright after 60 steps; settle_time would end it at `fallback`


def test_the_pouring_container_tilts_about_its_rim() -> None:
    """The pouring container turns about the y axis through its rim's centre: the rim stays
    where the base's position puts it, the body's quaternion is the tilt about y, and the
    fluid's collider has the MuJoCo body's pose, in every world of a batch."""
    import mujoco

    venv = PourVectorEnv(3, workers=1)
    venv.reset(seed=2, options={"start": ABOVE})  # above the receiving tray: tilting allowed
    batch = venv.batch
    for _ in range(4):
        venv.step(np.array([[1.0, 0.0], [0.3, 0.5], [-0.2, 1.0]]))
    assert batch.tilt.max() > 0.1  # the worlds did tilt
    for w in range(3):
        mid = batch.mocap_id[batch.worlds[w].container]
        data = batch.world_data(w)
        pos, quat = data.mocap_pos[mid], data.mocap_quat[mid]
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, quat)
        h = batch.rim_height[w]
        rim = pos + rot.reshape(3, 3) @ [0.0, 0.0, h]
        np.testing.assert_allclose(rim, batch.base[w] + [0.0, 0.0, h], atol=1e-12)
        th = batch.tilt[w]
        np.testing.assert_allclose(quat, [np.cos(th / 2), 0.0, np.sin(th / 2), 0.0], atol=1e-12)
        collider = batch.solver.colliders[batch.pour_col[w]].pose
        np.testing.assert_allclose(collider, [*pos, *quat], atol=1e-12)


@pytest.mark.parametrize(
    "liquid, device",
    [
        ("water", "cpu"),
        ("honey", "cpu"),
        pytest.param("water", "cuda", marks=pytest.mark.gpu, id="water-cuda"),
        pytest.param("honey", "cuda", marks=pytest.mark.gpu, id="honey-cuda"),
    ],
)
def test_scale_reads_the_poured_grams(liquid: str, device: str) -> None:
    """After a pour has settled in the tray, its force sensor reads the grams in it: the
    noise-free reading within 1 %, the filtered, noisy observation within 5 g (0.15 N noise,
    1 Hz low-pass). Honey's adhesion once reached the table through the tray's bottom, and
    the scale read 532 g for 150 g poured. On CUDA too: the liquid's wrench on the tray comes
    back from the device every substep."""
    import dataclasses

    from pourbench.envs import default_solver_config

    env = PourEnv(liquid=liquid, solver=dataclasses.replace(default_solver_config(), device=device))
    env.reset(seed=1, options={"start": ABOVE, "target_g": 100.0, "initial_g": 150.0})
    batch = env.unwrapped.batch
    for k in range(200):  # tilt for 3 s, then back until the episode ends, settled
        _, _, term, trunc, info = env.step(np.array([1.0 if k < 30 else -1.0, 0.0]))
        if term or trunc:
            break
    # the episode ended settled (a drop of honey may stay on the cup's lip, off the scale:
    # 5.4 g on CUDA, none on the CPU). Water pours over 140 g; honey (10 Pa·s) 98 g, and
    # keeps 36 g in the cup
    assert term and not trunc
    assert info["poured_g"] > 90.0
    assert batch.weight_g_true(0) == pytest.approx(info["poured_g"], rel=0.01)
    assert info["measured_g"] == pytest.approx(info["poured_g"], abs=5.0)


def test_collision_ends_episode_with_penalty() -> None:
    env = PourEnv(liquid="water")
    env.reset(seed=0, options={"start": (-0.165, 0.0, 0.0)})  # low, beside the tray
    for _ in range(10):
        _, rew, term, trunc, info = env.step(np.array([0.0, 1.0]))
        if term:
            break
    assert term and not trunc and info["collided"]
    assert rew <= -1.0


@pytest.mark.parametrize("workers", [1, 2])
def test_diverged_world_truncates_and_resets(workers: int) -> None:
    """A NaN-injected world, one in each worker's group, truncates with sim_diverged and is
    reset at the next step; its neighbours go on."""
    venv = PourVectorEnv(4, liquid="water", workers=workers)
    venv.reset(seed=0)
    for w in (1, 2):  # worlds 0-1 and 2-3 are the groups with 2 workers
        venv.call_world(w, poison)
    obs, rew, term, trunc, info = venv.step(np.zeros((4, 2)))
    assert trunc.tolist() == [False, True, True, False] and not term.any()
    assert info["sim_diverged"].tolist() == [False, True, True, False]
    assert np.all(np.isfinite(obs))
    obs, rew, term, trunc, info = venv.step(np.zeros((4, 2)))  # autoreset of worlds 1, 2
    assert not trunc.any() and not info["sim_diverged"].any() and rew[1] == rew[2] == 0.0
    assert np.all(np.isfinite(obs))
    venv.close()


def test_bad_input() -> None:
    env = PourEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="Water"):
        env.reset(options={"liquid": "lava"})
    with pytest.raises(ValueError, match="training"):
        env.reset(options={"container": "bucket"})
    with pytest.raises(ValueError, match="target_g"):
        env.reset(options={"target_g": -5.0})
    with pytest.raises(ValueError, match="lesson"):
        env.set_lesson(7)
    with pytest.raises(ValueError, match=r"target_g=1e\+06 g is more than any training"):
        env.reset(options={"target_g": 1e6})
    with pytest.raises(ValueError, match=r"target_g=1e\+06 g is more than container 'training'"):
        env.reset(options={"target_g": 1e6, "container": "training"})
    with pytest.raises(ValueError, match="less than one particle"):
        env.reset(options={"target_g": 1e-9})
    for start in ((0.0, 0.0, -1.0), (100.0, 0.0, 0.1), (0.0, 0.0, 0.9)):
        with pytest.raises(ValueError, match="off the table"):
            env.reset(options={"start": start})
    with pytest.raises(ValueError, match="initial_g must be finite"):
        env.reset(options={"initial_g": float("nan")})
    with pytest.raises(ValueError, match="initial_g=50 g is less than target_g=80 g"):
        env.reset(options={"target_g": 80.0, "initial_g": 50.0})
    with pytest.raises(ValueError, match=r"start must be three finite numbers"):
        env.reset(options={"start": (0.1, 0.0)})
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step([0.0])
    for action in (["1", "0.5"], [True, False], np.array([1 + 2j, 0]), np.array([1.0, None])):
        with pytest.raises(InvalidParameterError, match="actions must be"):
            env.step(action)  # refused, not converted
    with pytest.raises(InvalidParameterError, match="start must be three finite numbers"):
        env.reset(options={"start": ["-0.25", "0", "0.1"]})
    venv = PourVectorEnv(2)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        venv.step(np.array([[0.0, 0.0], [0.0, np.nan]]))
    with pytest.raises(ValueError, match=r"shape \(2, 2\)"):
        venv.step(np.zeros(2))


def test_bad_settings_and_resets_are_refused_before_anything_changes() -> None:
    with pytest.raises(InvalidParameterError, match=r"limits\.max_tilt must be > 0"):
        PourEnv(limits=ActionLimits(max_tilt=-1.0))
    with pytest.raises(InvalidParameterError, match=r"limits\.max_speed must be finite"):
        ActionLimits(max_speed=float("nan"))
    with pytest.raises(InvalidParameterError, match=r"reward\.window must be >= 1"):
        RewardConfig(window=0)
    with pytest.raises(InvalidParameterError, match="max_steps must be an integer"):
        PourEnv(max_steps=True)
    with pytest.raises(InvalidParameterError, match="num_envs must be an integer"):
        PourVectorEnv(2.7)
    env = PourEnv()
    with pytest.raises(InvalidParameterError, match="lesson must be an integer"):
        env.set_lesson(1.7)
    venv = PourVectorEnv(2, workers=2)
    with pytest.raises(InvalidParameterError, match="world 1 unreset, and it was never reset"):
        venv.reset(seed=0, options={"reset_mask": [True, False]})
    venv.reset(seed=0)
    for bad, match in [
        ({"seed": [5, -1]}, "seed must be >= 0"),
        ({"seed": [1.5, 2]}, "seed must be an integer"),
        ({"seed": 3, "options": {"reset_mask": True}}, "reset_mask must be 2 booleans"),
        ({"seed": 3, "options": {"reset_mask": [True]}}, "reset_mask must be 2 booleans"),
    ]:
        venv.step(np.zeros((2, 2)))
        steps = [venv.call_world(k, world_steps) for k in range(2)]
        with pytest.raises(InvalidParameterError, match=match):
            venv.reset(**bad)
        assert [venv.call_world(k, world_steps) for k in range(2)] == steps, "reset a world"
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 2\)"):
        venv.step(np.zeros(4))  # which two numbers are world 1's would be a guess
    assert [venv.call_world(k, world_steps) for k in range(2)] == steps, "stepped a world"
    venv.close()
    for make in (PourEnv, lambda **kw: PourVectorEnv(2, **kw)):
        with pytest.raises(InvalidParameterError, match="unknown environment setting 'liquidd'"):
            make(liquidd="water")  # was PourConfig's bare TypeError
    with pytest.raises(InvalidParameterError, match="control_hz must be >= 1 Hz"):
        PourEnv(control_hz=0.01)  # 12,000 solver steps an env step
    with pytest.raises(InvalidParameterError, match="reset options must be a dict"):
        env.reset(options=[("liquid", "water")])
    with pytest.raises(InvalidParameterError, match="target_g must be a number"):
        env.reset(options={"target_g": "lots", "initial_g": 150.0})
    env.reset(seed=0, options={"start": ABOVE})  # the refusals left it usable
    assert env.step(np.zeros(2))[0].shape == (12,)


def test_a_refused_reset_leaves_the_worlds_generator_as_it_was() -> None:
    """A reset refused after its draws (liquid, container and amounts drawn, then a start off
    the table) does not advance the world's generator: the next unseeded reset draws the
    episode it would have drawn."""
    episodes = []
    for refuse in (False, True):
        env = PourEnv()
        env.reset(seed=3)
        if refuse:
            with pytest.raises(InvalidParameterError, match="off the table"):
                env.reset(options={"start": (100.0, 0.0, 0.1)})
            # nor does a seeded one: the env keeps its seed and its own generator
            state = env.np_random.bit_generator.state
            with pytest.raises(UnknownNameError, match="lava"):
                env.reset(seed=99, options={"liquid": "lava"})
            assert env.np_random_seed == 3 and env.np_random.bit_generator.state == state
        obs, info = env.reset()
        episodes.append((obs.tolist(), info["target_g"], info["initial_g"]))
    assert episodes[0] == episodes[1]


@pytest.mark.parametrize("seed", [True, -1, 2.0])
def test_a_seed_that_is_not_a_whole_number_from_zero_is_refused_as_by_the_vector_env(seed) -> None:
    with pytest.raises(InvalidParameterError, match="seed"):
        PourEnv().reset(seed=seed)
    with pytest.raises(InvalidParameterError, match="seed"):
        PourVectorEnv(1).reset(seed=seed)


def test_stepping_outside_an_episode_is_refused_and_changes_nothing() -> None:
    env = PourEnv(max_steps=2)
    with pytest.raises(ResetNeeded, match="before its first reset"):
        env.step(np.zeros(2))
    env.reset(seed=0, options={"start": ABOVE})
    trunc = False
    for _ in range(2):
        _, _, term, trunc, _ = env.step(np.zeros(2))
    assert trunc and not term
    x = env.batch.solver.positions()
    with pytest.raises(ResetNeeded, match="after its episode ended"):
        env.step(np.zeros(2))
    assert np.array_equal(env.batch.solver.positions(), x), "the refused step moved liquid"
    env.reset(seed=1)
    _, _, term, trunc, _ = env.step(np.zeros(2))
    assert not (term or trunc)
    with pytest.raises(ResetNeeded, match="world 0 was stepped before"):
        PourVectorEnv(2).step(np.zeros((2, 2)))


@pytest.mark.parametrize(("env_id", "start"), [(POUR_ID, ABOVE), (ROBOT_POUR_ID, None)])
def test_a_rejected_first_reset_leaves_the_made_env_usable(env_id: str, start) -> None:
    """gym.make wraps the env in Gymnasium's passive env checker, and a first reset refused
    for its options loses nothing: the next reset and step work. (Gymnasium 1.4.0's checker
    fails every later step after a first reset that raised; constraints.txt keeps 1.3.0.)"""
    from gymnasium.wrappers import PassiveEnvChecker

    env = gym.make(env_id, max_steps=3)
    assert isinstance(env.env, PassiveEnvChecker)
    with pytest.raises(ValueError, match="unknown liquid"):
        env.reset(options={"liquid": "lava"})
    env.reset(seed=0, options={"start": start})
    obs, rew, term, trunc, info = env.step(np.zeros(2))
    assert obs.shape == (12,) and np.isfinite(rew) and not (term or trunc)
    assert info["target_g"] > 0
    env.close()


def test_vector_autoreset_rollout() -> None:
    venv = PourVectorEnv(2, max_steps=3)
    obs, info = venv.reset(seed=5)
    assert obs.shape == (2, 12) and venv.observation_space.contains(obs)
    for _ in range(3):
        obs, rew, term, trunc, info = venv.step(venv.action_space.sample())
    assert trunc.all() and not term.any()
    last = obs.copy()
    obs, rew, term, trunc, info = venv.step(venv.action_space.sample())
    np.testing.assert_array_equal(rew, 0.0)  # the reset step
    assert not (term | trunc).any()
    assert not np.array_equal(obs[:, 8], last[:, 8])  # new targets drawn

    same = PourVectorEnv(2, max_steps=2, autoreset_mode="same_step")
    same.reset(seed=5)
    same.step(np.zeros((2, 2)))
    obs, rew, term, trunc, info = same.step(np.zeros((2, 2)))
    assert trunc.all()
    assert info["_final_obs"].all() and info["final_obs"][0].shape == (12,)
    assert info["final_info"]["target_g"][0] == pytest.approx(info["final_obs"][0][8], abs=1e-3)
    # the info beside the new episode's observation is the new episode's (Gymnasium's rule)
    np.testing.assert_allclose(info["target_g"], obs[:, 8], atol=1e-3)
    assert not np.allclose(info["target_g"], info["final_info"]["target_g"])


def test_set_lesson_single_and_vector() -> None:
    env = PourEnv()
    venv = PourVectorEnv(2)
    lo, hi = env.batch.lessons[2].ranges["viscosity_pa_s"]
    env.set_lesson(2)
    venv.set_lesson(2)
    env.reset(seed=0)
    assert lo <= env.batch.worlds[0].liquid.viscosity_pa_s <= hi
    obs, _ = venv.reset(seed=0)
    feature = np.log10(np.array([lo, hi]) * 1e3)  # log10 of mPa·s
    assert np.all((obs[:, 3] >= feature[0]) & (obs[:, 3] <= feature[1]))


def _headless(code: str, **env: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter without a display, MUJOCO_GL as ``env`` says."""
    base = {
        k: v
        for k, v in os.environ.items()
        if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL", "PYOPENGL_PLATFORM")
    }
    return subprocess.run(
        [sys.executable, "-c", code], env={**base, **env}, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip


def _headless_stdout(code: str) -> str:
    """``code``'s output run by :func:`_headless` (EGL chosen by pourbench), skipping the test
    where this machine has no offscreen OpenGL."""
    res = _headless(code)
    if res.returncode and ("OpenGL" in res.stderr or "EGL" in res.stderr):
        pytest.skip(f"no offscreen OpenGL here: {res.stderr.strip().splitlines()[-1]}")
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_rgb_render_headless() -> None:
    """With no display and no MUJOCO_GL, importing pourbench chooses EGL: the env renders."""
    code = (
        "import numpy as np, pourbench, gymnasium as gym\n"
        "env = gym.make('pourbench/Pour-v0', render_mode='rgb_array', liquid='water')\n"
        "env.reset(seed=0, options={'start': (-0.02, 0.0, 0.12)})\n"
        "img = env.render()\n"
        "assert img.shape == (480, 640, 3) and img.dtype == np.uint8\n"
        "env.unwrapped.batch.solver.clear_world(0)\n"
        "empty = env.render()\n"
        "print('DIFF', int((np.abs(img.astype(int) - empty).sum(-1) > 30).sum()))\n"
    )
    out = _headless_stdout(code)
    assert int(out.split("DIFF")[1]) > 200  # the liquid's particles are drawn


def test_human_render_without_a_display_is_the_envs_own_error(monkeypatch) -> None:
    """render_mode="human" reaches the env through gym.make (no pygame wrapper), and without
    a display the env refuses it in one line that says what to use instead."""
    import sys

    from pourbench.errors import PourbenchError

    if not sys.platform.startswith("linux"):
        pytest.skip("the display check is Linux's")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    for make in (
        lambda: gym.make("pourbench/Pour-v0", render_mode="human"),
        lambda: PourEnv(render_mode="human"),
    ):
        with pytest.raises(
            PourbenchError, match=r"render_mode='human'.*needs a display.*rgb_array"
        ):
            make()
    with pytest.raises(ValueError, match="render_mode must be None, 'human' or 'rgb_array'"):
        PourEnv(render_mode="ansi")


def test_vector_render_with_workers_headless() -> None:
    """The vector env renders every world, the worker's too: world 1's image is the single
    env's given seed + 1, not world 0's. Pixels are compared with a margin, as the two images
    come from OpenGL contexts in separate processes; test_envs_workers compares the worlds'
    numbers exactly."""
    code = (
        "import numpy as np, pourbench, gymnasium as gym\n"
        "kw = dict(render_mode='rgb_array', liquid='water')\n"
        "opts = {'start': (-0.02, 0.0, 0.12)}\n"
        "venv = gym.make_vec('pourbench/Pour-v0', num_envs=2,"
        " vectorization_mode='vector_entry_point', workers=2, **kw)\n"
        "venv.reset(seed=0, options=opts)\n"
        "imgs = venv.render()\n"
        "assert len(imgs) == 2 and all(i.shape == (480, 640, 3) for i in imgs)\n"
        "env = gym.make('pourbench/Pour-v0', **kw)\n"
        "env.reset(seed=1, options=opts)\n"
        "one = env.render()\n"
        "def changed(a, b):\n"
        "    return int((np.abs(a.astype(int) - b).sum(-1) > 30).sum())\n"
        "print('CHANGED', changed(imgs[1], one), changed(imgs[0], imgs[1]))\n"
        "venv.close()\n"
    )
    to_single, between_worlds = map(int, _headless_stdout(code).split("CHANGED")[1].split())
    assert between_worlds > 200  # the seeds' liquids differ visibly
    assert to_single <= between_worlds // 20, (to_single, between_worlds)


def test_no_offscreen_library_leaves_the_backend_unset() -> None:
    """Headless, with neither EGL nor OSMesa installed (a bare GPU server): import pourbench
    chooses no backend, since MuJoCo imports the chosen one at its own import and a missing
    library broke ``import pourbench.fluids`` there; else EGL first, then OSMesa."""
    code = (
        "import ctypes.util, os, sys\n"
        "have = set(sys.argv[1:])\n"
        "ctypes.util.find_library = lambda name: f'lib{name}.so' if name in have else None\n"
        "import pourbench\n"
        "print('GL', os.environ.get('MUJOCO_GL'))\n"
        "if not have:\n"
        "    import pourbench.fluids  # imports MuJoCo\n"
    )

    def chosen(*libraries: str) -> str:
        res = _headless(f"import sys; sys.argv[1:] = {list(libraries)!r}\n" + code)
        assert res.returncode == 0, res.stderr
        return res.stdout.split("GL ")[1].strip()

    assert chosen() == "None"
    assert chosen("OSMesa") == "osmesa"
    assert chosen("EGL", "OSMesa") == "egl"


def test_render_without_a_usable_backend_says_what_to_set() -> None:
    """A backend that needs a display (GLFW) chosen on a machine without one: one clear
    error naming MUJOCO_GL, not MuJoCo's fatal OpenGL message alone."""
    code = (
        "import pourbench, gymnasium as gym\n"
        "env = gym.make('pourbench/Pour-v0', render_mode='rgb_array')\n"
        "env.reset(seed=0)\n"
        "try:\n"
        "    env.render()\n"
        "except RuntimeError as exc:\n"
        "    print('ERROR', exc)\n"
    )
    res = _headless(code, MUJOCO_GL="glfw")
    assert res.returncode == 0, res.stderr
    assert "ERROR offscreen rendering failed" in res.stdout and "MUJOCO_GL=egl" in res.stdout


def test_episode_ends_upright_with_algorithm5_bonus() -> None:
    env = PourEnv(liquid="water")
    opts = {"start": ABOVE, "target_g": 60.0, "initial_g": 150.0}
    _, info = env.reset(seed=2, options=opts)
    rewards = []
    for _ in range(120):
        back = info.get("measured_g", 0.0) >= 45.0 or env.batch.tilt[0] > 1.9
        _, rew, term, trunc, info = env.step(np.array([-1.0 if back else 1.0, 0.0]))
        rewards.append(rew)
        if term or trunc:
            break
    assert term and not trunc and not info["collided"]
    assert info["tilt"] <= env.config.upright_tilt
    assert info["poured_g"] > 20.0
    # first completed episode: the running average is this episode's error
    assert info["average_error_g"] == pytest.approx(info["error_g"])
    assert info["completed_episodes"] == 1
    bonus = (info["error_g"] <= 10.0) + (info["average_error_g"] <= 20.0)
    assert rewards[-1] == pytest.approx(bonus)
    assert all(r in (0.0, pytest.approx(-1 / env.config.max_steps)) for r in rewards[:-1])
    assert info["is_success"] == (info["error_g"] <= 10.0)
    # the running average is the environment's memory: the next episode starts with it
    obs, info2 = env.reset(seed=3)
    assert obs[10] == pytest.approx(info["error_g"], abs=1e-4)
    assert info2["average_error_g"] == pytest.approx(info["error_g"])
    fresh_obs, fresh_info = PourEnv(liquid="water").reset(seed=3)  # a new environment: none yet
    assert fresh_obs[10] == 0.0 and fresh_info["completed_episodes"] == 0


def test_rerun_recording(tmp_path) -> None:
    import rerun as rr

    empty = tmp_path / "empty.rrd"
    rec = rr.RecordingStream("pourbench")
    rec.save(empty)
    rec.flush()
    path = tmp_path / "pour.rrd"
    path.write_bytes(b"an earlier recording")
    env = PourEnv(record_path=str(path), max_steps=5)
    env.reset(seed=0)
    env.step(np.array([1.0, 1.0]))
    n = env.batch.solver.num_particles
    assert path.read_bytes() == b"an earlier recording"  # kept until this one is complete
    env.close()
    assert not path.with_name("pour.rrd.partial").exists()
    # two frames of particle positions (3 float32 each) beyond an empty recording
    assert path.stat().st_size > empty.stat().st_size + 2 * 12 * n


def test_novel_containers_are_observed() -> None:
    from pourbench.containers import container_names, get_container

    env = PourEnv(container_set="novel", liquid="water")
    seen = set()
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        c = get_container(info["container"])
        assert info["container"] in container_names("novel")
        assert obs[5] == pytest.approx(c.diameter) and obs[6] == pytest.approx(c.depth)
        seen.add(info["container"])
    assert len(seen) > 1
    obs, info = env.reset(seed=0, options={"container": "mug", "target_g": 80.0})
    assert info["container"] == "mug" and obs[8] == pytest.approx(80.0)
    obs, *_ = env.step(np.array([1.0, 1.0]))
    assert np.all(np.isfinite(obs))
    with pytest.raises(InvalidParameterError, match=r"'training' \(training set\) is not in"):
        env.reset(options={"container": "training"})  # not in the novel set


def test_a_pouring_container_is_taken_by_name_from_either_set() -> None:
    """``container=`` names one pouring container of either set (the set is inferred); a
    reset asking for one outside the scene says how to get it, an unknown name lists every
    pouring container with its set."""
    env = PourEnv(container="bottle_water", liquid="water")
    _, info = env.reset(seed=0, options={"target_g": 80.0})
    assert info["container"] == "bottle_water"
    with pytest.raises(InvalidParameterError, match=r"make the env with container='mug'"):
        env.reset(options={"container": "mug"})
    with pytest.raises(
        UnknownNameError, match=r"mugg'; known .*mug \(novel\).*training \(training\)"
    ):
        env.reset(options={"container": "mugg"})
    with pytest.raises(UnknownNameError, match=r"bowl_big"):
        PourEnv(container="bowl_big")


def test_drawn_containers_hold_the_asked_target() -> None:
    """With ``target_g`` given, only containers that hold it are drawn: 280 g of water from
    the novel set never draws the wine glass (278 g), which would fail mid-evaluation."""
    env = PourEnv(liquid="water", container_set="novel")
    batch = env.unwrapped.batch
    for seed in range(12):
        env.reset(seed=seed, options={"target_g": 280.0})
        container = batch.worlds[0].container
        assert 0.85 * batch.capacity_g(container, 1000.0) >= 280.0, container


@pytest.mark.parametrize(
    "bad, name",
    [
        ({"control_hz": 0.0}, "control_hz"),
        ({"control_hz": float("nan")}, "control_hz"),
        ({"control_hz": 1000.0}, "control_hz"),
        ({"control_hz": 50.0}, "rates near it: 40, 60"),
        ({"max_steps": 0}, "max_steps"),
        ({"sensor_noise_n": -1.0}, "sensor_noise_n"),
        ({"sensor_cutoff_hz": 60.0}, "sensor_cutoff_hz"),
        ({"target_range_g": (200.0, 50.0)}, "target_range_g"),
        ({"upright_tilt": 0.5}, "upright_tilt"),
        ({"start_x": (-5.0, -4.0)}, "start_x"),
        ({"start_y": (0.0, 0.6)}, "start_y"),
        ({"start_height": (0.6, 0.7)}, "start_height"),
        ({"target_range_g": (0.1, 1.0), "liquid": "honey"}, "one particle"),
        ({"container": "cup_small"}, "cup_small"),
        ({"limits": {"max_tilt": 1.0}}, r"limits must be ActionLimits\("),
        ({"reward": {}}, r"reward must be RewardConfig\("),
        ({"solver": {"spacing": 0.01}}, r"solver must be SolverConfig\("),
        ({"target_range_g": (50.0, 400.0)}, "target_range_g"),
    ],
)
def test_bad_settings_are_refused_when_the_env_is_made(bad: dict, name: str) -> None:
    """Settings under which some reset without options would be refused (a start off the
    table, a target or fill no pouring container holds, a target under one particle) are
    refused when the env is made, so no autoreset can fail mid-run."""
    with pytest.raises(ValueError, match=name):
        PourEnv(**bad)


def test_a_small_container_pours_its_own_range_at_every_seed() -> None:
    """cup_small (118 g of the lightest curriculum liquid) with ranges it holds: every
    drawn reset starts."""
    env = PourEnv(container="cup_small", target_range_g=(20.0, 60.0), extra_range_g=(10.0, 40.0))
    for seed in range(30):
        _, info = env.reset(seed=seed)
        assert 20.0 <= info["target_g"] <= 60.0 and info["container"] == "cup_small"


def hold_filled(container_set: str, names: tuple[str, ...], liquids: tuple[str, ...]) -> None:
    """Each of ``names`` filled with each of ``liquids`` to the largest mass Pour-v0 accepts
    (85 % of its capacity), one world each, held upright and still for 3 s at Pour-v0's
    defaults: no world diverges and no liquid leaves its container."""
    cases = [(c, liq) for c in names for liq in liquids]
    batch = PourBatch(len(cases), PourConfig(container_set=container_set))
    for w, (name, liq) in enumerate(cases):
        cap = 0.85 * batch.capacity_g(name, liquid_profile(liq).density)
        # the target only has to be one the container can hold (the spoon holds 3 g)
        opts = {"container": name, "liquid": liq, "initial_g": 0.999 * cap, "target_g": cap / 2}
        batch.reset_world(w, seed=w, options=opts)
    batch.flush()
    for _ in range(30):  # 3 s of 10 Hz control steps, every action zero: nothing moves
        *_, info = batch.step(np.zeros((len(cases), 2)))
        held = info["spilled_g"] + info["in_flight_g"] + info["poured_g"]
        assert not info["sim_diverged"].any(), [cases[w] for w in info["sim_diverged"].nonzero()[0]]
        assert (held == 0.0).all(), {cases[w]: held[w] for w in np.flatnonzero(held)}


def test_deep_containers_filled_to_the_brim_hold_their_water() -> None:
    hold_filled(
        "novel", ("bottle_wine", "bottle_water", "measuring_cylinder", "pitcher"), ("water",)
    )


@pytest.mark.slow
def test_every_container_filled_to_the_brim_holds_water_and_honey() -> None:
    for container_set in ("training", "novel"):
        hold_filled(container_set, container_names(container_set), ("water", "honey"))


def test_a_liquid_without_a_physical_viscosity_is_refused() -> None:
    """The observation carries the viscosity in Pa·s (log10 of mPa·s): a FleX-only profile is
    refused when the env is made or reset, naming the liquid, and the env goes on."""
    from pourbench.errors import InvalidParameterError
    from pourbench.fluids import liquid_profile

    flex_only = liquid_profile("water").replace(name="FleX water", viscosity_pa_s=None)
    with pytest.raises(InvalidParameterError, match="'FleX water' has no physical viscosity"):
        PourEnv(liquid=flex_only)
    env = PourEnv(liquid="honey")
    obs, _ = env.reset(seed=0)
    assert obs[3] == pytest.approx(4.0)  # log10 of honey's 10 000 mPa·s
    with pytest.raises(InvalidParameterError, match="no physical viscosity"):
        env.reset(seed=0, options={"liquid": flex_only})
    obs, *_ = env.step(np.zeros(2))
    assert obs[3] == pytest.approx(4.0)


def test_the_denser_reward_charges_the_final_error_at_the_step_limit() -> None:
    """A policy that never pours is charged its whole target at the step limit by the denser
    option, and nothing beyond the step penalty by Algorithm 5 alone."""
    from pourbench.envs.pour_v0 import PourEnv
    from pourbench.envs.reward import RewardConfig

    rewards = []
    for per_g in (0.0, 0.02):
        env = PourEnv(liquid="water", max_steps=3, reward=RewardConfig(final_error_per_g=per_g))
        env.reset(seed=0, options={"target_g": 50.0})
        for _ in range(3):
            _, r, term, trunc, info = env.step(np.zeros(2, np.float32))
        env.close()
        assert trunc and not term and info["error_g"] == 50.0
        rewards.append(r)
    assert rewards[0] == pytest.approx(-1.0 / 3.0)
    assert rewards[1] == pytest.approx(-1.0 / 3.0 - 0.02 * 50.0)


def test_the_progress_term_pays_each_gram_of_the_final_error_as_the_scale_moves() -> None:
    """With ``RewardConfig.progress_per_g`` = c each step's reward gains c (error before −
    error after) and nothing else, the liquid moving as without it: over an episode that
    reaches the target and pours past it, the steps that bring the error down pay, those
    that pour past the target charge, and the whole adds c (target − final error), so
    nothing of it is left for the episode's end."""
    from pourbench.envs.pour_v0 import PourEnv
    from pourbench.envs.reward import RewardConfig

    c, steps = 0.05, 70
    start = {"start": (-0.25, 0.0, 0.12), "target_g": 60.0}
    runs = {}
    for per_g in (0.0, c):
        env = PourEnv(liquid="water", max_steps=steps, reward=RewardConfig(progress_per_g=per_g))
        env.reset(seed=0, options=start)
        rewards, errors = [], [start["target_g"]]
        for t in range(steps):
            _, r, term, trunc, info = env.step(np.array([1.0 if t < 55 else -1.0, 1.0]))
            rewards.append(r)
            errors.append(info["error_g"])
            if term or trunc:
                break
        runs[per_g] = (np.array(rewards), np.array(errors))
        env.close()
    (plain, errors0), (paid, errors) = runs[0.0], runs[c]
    np.testing.assert_array_equal(errors, errors0)  # the same pour
    added = paid - plain
    np.testing.assert_allclose(added, c * (errors[:-1] - errors[1:]), atol=1e-12)
    assert errors.min() < 5.0 and errors[-1] > 20.0  # reached the target, then poured past it
    assert np.sum(added) == pytest.approx(c * (start["target_g"] - errors[-1]))
    assert added[-1] == pytest.approx(c * (errors[-2] - errors[-1]), abs=1e-12)
    with pytest.raises(InvalidParameterError, match="progress_per_g must be >= 0"):
        RewardConfig(progress_per_g=-0.01)
    from pourbench.envs.robot_pour import RobotPourEnv

    with pytest.raises(InvalidParameterError, match=r"PourRobot-v0 .* no progress_per_g term"):
        RobotPourEnv(reward=RewardConfig(progress_per_g=0.05))


def test_the_shaping_term_is_potential_based() -> None:
    """With ``RewardConfig.shaping`` the reward gains γΦ(s′) − Φ(s) and nothing else: over a
    whole episode that ends at the step limit (a terminal state for the learners) the
    discounted sum of what it adds is −Φ(s0), from the closed-form distance; a step toward
    the receiving container adds, and so does tilting over it, a step away takes off; once
    the scale reads more than the target every step adds k (γ (1 + c′) − (1 + c)), c the
    closeness 1 − (reading − target) / target, so a step that pours on takes off. The liquid
    moves as without it."""
    from pourbench.envs.pour_v0 import PourEnv
    from pourbench.envs.reward import SHAPING_DISTANCE_M, RewardConfig

    gamma, k, steps = 0.99, 0.5, 70
    start = {"start": (-0.25, 0.0, 0.12), "target_g": 60.0}
    runs = {}
    for scale in (0.0, k):
        env = PourEnv(liquid="water", max_steps=steps,
                      reward=RewardConfig(shaping=scale, shaping_gamma=gamma))  # fmt: skip
        env.reset(seed=0, options=start)
        batch = env.unwrapped.batch
        phi0 = batch.potential[0]
        rewards, poured, reading = [], [], [batch.filter.value_g[0]]
        for t in range(steps):
            _, r, term, trunc, info = env.step(np.array([1.0 if t < 55 else -1.0, 1.0]))
            rewards.append(r)
            poured.append(info["poured_g"])
            reading.append(batch.filter.value_g[0])
            if term or trunc:
                break
        runs[scale] = (np.array(rewards), poured, phi0)
        env.close()
    (plain, poured0, _), (shaped, poured1, phi0) = runs[0.0], runs[k]
    assert poured0 == poured1 and poured1[-1] > 0  # it poured, as without the term
    assert trunc and not term and len(shaped) == steps  # ended by the step limit
    half = batch._half[batch.cidx[0]]
    assert phi0 == pytest.approx(k * (1.0 - (0.25 - half) / SHAPING_DISTANCE_M))
    added = shaped - plain
    assert np.sum(gamma ** np.arange(len(added)) * added) == pytest.approx(-phi0, abs=1e-9)
    assert added[0] > 0  # approaching
    assert added[25] > 0  # tilting over the receiving container, before liquid reaches it
    target = start["target_g"]
    closeness = 1.0 - np.minimum((np.array(reading) - target) / target, 2.0)
    over = [t for t in range(len(added) - 1) if min(reading[t], reading[t + 1]) > target]
    assert len(over) > 10  # it over-poured and stayed over to the end
    for t in over:  # above the receiving container, the scale full: only closeness moves
        expected = k * (gamma * (1.0 + closeness[t + 1]) - (1.0 + closeness[t]))
        assert added[t] == pytest.approx(expected, abs=1e-9)
    rising = [t for t in over if reading[t + 1] > reading[t] + 5.0]
    assert rising and all(added[t] < 0 for t in rising)  # pouring on past the target costs
    env = PourEnv(liquid="water", reward=RewardConfig(shaping=k, shaping_gamma=gamma))
    env.reset(seed=0, options=start)
    _, r, *_ = env.step(np.array([0.0, -1.0]))  # a step away from the receiving container
    assert r < -1.0 / 250.0
    with pytest.raises(InvalidParameterError, match="shaping_gamma must be <= 1"):
        RewardConfig(shaping=1.0, shaping_gamma=1.5)
    from pourbench.envs.robot_pour import RobotPourEnv

    with pytest.raises(InvalidParameterError, match=r"PourRobot-v0 .* has no shaping term"):
        RobotPourEnv(reward=RewardConfig(shaping=1.0))


def test_reset_options_made_directly_are_checked_like_a_dict() -> None:
    """A ResetOptions built by hand holds checked values as one parsed from a dict does."""
    from pourbench.envs.options import ResetOptions

    assert ResetOptions(liquid="water").liquid == liquid_profile("water")
    assert ResetOptions.parse({"liquid": "water"}) == ResetOptions(liquid="water")
    with pytest.raises(InvalidParameterError, match="initial_g must be finite"):
        ResetOptions(initial_g=float("nan"))
    with pytest.raises(UnknownNameError, match="lava"):
        ResetOptions(liquid="lava")
    env = PourEnv(liquid="water")
    _, info = env.reset(seed=0, options=ResetOptions(target_g=80.0, initial_g=120.0))
    assert info["target_g"] == 80.0


def test_the_fill_holds_at_least_the_target() -> None:
    """A reset fills at least its initial amount, so a target equal to the initial amount can
    be reached: {"target_g": 100, "initial_g": 100} fills 100 g and less than a particle more
    (the nearest particle count held 99.84 g), and so does every drawn reset."""
    env = PourEnv(liquid="water")
    _, info = env.reset(seed=0, options={"target_g": 100.0, "initial_g": 100.0})
    grams = env.unwrapped.batch.particle_g[0]
    assert 100.0 <= info["initial_g"] < 100.0 + grams
    for seed in range(8):
        _, info = env.reset(seed=seed)
        assert info["initial_g"] >= info["target_g"]


def test_an_initial_amount_alone_draws_a_target_it_holds() -> None:
    """reset(options={"initial_g": x}) draws the target from the config's range up to x, at
    every seed; an x below the range's least target is refused."""
    env = PourEnv(liquid="water")
    for seed in range(6):
        _, info = env.reset(seed=seed, options={"initial_g": 120.0})
        assert 50.0 <= info["target_g"] <= 120.0
    with pytest.raises(InvalidParameterError, match="give target_g too"):
        env.reset(seed=0, options={"initial_g": 30.0})
