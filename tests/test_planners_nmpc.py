"""NMPC-MP: analytic gradients, convergence, warm start, limits, clearance and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from planner_arms import CAPSULES, JOINTS, arm7_model, central_differences

from pourbench.geometry.rotation import rotation_error
from pourbench.planners.distance import Box, Capsule, Sphere, capsule_obstacle_distances
from pourbench.planners.kinematics import ArmKinematics
from pourbench.planners.nmpc import NMPCConfig, NMPCPlanner
from pourbench.planners.rollout import run_to_goal


@pytest.fixture(scope="module")
def kin() -> ArmKinematics:
    return ArmKinematics(arm7_model(limited=False), JOINTS, "ee", CAPSULES)


@pytest.fixture(scope="module")
def kin_limited() -> ArmKinematics:
    return ArmKinematics(arm7_model(limited=True), JOINTS, "ee", CAPSULES)


def _obstacles():
    return [
        Sphere([0.35, 0.25, 0.95], 0.08),
        Box([0.45, -0.35, 0.7], [0.1, 0.12, 0.2], np.eye(3)),
        Capsule([0.3, 0.45, 0.4], [0.45, 0.3, 1.0], 0.05),  # e.g. another arm's link
    ]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gradients_match_finite_differences(kin, seed):
    """∇f and ∂sd/∂U (Eq. 4.56, 4.60–4.61) against central differences, relative < 1e-4."""
    rng = np.random.default_rng(seed)
    planner = NMPCPlanner(kin, NMPCConfig(ph=8, ch=4))
    q0 = kin.home() + rng.normal(0, 0.4, kin.n)
    U = rng.normal(0, 0.4, planner.nU)
    goal_pos = rng.normal([0.4, 0.0, 0.9], 0.15)
    goal_quat = rng.normal(size=4)
    obs = _obstacles()
    _, grad, sd, dsd = planner.cost_and_constraints(q0, goal_pos, goal_quat, obs, U)
    grad_fd, dsd_fd = central_differences(planner, q0, goal_pos, goal_quat, obs, U)
    assert np.linalg.norm(grad - grad_fd) / np.linalg.norm(grad_fd) < 1e-4
    assert sd.size == 8 * 3 * 3
    moving = np.linalg.norm(dsd_fd, axis=1) > 1e-8
    rel = np.linalg.norm(dsd - dsd_fd, axis=1)[moving] / np.linalg.norm(dsd_fd, axis=1)[moving]
    assert moving.sum() > 30
    assert np.max(rel) < 1e-4


@pytest.mark.parametrize("hessian", ["gauss_newton", pytest.param("bfgs", marks=pytest.mark.slow)])
def test_free_space_converges_to_reachable_pose(kin, hessian):
    """Closed loop in free space reaches a reachable goal within 1 mm and 0.01 rad."""
    q0 = kin.home()
    goal_pos, goal_quat = kin.ee_pose(q0 + np.array([0.5, -0.3, 0.2, -0.4, 0.3, 0.4, 0.5]))
    assert np.linalg.norm(goal_pos - kin.ee_pose(q0)[0]) > 0.25
    planner = NMPCPlanner(kin, NMPCConfig(hessian=hessian))
    run = run_to_goal(planner, kin, q0, goal_pos, goal_quat, ts=0.2, max_steps=400)
    assert run.success
    p, xi = kin.ee_pose(run.qs[-1])
    assert np.linalg.norm(p - goal_pos) <= 1e-3
    assert rotation_error(xi, goal_quat) <= 1e-2
    assert np.all(np.abs(run.us) <= planner.config.max_joint_speed + 1e-6)


def test_warm_start_cuts_sqp_iterations(kin):
    """Along one closed-loop run, the shifted warm start needs fewer SQP iterations than a
    cold start (U = 0) solving the very same problems."""
    q = kin.home()
    goal_pos, goal_quat = kin.ee_pose(q + np.array([0.9, -0.4, 0.3, -0.5, 0.3, 0.5, 0.4]))
    obs = [Box([0.3, 0.0, 1.25], [0.08, 0.3, 0.05])]
    warm = NMPCPlanner(kin, NMPCConfig(warm_start=True))
    cold = NMPCPlanner(kin, NMPCConfig(warm_start=False))
    it_warm, it_cold = [], []
    for _ in range(25):
        rw = warm.plan(q, goal_pos, goal_quat, obs)
        rc = cold.plan(q, goal_pos, goal_quat, obs)
        it_warm.append(rw.iterations)
        it_cold.append(rc.iterations)
        q = q + rw.u * warm.config.ts
    assert np.mean(it_warm[1:]) < np.mean(it_cold[1:])


def test_joint_limits_hold(kin_limited):
    """With position limits, every executed and predicted configuration stays inside them."""
    kin = kin_limited
    q0 = kin.home()
    # A goal that pulls joints 4 and 2 against their limits (q4 ≤ −0.1, |q2| ≤ 2.8).
    goal_pos = kin.ee_pose(q0)[0] + np.array([0.0, 0.0, 0.6])  # straight up: needs q4 → 0
    goal_quat = kin.ee_pose(q0)[1]
    planner = NMPCPlanner(kin, NMPCConfig())
    preds = []

    class Spy:
        def plan(self, *a):
            r = planner.plan(*a)
            preds.append(r.q_pred)
            return r

    run = run_to_goal(Spy(), kin, q0, goal_pos, goal_quat, ts=0.2, max_steps=60)
    qs = np.vstack([run.qs, *preds])
    assert np.all(qs >= kin.lower - 1e-9) and np.all(qs <= kin.upper + 1e-9)
    # The limit is binding: joint 4 ends close to its upper limit −0.1 rad.
    assert run.qs[-1, 3] > -0.1 - 0.05


def test_moving_sphere_clearance(kin):
    """A sphere crossing the path and passing through the goal (task iv on a small arm):
    true clearance, checked at 10 sub-steps per control step, never drops more than 5 mm
    below the safety distance, and nothing collides."""
    q0 = kin.home()
    goal_pos, goal_quat = kin.ee_pose(q0 + np.array([1.2, 0.6, 0.0, 0.3, 0.0, -0.2, 0.0]))
    start = kin.ee_pose(q0)[0]
    safety = 0.05
    v = np.array([0.0, 0.12, 0.0])  # m/s
    c0 = goal_pos - v * 4.0  # reaches the goal after 4 s
    sphere = lambda step: Sphere(c0 + v * 0.2 * step, 0.06, velocity=v)  # noqa: E731
    planner = NMPCPlanner(kin, NMPCConfig(safety_distance=safety))
    clear = []

    def check(step, q):
        q_prev = check.q
        for s in np.linspace(0.0, 1.0, 11)[1:]:
            qi = q_prev + s * (q - q_prev)
            st = kin.forward(qi)
            ob = Sphere(c0 + v * 0.2 * (step + s), 0.06)
            clear.append(capsule_obstacle_distances(st.seg_a, st.seg_b, st.radius, [ob]).sd.min())
        check.q = q.copy()

    check.q = q0.copy()
    run = run_to_goal(
        planner, kin, q0, goal_pos, goal_quat, ts=0.2, max_steps=100,
        obstacles=lambda k: [sphere(k)], stop_at_goal=False, on_step=check, pos_tol=0.01,
    )  # fmt: skip
    clear = np.array(clear)
    assert np.linalg.norm(start - goal_pos) > 0.2
    assert clear.min() >= safety - 0.005
    assert np.all(clear > 0.0)
    # The sphere really interfered: at some time it was within 10 cm of the arm.
    assert clear.min() < safety + 0.05
    # Once the sphere has gone by, the arm gets to the goal.
    assert run.pos_error < 0.01


def test_unreachable_goal_is_a_failure_not_an_exception(kin):
    q0 = kin.home()
    planner = NMPCPlanner(kin, NMPCConfig(ph=10, ch=5))
    run = run_to_goal(
        planner, kin, q0, np.array([3.0, 0.0, 0.5]), np.array([1.0, 0, 0, 0]), ts=0.2,
        max_steps=15,
    )  # fmt: skip
    assert not run.success
    assert run.reason.startswith("goal not reached")
    assert run.pos_error > 1.5


def test_bad_input_raises_value_error(kin):
    planner = NMPCPlanner(kin)
    q0 = kin.home()
    with pytest.raises(ValueError):
        planner.plan(q0, np.array([np.nan, 0.0, 0.5]), np.array([1.0, 0, 0, 0]))
    with pytest.raises(ValueError):
        planner.plan(q0, np.array([0.3, 0.0, 0.5]), np.array([np.nan, 0, 0, 0]))
    with pytest.raises(ValueError):
        planner.plan(q0[:3], np.array([0.3, 0.0, 0.5]), np.array([1.0, 0, 0, 0]))
    with pytest.raises(ValueError):
        NMPCConfig(ph=5, ch=6)
    with pytest.raises(ValueError):
        NMPCConfig(hessian="newton")
    with pytest.raises(ValueError):
        ArmKinematics(arm7_model(), ("j1", "nope"), "ee")


_GOAL = (np.array([0.3, 0.2, 0.8]), np.array([1.0, 0.0, 0.0, 0.0]))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"activation_distance": np.nan}, r"activation_distance must be finite, got nan"),
        ({"activation_distance": -1.0}, r"activation_distance must be >= 0.0, got -1.0"),
        ({"joint_limit_margin": np.nan}, r"joint_limit_margin must be finite, got nan"),
        ({"joint_limit_margin": -0.5}, r"joint_limit_margin must be >= 0.0, got -0.5"),
        ({"max_iter": np.nan}, r"max_iter must be an integer, got nan"),
        ({"max_iter": 2.5}, r"max_iter must be an integer, got 2.5"),
        ({"max_iter": np.inf}, r"max_iter must be an integer, got inf"),
        ({"max_iter": 0}, r"max_iter must be >= 1, got 0"),
        ({"ph": 2.5, "ch": 1}, r"ph must be an integer, got 2.5"),
        ({"ch": 2.5}, r"ch must be an integer, got 2.5"),
        ({"ph": True, "ch": True}, r"ph must be an integer, got True"),
        ({"restoration_iters": 2.5}, r"restoration_iters must be an integer, got 2.5"),
        ({"restoration_iters": -1}, r"restoration_iters must be >= 0, got -1"),
        ({"time_budget_s": np.nan}, r"time_budget_s must be finite, got nan"),
        ({"time_budget_s": -1.0}, r"time_budget_s must be > 0, got -1.0"),
        ({"step_tol": np.nan}, r"step_tol must be finite, got nan"),
        ({"merit_rtol": -1.0}, r"merit_rtol must be >= 0.0, got -1.0"),
        ({"restoration_tol": np.nan}, r"restoration_tol must be finite, got nan"),
        ({"safety_distance": -0.1}, r"safety_distance must be >= 0.0, got -0.1"),
        ({"ts": 0.0}, r"ts must be > 0, got 0.0"),
        ({"ts": "0.2"}, r"ts must be a number, got '0.2'"),
        ({"q_pos": np.nan}, r"q_pos must be finite, got nan"),
        ({"max_joint_speed": ()}, r"max_joint_speed must be a number or one per joint"),
        ({"max_joint_speed": np.inf}, r"max_joint_speed must be finite and > 0, got inf"),
        ({"warm_start": "no"}, r"warm_start must be True or False, got 'no'"),
    ],
)
def test_bad_config_is_refused_at_construction(kwargs, match):
    with pytest.raises(ValueError, match=match):
        NMPCConfig(**kwargs)


def test_one_speed_in_a_list_applies_to_every_joint(kin):
    one = NMPCPlanner(kin, NMPCConfig(max_joint_speed=[0.4]))
    every = NMPCPlanner(kin, NMPCConfig(max_joint_speed=0.4))
    q0 = kin.home()
    args = (q0, kin.ee_pose(q0)[0] + [0.2, 0.0, 0.0], kin.ee_pose(q0)[1])
    np.testing.assert_array_equal(one.plan(*args).u, every.plan(*args).u)


def test_config_that_does_not_fit_the_arm_is_refused(kin, kin_limited):
    with pytest.raises(
        ValueError,
        match=r"max_joint_speed must be one number or 7 \(one per joint\), got \(0.6, 0.6\)",
    ):
        NMPCPlanner(kin, NMPCConfig(max_joint_speed=(0.6, 0.6)))
    # 2 × 5.0 rad > the 5.6 rad range of j1: no configuration keeps the margin.
    with pytest.raises(ValueError, match=r"joint_limit_margin 5.0 is more than half the range"):
        NMPCPlanner(kin_limited, NMPCConfig(joint_limit_margin=5.0))
    NMPCPlanner(kin, NMPCConfig(joint_limit_margin=5.0))  # no limits: any margin fits
    NMPCPlanner(kin_limited, NMPCConfig(joint_limit_margin=1.4))  # j4's range is 2.9 rad


@pytest.mark.parametrize(
    ("q0", "goal_pos", "goal_quat", "obstacles", "match"),
    [
        (np.full(7, np.nan), *_GOAL, (), r"q0 must be finite"),
        (np.zeros(6), *_GOAL, (), r"q0 must have shape \(7,\)"),
        (None, [0.3, 0.0], _GOAL[1], (), r"goal_pos must have shape \(3,\)"),
        (None, _GOAL[0], np.zeros(4), (), r"goal_quat must not be zero"),
        (None, _GOAL[0], [np.nan] * 4, (), r"goal_quat must be finite"),
        (None, *_GOAL, [Sphere([0, 0, 2], 0.1), "x"], r"obstacles\[1\] must be a Sphere.*'x'"),
        (None, *_GOAL, Sphere([0, 0, 2], 0.1), r"obstacles must be a sequence of obstacles"),
    ],
)
def test_bad_plan_input_is_refused_and_loses_nothing(
    kin, q0, goal_pos, goal_quat, obstacles, match
):
    """A refused call leaves the warm start alone: the next plan equals an undisturbed one."""
    cfg = NMPCConfig(ph=6, ch=3, max_iter=3)
    good = (kin.home(), *_GOAL, [Sphere([0.3, 0.2, 1.0], 0.05)])
    ref, planner = NMPCPlanner(kin, cfg), NMPCPlanner(kin, cfg)
    ref.plan(*good)
    planner.plan(*good)
    with pytest.raises(ValueError, match=match):
        planner.plan(kin.home() if q0 is None else q0, goal_pos, goal_quat, obstacles)
    np.testing.assert_array_equal(planner.plan(*good).U, ref.plan(*good).U)


def test_cost_and_constraints_refuses_bad_goal(kin):
    planner = NMPCPlanner(kin, NMPCConfig(ph=4, ch=2))
    U = np.zeros(planner.nU)
    for quat in (np.zeros(4), [np.nan, 0, 0, 1]):
        with pytest.raises(ValueError, match=r"goal_quat must (not be zero|be finite)"):
            planner.cost_and_constraints(kin.home(), _GOAL[0], quat, [], U)
    with pytest.raises(ValueError, match=r"U must have shape \(14,\)"):
        planner.cost_and_constraints(kin.home(), *_GOAL, [], U[:3])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"goal_quat": [np.nan] * 4}, r"goal_quat must be finite"),
        ({"goal_quat": np.zeros(4)}, r"goal_quat must not be zero"),
        ({"goal_pos": [0.3, np.nan, 0.8]}, r"goal_pos must be finite"),
        ({"q0": np.zeros(6)}, r"q0 must have shape \(7,\), got \(6,\)"),
        ({"ts": 0.0}, r"ts must be > 0, got 0.0"),
        ({"ts": -0.2}, r"ts must be > 0, got -0.2"),
        ({"ts": np.nan}, r"ts must be finite, got nan"),
        ({"ts": 100.0}, r"ts 100.0 differs from the planner's control period 0.2"),
        ({"max_steps": 2.5}, r"max_steps must be an integer, got 2.5"),
        ({"pos_tol": np.nan}, r"pos_tol must be finite, got nan"),
        ({"rot_tol": -1.0}, r"rot_tol must be >= 0.0, got -1.0"),
    ],
)
def test_run_to_goal_refuses_bad_input(kin, kwargs, match):
    """A NaN or zero goal quaternion never counts as reached; ts must be the planner's."""
    planner = NMPCPlanner(kin, NMPCConfig(ph=4, ch=2, max_iter=2))
    args = {"q0": kin.home(), "goal_pos": _GOAL[0], "goal_quat": _GOAL[1], "ts": 0.2}
    args.update({"max_steps": 2, **kwargs})
    with pytest.raises(ValueError, match=match):
        run_to_goal(planner, kin, **args)
    assert planner._U_prev is None  # refused before the planner was called


