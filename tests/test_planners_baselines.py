"""Real robots, the MuJoCo planning world, mink, OMPL, STOMP and CHOMP."""

from __future__ import annotations

import numpy as np
import pytest
from planner_arms import CAPSULES, JOINTS, arm7_model, arm7_xml, central_differences

from pourbench.planners.baselines.chomp import ChompConfig, plan_chomp
from pourbench.planners.baselines.common import densify
from pourbench.planners.baselines.ompl_planners import plan_ompl
from pourbench.planners.baselines.stomp import StompConfig, plan_stomp
from pourbench.planners.distance import Box, Capsule, Sphere, capsule_obstacle_distances
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


def test_unknown_robot_raises_value_error():
    with pytest.raises(ValueError, match="unknown robot"):
        arm_spec("ur5")
    with pytest.raises(ValueError, match="unknown robot"):
        arm_spec(["panda"])  # type: ignore[arg-type]
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


def test_ompl_same_seed_same_path_in_one_process(blocked, capfd):
    """The seed applies to every call, not only the process's first; reseeding logs nothing."""
    kin, q0, q_goal, box = blocked
    world = _arm7_world([box])
    args = (world, kin, q0, q_goal, "rrtconnect")
    a = plan_ompl(*args, safety_distance=0.02, time_limit=5, seed=0)
    other = plan_ompl(*args, safety_distance=0.02, time_limit=5, seed=7)
    b = plan_ompl(*args, safety_distance=0.02, time_limit=5, seed=0)
    assert a.success and b.success and other.success
    assert a.path.shape == b.path.shape and np.array_equal(a.path, b.path), (
        "same seed, different paths"
    )
    assert "Random number generation already started" not in capfd.readouterr().err


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


# ------------------------------------------------------------------------- bad input
_BOX = Box([0.35, 0.35, 0.7], [0.05, 0.05, 0.05])
_SPEED = np.full(7, 0.6)


@pytest.fixture(scope="module")
def mink_setup():
    kin = ArmKinematics(arm7_model(), JOINTS, "ee", CAPSULES)
    world = _arm7_world([_BOX])
    ctrl = MinkController(world, JOINTS, "ee", CAPSULES, ts=0.2, safety_distance=0.03,
                          max_joint_speed=_SPEED)  # fmt: skip
    goal = kin.ee_pose(kin.home() + np.array([0.6, 0.3, 0.0, 0.3, 0.0, -0.3, 0.2]))
    return kin, world, ctrl, goal


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"max_joint_speed": np.nan}, r"max_joint_speed must be finite and > 0, got nan"),
        ({"max_joint_speed": np.full(3, 0.6)}, r"max_joint_speed must be one number or 7"),
        ({"substeps": -2}, r"substeps must be >= 1, got -2"),
        ({"substeps": 0}, r"substeps must be >= 1, got 0"),
        ({"substeps": 2.5}, r"substeps must be an integer, got 2.5"),
        ({"safety_distance": np.nan}, r"safety_distance must be finite, got nan"),
        ({"safety_distance": -1.0}, r"safety_distance must be >= 0.0, got -1.0"),
        ({"ts": 0.0}, r"ts must be > 0, got 0.0"),
        ({"ts": -0.2}, r"ts must be > 0, got -0.2"),
        ({"orientation_cost": -1.0}, r"orientation_cost must be >= 0.0, got -1.0"),
        ({"posture_cost": np.nan}, r"posture_cost must be finite, got nan"),
        ({"base_qpos": np.zeros(3)}, r"base_qpos must have shape \(7,\), got \(3,\)"),
        ({"base_qpos": np.full(7, np.nan)}, r"base_qpos must be finite"),
        ({"ee_site": "nope"}, r"unknown site 'nope'; known sites: arm_base, ee"),
        ({"robot_geoms": ("nope",)}, r"unknown geom 'nope'"),
        ({"joints": ("j1", "nope")}, r"unknown joint 'nope'"),
        ({"joints": ()}, r"joints must name at least one joint"),
    ],
)
def test_mink_controller_refuses_bad_settings(mink_setup, kwargs, match):
    world = mink_setup[1]
    args = {"joints": JOINTS, "ee_site": "ee", "robot_geoms": CAPSULES, "ts": 0.2,
            "safety_distance": 0.03, "max_joint_speed": _SPEED}  # fmt: skip
    args.update(kwargs)
    j, e, g = args.pop("joints"), args.pop("ee_site"), args.pop("robot_geoms")
    with pytest.raises(ValueError, match=match):
        MinkController(world, j, e, g, **args)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda c, q, g: c.plan(np.full(7, np.nan), *g, [_BOX]), r"q0 must be finite"),
        (lambda c, q, g: c.plan(q[:3], *g, [_BOX]), r"q0 must have shape \(7,\)"),
        (lambda c, q, g: c.plan(q, g[0], np.zeros(4), [_BOX]), r"goal_quat must not be zero"),
        (lambda c, q, g: c.plan(q, g[0], np.ones(3), [_BOX]), r"goal_quat must have shape"),
        (lambda c, q, g: c.plan(q, g[0][:2], g[1], [_BOX]), r"goal_pos must have shape"),
        (lambda c, q, g: c.plan(q, *g, ["x"]), r"obstacles\[0\] must be a Sphere, Box or"),
        (lambda c, q, g: c.plan(q, *g, [Sphere([0, 0, 0], 0.1)]), r"obstacles\[0\] must stay"),
        (lambda c, q, g: c.plan(q, *g, []), r"world has 1 obstacles, got 0"),
        (lambda c, q, g: c.solve_ik(q, [np.nan] * 3, g[1]), r"goal_pos must be finite"),
        (lambda c, q, g: c.solve_ik(np.full(7, np.nan), *g), r"q0 must be finite"),
        (lambda c, q, g: c.solve_ik(q, g[0], np.zeros(4)), r"goal_quat must not be zero"),
        (lambda c, q, g: c.solve_ik(q, *g, max_iters=2.5), r"max_iters must be an integer"),
        (lambda c, q, g: c.solve_ik(q, *g, dt=0.0), r"dt must be > 0, got 0.0"),
    ],
)
def test_mink_refuses_bad_goals_quickly_and_loses_nothing(mink_setup, call, match):
    """Refused at once (not after ~40 s of failing IK), and the next good call is unchanged."""
    kin, world, ctrl, goal = mink_setup
    q0 = kin.home()
    ref = ctrl.plan(q0, *goal, [_BOX]).u
    with pytest.raises(ValueError, match=match):
        call(ctrl, q0, goal)
    np.testing.assert_array_equal(world.data.mocap_pos[0], _BOX.center)
    np.testing.assert_array_equal(ctrl.plan(q0, *goal, [_BOX]).u, ref)


