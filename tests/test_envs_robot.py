"""PourRobot-v0: the robot in the loop with real MuJoCo, the real planners and the real liquid.

Fast: construction through Gymnasium, spaces equal Pour-v0's, bad input refused with the
value named, same seed same episode, the planner tracking the handler's end-effector target,
collision and planner-failure flags, the F/T gravity compensation. Slow: PD baseline pours
and the left wrist's reading of settled liquid.
"""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.utils.env_checker import check_env

import pourbench  # noqa: F401  (registers the ids)
from pourbench.agents.pd import PDPourer
from pourbench.envs.ft_sensor import GRIPPER_MASS, gravity_compensate, vertical_load
from pourbench.envs.observation import GRAVITY
from pourbench.envs.pour_v0 import PourEnv
from pourbench.envs.robot_pour import RobotPourEnv, RobotSettings
from pourbench.errors import CapacityError, InvalidParameterError, UnknownNameError

COMBOS = [("movo", "nmpc"), ("movo", "mink"), ("panda", "nmpc"), ("panda", "mink")]


def test_made_through_gymnasium_with_pour_v0_spaces() -> None:
    env = gym.make("pourbench/PourRobot-v0")
    robot = env.unwrapped
    assert isinstance(robot, RobotPourEnv)
    assert (robot.robot, robot.planner_name) == ("movo", "nmpc")  # the defaults
    pour = PourEnv()
    assert env.observation_space == pour.observation_space
    assert env.action_space == pour.action_space
    obs, info = env.reset(seed=0)
    assert obs.shape == (12,) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    assert info["collided"] is False and info["planner_failed"] is False
    _, _, _, _, step_info = env.step(np.zeros(2))
    assert list(info) == list(step_info)  # the reset's info has a step's keys, in order
    assert info["joint_velocity"].shape == step_info["joint_velocity"].shape


@pytest.mark.parametrize(("robot", "planner"), [("movo", "nmpc"), ("panda", "mink")])
def test_gymnasium_env_checker(robot: str, planner: str) -> None:
    check_env(RobotPourEnv(robot=robot, planner=planner, max_steps=10), skip_render_check=True)


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"robot": "ur5"}, UnknownNameError, r"'ur5'.*movo.*panda"),
        ({"planner": "rrt"}, UnknownNameError, r"'rrt'.*mink, nmpc"),
        ({"liquid": "lava"}, UnknownNameError, r"'lava'"),
        ({"max_step": 10}, InvalidParameterError, r"'max_step'"),
    ],
)
def test_bad_construction_is_refused_naming_the_value(kwargs, exc, match) -> None:
    with pytest.raises(exc, match=match):
        RobotPourEnv(**kwargs)