def test_rotation_error_refuses_nan():
    with pytest.raises(ValueError, match=r"quaternions must be finite"):
        rotation_error(np.array([1.0, 0, 0, 0]), np.array([np.nan] * 4))
    assert rotation_error(np.array([1.0, 0, 0, 0]), np.array([0.0, 1, 0, 0])) == pytest.approx(
        np.pi
    )


def test_kinematics_refuses_bad_configurations_and_loses_nothing():
    kin = ArmKinematics(arm7_model(), JOINTS, "ee", CAPSULES)
    q = kin.home()
    before = kin.forward(q).ee_pos.copy()
    base = kin.base_qpos.copy()
    with pytest.raises(ValueError, match=r"base_qpos must have shape \(7,\), got \(3,\)"):
        kin.set_base_qpos(np.zeros(3))
    with pytest.raises(ValueError, match=r"base_qpos must be finite"):
        kin.set_base_qpos(np.full(7, np.nan))
    np.testing.assert_array_equal(kin.base_qpos, base)
    np.testing.assert_array_equal(kin.forward(q).ee_pos, before)
    with pytest.raises(ValueError, match=r"q must have shape \(7,\), got \(\)"):
        kin.forward(0.5)
    with pytest.raises(ValueError, match=r"q must have shape \(7,\), got \(3,\)"):
        kin.full_qpos(np.zeros(3))
    with pytest.raises(ValueError, match=r"base_qpos must be finite"):
        ArmKinematics(arm7_model(), JOINTS, "ee", CAPSULES, base_qpos=np.full(7, np.nan))