def test_world_refuses_bad_configurations_and_loses_nothing(mink_setup):
    kin, world, _, _ = mink_setup
    q = kin.full_qpos(kin.home())
    world.set_qpos(q)
    ref = world.clearance()
    assert ref == world.clearance(q)
    for bad in (np.full(7, np.nan), np.zeros(3)):
        with pytest.raises(ValueError, match=r"qpos must (be finite|have shape)"):
            world.clearance(bad)
        with pytest.raises(ValueError, match=r"qpos must (be finite|have shape)"):
            world.set_qpos(bad)
    for distmax, match in ((-1.0, r"distmax must be > 0, got -1.0"), (np.nan, r"finite")):
        with pytest.raises(ValueError, match=match):
            world.clearance(q, distmax=distmax)
    np.testing.assert_array_equal(world.data.qpos, q)
    assert world.clearance() == ref


def test_world_obstacles():
    """Non-obstacles are refused; a capsule with a == b becomes a sphere geom; a refused
    set_obstacles moves nothing."""
    with pytest.raises(ValueError, match=r"obstacles\[1\] must be a Sphere, Box or Capsule"):
        _arm7_world([_BOX, None])
    pt = [0.5, 0.0, 1.0]
    world = _arm7_world([Capsule(pt, pt, 0.05), _BOX])
    ref = _arm7_world([Sphere(pt, 0.05), _BOX])
    q = np.zeros(7)
    assert world.clearance(q) == pytest.approx(ref.clearance(q), abs=1e-12)
    before = world.data.mocap_pos.copy()
    moved = Capsule([0.0, 0.0, 2.0], [0.0, 0.0, 2.0], 0.05)
    with pytest.raises(ValueError, match=r"obstacles\[1\] must stay a Box"):
        world.set_obstacles([moved, Sphere(pt, 0.05)])
    np.testing.assert_array_equal(world.data.mocap_pos, before)
    # a new size would be ignored by the compiled geom (the clearance of the old one)
    bigger = Box(_BOX.center, 2.0 * np.asarray(_BOX.half_extents))
    with pytest.raises(ValueError, match=r"obstacles\[1\] must keep its size"):
        world.set_obstacles([moved, bigger])
    np.testing.assert_array_equal(world.data.mocap_pos, before)
    world.set_obstacles([moved, _BOX])  # same sizes, a new pose: taken
    np.testing.assert_allclose(world.data.mocap_pos[world.mocap_ids[0]], [0.0, 0.0, 2.0])


_ENDPOINT_CASES = [
    ({"q_start": np.full(7, np.nan)}, r"q_start must be finite"),
    ({"q_goal": np.full(7, np.nan)}, r"q_goal must be finite"),
    ({"q_start": np.zeros(6), "q_goal": np.zeros(6)}, r"q_start must have shape \(7,\)"),
    ({"safety_distance": -1.0}, r"safety_distance must be >= 0.0, got -1.0"),
    ({"safety_distance": np.nan}, r"safety_distance must be finite, got nan"),
]
_OBSTACLE_CASE = ({"obstacles": [_BOX, "x"]}, r"obstacles\[1\] must be a Sphere, Box or Capsule")


