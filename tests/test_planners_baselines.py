"""Real robots, the MuJoCo planning world, mink, OMPL, STOMP and CHOMP."""

from __future__ import annotations

import numpy as np
import pytest
from planner_arms import CAPSULES, JOINTS, arm7_model, arm7_xml, central_differences

from pourbench.planners._threads import limit_blas_threads
from pourbench.planners.baselines.chomp import plan_chomp
from pourbench.planners.baselines.common import densify
from pourbench.planners.baselines.ompl_planners import plan_ompl
from pourbench.planners.baselines.stomp import plan_stomp
from pourbench.planners.distance import Box, capsule_obstacle_distances
from pourbench.planners.kinematics import ArmKinematics
from pourbench.planners.mink_controller import MinkController
from pourbench.planners.nmpc import NMPCConfig, NMPCPlanner
from pourbench.planners.robots import (
    arm_kinematics,
    arm_spec,
    geom_obstacles,
    joint_speed_limits,
    robot_mjspec,
)
from pourbench.planners.rollout import run_to_goal
from pourbench.planners.world import PlanningWorld

limit_blas_threads(1)


def test_unknown_robot_raises_value_error():
    with pytest.raises(ValueError, match="unknown robot"):
        arm_spec("ur5")
    with pytest.raises(ValueError):
        arm_kinematics("kuka")


@pytest.mark.parametrize("name", ["movo", "panda"])
def test_real_robot_gradients_match_finite_differences(name):
    """Cost gradient and signed-distance Jacobian on the shipped MJCF robots (the Movo's body
    boxes and other arm, and a box, as obstacles), relative error < 1e-4."""
    spec = arm_spec(name)
    kin = arm_kinematics(name)
    rng = np.random.default_rng(7)
    p0, x0 = kin.ee_pose(kin.home())
    obs = [Box(p0 + np.array([0.1, -0.15, 0.0]), [0.08, 0.05, 0.1])]
    obs += geom_obstacles(kin, spec.body_boxes + spec.other_capsules)
    planner = NMPCPlanner(kin, NMPCConfig(ph=4, ch=2))
    q0 = kin.home() + rng.normal(0, 0.2, kin.n)
    U = rng.normal(0, 0.3, planner.nU)
    goal = p0 + np.array([0.05, -0.2, 0.1])
    _, grad, _, dsd = planner.cost_and_constraints(q0, goal, x0, obs, U)
    g_fd, d_fd = central_differences(planner, q0, goal, x0, obs, U)
    assert np.linalg.norm(grad - g_fd) / np.linalg.norm(g_fd) < 1e-4
    moving = np.linalg.norm(d_fd, axis=1) > 1e-8
    rel = np.linalg.norm(dsd - d_fd, axis=1)[moving] / np.linalg.norm(d_fd, axis=1)[moving]
    assert moving.sum() >= 4
    assert rel.max() < 1e-4


def test_world_clearance_matches_analytic_distances():
    """MuJoCo's mj_geomDistance (world) and our capsule distances agree on the Movo."""
    spec = arm_spec("movo")
    kin = arm_kinematics("movo")
    p0 = kin.ee_pose(kin.home())[0]
    box = Box(p0 + np.array([0.0, -0.25, 0.0]), [0.1, 0.05, 0.1])
    statics = spec.body_boxes + spec.other_capsules
    world = PlanningWorld(robot_mjspec(spec), spec.capsules, [box], statics)
    obs = [box, *geom_obstacles(kin, statics)]
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = kin.home() + rng.normal(0, 0.3, kin.n)
        st = kin.forward(q)
        ours = capsule_obstacle_distances(st.seg_a, st.seg_b, st.radius, obs).sd.min()
        assert world.clearance(kin.full_qpos(q)) == pytest.approx(ours, abs=1e-5)