def test_bad_actions_and_targets_are_refused_naming_the_value() -> None:
    env = RobotPourEnv(robot="panda", liquid="water")
    with pytest.raises(ResetNeeded):
        env.step(np.zeros(2))
    env.reset(seed=0, options={"target_g": 100.0})
    with pytest.raises(InvalidParameterError, match=r"finite.*nan"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(InvalidParameterError, match=r"shape \(2,\).*\(3,\)"):
        env.step(np.zeros(3))
    with pytest.raises(CapacityError, match=r"target_g=5000 g.*'training' holds \d+ g"):
        env.reset(options={"target_g": 5000.0})
    with pytest.raises(CapacityError, match=r"initial_g=900 g"):
        env.reset(options={"target_g": 100.0, "initial_g": 900.0})
    with pytest.raises(InvalidParameterError, match=r"unknown reset options \['colour'\]"):
        env.reset(options={"colour": "red"})
    with pytest.raises(UnknownNameError, match=r"'bottle'"):
        env.reset(options={"container": "bottle"})
    with pytest.raises(InvalidParameterError, match=r"out of the panda's reach"):
        env.reset(options={"start": [-0.25, 0.0, 2.0]})
    with pytest.raises(InvalidParameterError, match=r"start must be three.*'abc'"):
        env.reset(options={"start": "abc"})
    # refused steps and resets changed nothing: the episode goes on where it was
    q = env.data.qpos[env.kin.qadr].copy()
    _, _, term, trunc, info = env.step(np.zeros(2))
    assert not (term or trunc or info["planner_failed"])
    np.testing.assert_allclose(env.data.qpos[env.kin.qadr], q, atol=5e-3)  # held, not reset


def _run(env: RobotPourEnv, seed: int, actions: np.ndarray) -> tuple[np.ndarray, list]:
    obs, _ = env.reset(seed=seed)
    out, infos = [obs], []
    for a in actions:
        obs, rew, term, trunc, info = env.step(a)
        out.append(obs)
        infos.append((rew, term, trunc, info["poured_g"], info["pos_error_m"]))
        assert not (term or trunc)
    return np.array(out), infos


@pytest.mark.parametrize(("robot", "planner"), [("movo", "nmpc"), ("panda", "mink")])
def test_same_seed_same_episode(robot: str, planner: str) -> None:
    acts = np.tile([[1.0, 1.0]], (25, 1))  # approach, then tilt over the tray
    a, ia = _run(RobotPourEnv(robot=robot, planner=planner), 5, acts)
    b, ib = _run(RobotPourEnv(robot=robot, planner=planner), 5, acts)
    np.testing.assert_array_equal(a, b)
    assert ia == ib
    assert a[-1, 11] > 0.3  # it did tilt: the run covered the approach and the turn
    c, _ = _run(RobotPourEnv(robot=robot, planner=planner), 6, acts[:1])
    assert not np.array_equal(a[0], c[0])  # another seed: another liquid or target


@pytest.mark.parametrize(("robot", "planner"), COMBOS)
def test_planner_tracks_the_handler_target_once_settled(robot: str, planner: str) -> None:
    """Approach (translation), tilt 0.5 rad, then hold: the rim reaches the handler's pose
    target within 1 cm and 2 degrees once the target stands still."""
    env = RobotPourEnv(robot=robot, planner=planner, liquid="water")
    env.reset(seed=1, options={"start": [-0.22, 0.03, 0.12], "target_g": 150.0})
    worst = 0.0
    for a in [(0.0, 1.0)] * 20 + [(1.0, 0.0)] * 6 + [(0.0, 0.0)] * 15:
        obs, _, term, trunc, info = env.step(np.array(a))
        assert not (term or trunc), info
        worst = max(worst, info["pos_error_m"])
    assert obs[11] == pytest.approx(6 * 0.08, abs=1e-6)  # 6 steps at 0.8 rad/s
    goal_p, goal_q = env.ee_target()
    p, q = env.ee_pose()
    assert np.linalg.norm(p - goal_p) <= 0.01
    assert 2 * np.arccos(min(1.0, abs(float(q @ goal_q)))) <= np.radians(2.0)
    assert info["tilt_measured"] == pytest.approx(obs[11], abs=np.radians(2.0))
    assert worst < 0.03  # while moving at the handler's full speed, too


def test_the_planner_runs_at_10_hz_or_faster_whatever_the_control_rate() -> None:
    """At 2 Hz (0.5 s steps) the planner is called five times a step, toward targets
    interpolated along the handler's motion, and still tracks it."""
    assert RobotPourEnv().plan_dt == pytest.approx(0.1)  # 10 Hz: once a step
    env = RobotPourEnv(robot="panda", liquid="water", control_hz=2.0)
    assert (env.plans, env.plan_dt) == (5, pytest.approx(0.1))
    env.reset(seed=0, options={"start": [-0.22, 0.0, 0.12], "target_g": 100.0})
    for a in [(0.0, 1.0)] * 3 + [(0.5, 0.0)] * 2 + [(0.0, 0.0)] * 3:
        obs, _, term, trunc, info = env.step(np.array(a))
        assert not (term or trunc), info
    assert obs[11] == pytest.approx(2 * 0.5 * 0.8 * 0.5)  # two 0.5 s steps at 0.4 rad/s
    assert info["pos_error_m"] <= 0.01 and info["rot_error_rad"] <= np.radians(2.0)


@pytest.mark.parametrize(("robot", "planner"), COMBOS)
def test_driving_the_container_into_the_tray_wall_ends_the_episode(robot, planner) -> None:
    """Algorithm 4 approaches horizontally from a start whose base is below the tray's rim:
    the planner, keeping its clearance between the cup's capsule and the tray (and the arm's
    and the table), stops short of it; the episode ends with ``planner_failed`` and no
    contact was ever made."""
    env = RobotPourEnv(robot=robot, planner=planner, liquid="water")
    env.reset(seed=0, options={"start": [-0.25, 0.0, 0.01], "target_g": 100.0})
    for _ in range(30):
        _, rew, term, trunc, info = env.step(np.array([0.0, 1.0]))
        assert env.data.ncon == 0
        if term or trunc:
            break
    assert term and not trunc
    assert info["planner_failed"] and not info["collided"]
    assert rew <= -1.0  # Algorithm 5's collision penalty


@pytest.mark.parametrize("robot", ["movo", "panda"])
def test_a_cup_in_the_tray_wall_is_a_collision(robot: str) -> None:
    """The arm put (by IK on the real model) where the cup cuts the tray's wall: the next
    step's MuJoCo contacts end the episode with ``collided``."""
    env = RobotPourEnv(robot=robot, liquid="water")
    env.reset(seed=0, options={"start": [-0.25, 0.0, 0.12], "target_g": 100.0})
    goal_p, goal_q = env._to_world(np.array([-0.12, 0.0, 0.005]), 0.0)
    q, err = env._ik(env.data.qpos[env.kin.qadr].copy(), goal_p, goal_q)
    assert err < 1e-4
    env.data.qpos[env.kin.qadr] = q
    env.data.act[env.act_adr] = q
    mujoco.mj_forward(env.model, env.data)
    _, rew, term, _, info = env.step(np.zeros(2))
    assert term and info["collided"] and not info["planner_failed"]
    assert rew <= -1.0


def test_the_pouring_arm_touching_the_other_arm_is_a_collision() -> None:
    """MuJoCo makes no contacts between robot links; the overlap check covers them: the
    Movo's cup put into its left gripper (by IK on the real model) overlaps, home does not."""
    env = RobotPourEnv(robot="movo")
    env.reset(seed=0, options={"target_g": 100.0})
    m, d = env.model, env.data
    assert not env._self_pairs.overlapping(d)
    left = d.site_xpos[m.site("left_ee").id] + np.array([0.05, 0.0, 0.0])
    q, err = env._ik(env.kin.home(), left, env.rim_quat0)
    assert err < 1e-4
    d.qpos[env.kin.qadr] = q
    mujoco.mj_kinematics(m, d)
    assert env._self_pairs.overlapping(d)


def test_a_planner_that_misses_its_target_ends_the_episode() -> None:
    env = RobotPourEnv(robot="movo", settings=RobotSettings(max_pos_error=1e-4))
    env.reset(seed=0, options={"target_g": 100.0})
    _, _, term, _, info = env.step(np.array([0.0, 1.0]))
    assert term and info["planner_failed"] and not info["collided"]


@pytest.mark.parametrize("robot", ["movo", "panda"])
def test_rgb_array_shows_the_scene_and_the_liquid(robot: str) -> None:
    env = RobotPourEnv(robot=robot, liquid="water", render_mode="rgb_array")
    env.reset(seed=0, options={"target_g": 100.0})
    img = env.render()
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    assert img.std() > 20  # a scene, not a blank frame
    env.solver.clear_world(0)  # the same scene without its liquid
    env.solver.step(0)
    changed = np.abs(img.astype(int) - env.render().astype(int)).sum(-1) > 30
    assert changed.sum() > 200  # the particles (in the cup, behind its translucent wall)
    env.close()
    assert RobotPourEnv(robot=robot).render() is None  # render_mode None draws nothing


def test_gravity_compensation_removes_the_gripper_whatever_its_orientation() -> None:
    rng = np.random.default_rng(0)
    rot = np.linalg.qr(rng.normal(size=(4, 3, 3)))[0]
    rot *= np.linalg.det(rot)[:, None, None]  # proper rotations
    load = 0.3  # kg held below the gripper
    up = np.einsum("nji,j->ni", rot, [0.0, 0.0, 1.0])  # world up in the sensor frame
    force = (GRIPPER_MASS + load) * GRAVITY * up
    comp, _ = gravity_compensate(force, np.zeros((4, 3)), rot)
    np.testing.assert_allclose(vertical_load(comp, rot), load * GRAVITY, atol=1e-9)


def test_movo_left_wrist_reads_the_tray_and_not_the_gripper() -> None:
    """At reset the compensated left-wrist force is the empty tray's weight (0.2 kg), not
    gripper + tray: the gripper's 1.435 kg is compensated."""
    env = RobotPourEnv(robot="movo", liquid="water")
    _, info = env.reset(seed=0, options={"target_g": 100.0})
    assert env.force_n == pytest.approx(0.2 * GRAVITY, abs=0.02)
    assert info["measured_g"] == 0.0


def test_movo_right_wrist_feels_the_cup_and_its_liquid() -> None:
    """The liquid's reaction on the cup enters MuJoCo: after 2 s at rest the right wrist's
    compensated load is the cup (90 g) plus the liquid in it."""
    env = RobotPourEnv(robot="movo", liquid="water")
    env.reset(seed=0, options={"target_g": 100.0})
    assert env.pouring_wrist_g() == pytest.approx(90.0, abs=0.1)  # no liquid force yet
    for _ in range(20):
        env.step(np.zeros(2))
    assert env.pouring_wrist_g() == pytest.approx(90.0 + env.initial_g, abs=3.0)
    with pytest.raises(InvalidParameterError, match="'panda' has no wrist"):
        RobotPourEnv(robot="panda").pouring_wrist_g()


def _pd_pour(robot: str, planner: str, seed: int, target: float) -> dict:
    env = RobotPourEnv(robot=robot, planner=planner, liquid="water")
    obs, info = env.reset(seed=seed, options={"target_g": target})
    pd = PDPourer(1)
    for _ in range(env.config.max_steps):
        obs, _, term, trunc, info = env.step(pd.act(obs))
        if term or trunc:
            break
    return {**info, "terminated": term, "truncated": trunc}


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["movo", "panda"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pd_baseline_pours_100_g_of_water_within_10_g(robot: str, seed: int) -> None:
    """The PD baseline pours 100 g of water with the robot in the loop within 10 g."""
    out = _pd_pour(robot, "nmpc", seed, 100.0)
    assert out["terminated"] and not out["truncated"]
    assert not out["collided"] and not out["planner_failed"] and not out["sim_diverged"]
    assert out["error_g"] <= 10.0, out


@pytest.mark.slow
@pytest.mark.parametrize("grams", [50.0, 150.0])
def test_left_wrist_reads_settled_liquid_in_the_tray_within_2_g(grams: float) -> None:
    """Liquid placed in the tray held by the Movo's left hand settles for 3 s with the robot
    still; the filtered, gravity-compensated, tared wrist reading (averaged over the last
    second's ten observations) is the liquid's mass within 2 g."""
    env = RobotPourEnv(robot="movo", liquid="water")
    env.reset(seed=0, options={"target_g": 100.0})
    n = env.solver.fill(0, env.recv_col, grams)
    mass = n * env.particle_g
    env.solver.step(0)
    readings = []
    for _ in range(40):
        obs, _, term, trunc, info = env.step(np.zeros(2))  # nothing moves
        assert not (term or trunc)
        readings.append(obs[7])
    inside = info["poured_g"]
    assert inside == pytest.approx(mass, abs=1.0)  # settled in the tray
    assert np.mean(readings[-10:]) == pytest.approx(inside, abs=2.0)


def test_a_robot_pour_is_recorded_for_rerun(tmp_path) -> None:
    """``record_path``: a frame per reset and step of the particles, every robot geom's pose,
    the end-effector's target and pose, the arm's actual (and, per step, commanded) joint
    velocities and the weight raw and filtered; moved into place on close."""
    from collections import Counter

    from rerun.chunk import RrdReader

    path = tmp_path / "robot.rrd"
    env = RobotPourEnv(robot="movo", liquid="water", record_path=str(path))
    env.reset(seed=0, options={"target_g": 100.0})
    for _ in range(3):
        env.step(np.array([1.0, 0.0]))
    geoms = len(env._recorder.geoms)
    joints = env.kin.joint_names
    env.close()
    assert not path.with_name("robot.rrd.partial").exists()
    frames: Counter = Counter()
    for chunk in RrdReader(path).stream():
        if not chunk.is_static:
            frames[chunk.entity_path] += chunk.num_rows
    for entity in ("world/liquid", "world/ee/target", "world/ee/actual", "plots/weight_g/raw"):
        assert frames["/" + entity] == 4, entity
    assert frames["/plots/weight_g/filtered"] == 4
    assert frames[f"/plots/joint_velocity/{joints[0]}/actual"] == 4
    assert frames[f"/plots/joint_velocity/{joints[0]}/commanded"] == 3
    moved = [e for e in frames if e.startswith("/world/robot/")]
    assert geoms > 20 and len(moved) == geoms and all(frames[e] == 4 for e in moved)


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        ({"control_hz": 200.0}, "above the liquid solver's rate"),
        ({"control_hz": 50.0}, "near"),
        ({"target_range_g": (50.0, 400.0)}, "more than the pouring container 'training'"),
    ],
)
def test_settings_a_reset_could_not_run_are_refused(bad: dict, match: str) -> None:
    """PourRobot-v0 takes the control rates and amounts Pour-v0 takes: whole numbers of
    solver steps, and targets its container holds (so no drawn reset can be refused)."""
    with pytest.raises(ValueError, match=match):
        RobotPourEnv(**bad)
    assert RobotPourEnv(control_hz=20.0).metadata["render_fps"] == 20.0