@pytest.mark.parametrize(
    ("planner", "change", "match"),
    [(p, *case) for p in ("chomp", "stomp", "ompl") for case in _ENDPOINT_CASES]
    + [(p, *_OBSTACLE_CASE) for p in ("chomp", "stomp")],  # OMPL's obstacles are the world's
)
def test_offline_planners_refuse_bad_input(mink_setup, planner, change, match):
    kin, world, _, _ = mink_setup
    args = {"q_start": kin.home(), "q_goal": kin.home() + 0.3, "safety_distance": 0.02,
            "obstacles": [_BOX]}  # fmt: skip
    args.update(change)
    obs, qs, qg = args.pop("obstacles"), args.pop("q_start"), args.pop("q_goal")
    with pytest.raises(ValueError, match=match):
        if planner == "chomp":
            plan_chomp(kin, obs, qs, qg, **args)
        elif planner == "stomp":
            plan_stomp(kin, obs, qs, qg, **args)
        else:
            plan_ompl(world, kin, qs, qg, time_limit=0.1, **args)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"resolution": 0.0}, r"resolution must be > 0, got 0.0"),
        ({"resolution": -1.0}, r"resolution must be > 0, got -1.0"),
        ({"resolution": np.nan}, r"resolution must be finite, got nan"),
        ({"resolution": 1.0}, r"resolution must be in \(0, 1\), got 1.0"),
        ({"span": -5.0}, r"span must be > 0, got -5.0"),
        ({"span": np.nan}, r"span must be finite, got nan"),
        ({"time_limit": np.inf}, r"time_limit must be finite, got inf"),
        ({"time_limit": np.nan}, r"time_limit must be finite, got nan"),
        ({"time_limit": 0.0}, r"time_limit must be > 0, got 0.0"),
        ({"seed": -1}, r"seed must be >= 0, got -1"),
    ],
)
def test_ompl_refuses_bad_settings(mink_setup, kwargs, match):
    kin, world, _, _ = mink_setup
    with pytest.raises(ValueError, match=match):
        plan_ompl(world, kin, kin.home(), kin.home() + 0.3, safety_distance=0.02, **kwargs)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: ChompConfig(waypoints=2), r"waypoints must be >= 3, got 2"),
        (lambda: ChompConfig(max_iters=np.nan), r"max_iters must be an integer, got nan"),
        (lambda: ChompConfig(eta=0.0), r"eta must be > 0, got 0.0"),
        (lambda: ChompConfig(obstacle_weight=np.nan), r"obstacle_weight must be finite"),
        (lambda: ChompConfig(epsilon=0.0), r"epsilon must be > 0, got 0.0"),
        (lambda: ChompConfig(max_step=-0.1), r"max_step must be > 0, got -0.1"),
        (lambda: StompConfig(waypoints=2), r"waypoints must be >= 3, got 2"),
        (lambda: StompConfig(rollouts=0), r"rollouts must be >= 1, got 0"),
        (lambda: StompConfig(rollouts=1.5), r"rollouts must be an integer, got 1.5"),
        (lambda: StompConfig(max_iters=np.nan), r"max_iters must be an integer, got nan"),
        (lambda: StompConfig(noise_std=np.nan), r"noise_std must be finite, got nan"),
        (lambda: StompConfig(h=-1.0), r"h must be >= 0.0, got -1.0"),
        (lambda: densify(np.zeros((2, 7)), 0.0), r"max_step must be > 0, got 0.0"),
        (lambda: densify(np.zeros((2, 7)), -1.0), r"max_step must be > 0, got -1.0"),
        (lambda: densify(np.zeros((0, 7)), 0.1), r"path must have at least one waypoint"),
        (lambda: densify(np.full((2, 7), np.nan), 0.1), r"path must be finite"),
    ],
)
def test_offline_settings_are_refused(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_stomp_seeds(mink_setup):
    """An integer >= 0, None or a Generator, as numpy takes; a fractional seed is refused."""
    kin = mink_setup[0]
    args = (kin, [_BOX], kin.home(), kin.home() + 0.3)
    cfg = StompConfig(max_iters=2)
    with pytest.raises(ValueError, match=r"seed must be an integer, got 1.5"):
        plan_stomp(*args, safety_distance=0.02, seed=1.5)
    by_int = plan_stomp(*args, safety_distance=0.02, config=cfg, seed=4)
    by_gen = plan_stomp(*args, safety_distance=0.02, config=cfg, seed=np.random.default_rng(4))
    np.testing.assert_array_equal(by_int.path, by_gen.path)
    assert plan_stomp(*args, safety_distance=0.02, config=cfg, seed=None).path.shape[1] == 7


def test_planning_world_refuses_zero_radius_obstacles():
    with pytest.raises(ValueError, match=r"needs a radius > 0"):
        _arm7_world([Sphere([0.5, 0.0, 1.0], 0.0)])