def test_panda_never_leaves_joint_limits():
    """NMPC-MP on the Panda towards the pose of a configuration next to the limits of joints
    4 and 6: every configuration stays inside the limits while a limit is pressed."""
    kin = arm_kinematics("panda")
    q0 = kin.home()
    vmax = joint_speed_limits(kin.model, arm_spec("panda").joints, 1.0)
    planner = NMPCPlanner(kin, NMPCConfig(max_joint_speed=tuple(vmax)))
    goal_pos, goal_quat = kin.ee_pose(np.array([0.3, 0.6, -0.2, -0.12, 0.1, 3.65, 0.5]))
    run = run_to_goal(planner, kin, q0, goal_pos, goal_quat, ts=0.2, max_steps=120)
    gap = np.minimum(run.qs - kin.lower, kin.upper - run.qs)
    assert gap.min() >= -1e-9  # never outside
    assert gap.min() <= planner.config.joint_limit_margin + 1e-3  # a limit was pressed


def _arm7_world(obstacles):
    import mujoco

    spec = mujoco.MjSpec.from_string(arm7_xml())
    return PlanningWorld(spec, CAPSULES, obstacles)


def test_mink_controller_reaches_goal_and_keeps_clearance():
    kin = ArmKinematics(arm7_model(), JOINTS, "ee", CAPSULES)
    q0 = kin.home()
    goal_pos, goal_quat = kin.ee_pose(q0 + np.array([0.6, 0.3, 0.0, 0.3, 0.0, -0.3, 0.2]))
    box = Box([0.35, 0.35, 0.7], [0.05, 0.05, 0.05])
    world = _arm7_world([box])
    ctrl = MinkController(world, JOINTS, "ee", CAPSULES, ts=0.2, safety_distance=0.03,
                          max_joint_speed=np.full(7, 0.6))  # fmt: skip
    run = run_to_goal(ctrl, kin, q0, goal_pos, goal_quat, ts=0.2, max_steps=100,
                      pos_tol=0.01, rot_tol=0.05, obstacles=[box])  # fmt: skip
    assert run.success
    clear = [world.clearance(kin.full_qpos(q)) for q in run.qs]
    assert min(clear) > 0.0
    assert np.all(np.abs(run.us) <= 0.6 * 1.001)  # mink's QP meets the bound to ~1e-5


@pytest.fixture(scope="module")
def blocked():
    """arm7 with a box that the straight joint-space path from home to the goal hits."""
    kin = ArmKinematics(arm7_model(), JOINTS, "ee", CAPSULES)
    q0 = kin.home() + np.array([0.0, 0.7, 0.0, 0.6, 0.0, -0.3, 0.0])  # leaning forward
    q_goal = q0 + np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    mid = kin.forward(q0 + 0.5 * (q_goal - q0))
    center = 0.5 * (mid.seg_a[0, 1] + mid.seg_b[0, 1])  # middle of the forearm capsule
    box = Box(center, [0.06, 0.06, 0.06])
    return kin, q0, q_goal, box


def _dense_clearance(world, kin, path):
    return min(world.clearance(kin.full_qpos(q)) for q in densify(path, 0.01))


def test_ompl_rrtconnect_path_is_valid(blocked):
    kin, q0, q_goal, box = blocked
    world = _arm7_world([box])
    assert _dense_clearance(world, kin, np.array([q0, q_goal])) < 0.0  # straight line collides
    plan = plan_ompl(world, kin, q0, q_goal, "rrtconnect", safety_distance=0.02, time_limit=5)
    assert plan.success
    np.testing.assert_allclose(plan.path[0], q0)
    np.testing.assert_allclose(plan.path[-1], q_goal, atol=1e-9)
    # OMPL checks motions at its resolution; densely we allow 5 mm below the safety distance.
    assert _dense_clearance(world, kin, plan.path) > 0.02 - 0.005


@pytest.mark.parametrize("planner", ["stomp", "chomp"])
def test_stomp_and_chomp_find_collision_free_paths(blocked, planner):
    kin, q0, q_goal, box = blocked
    world = _arm7_world([box])
    if planner == "stomp":
        plan = plan_stomp(kin, [box], q0, q_goal, safety_distance=0.02, seed=3)
    else:
        plan = plan_chomp(kin, [box], q0, q_goal, safety_distance=0.02)
    assert plan.success, plan.reason
    np.testing.assert_allclose(plan.path[0], q0)
    np.testing.assert_allclose(plan.path[-1], q_goal)
    assert _dense_clearance(world, kin, plan.path) >= 0.02 - 1e-6  # checked by MuJoCo
