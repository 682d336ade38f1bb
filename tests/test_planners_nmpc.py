"""NMPC-MP: analytic gradients, convergence, warm start, limits, clearance and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from planner_arms import CAPSULES, JOINTS, arm7_model, central_differences

from pourbench.planners._threads import limit_blas_threads
from pourbench.planners.distance import Box, Capsule, Sphere, capsule_obstacle_distances
from pourbench.planners.kinematics import ArmKinematics
from pourbench.planners.nmpc import NMPCConfig, NMPCPlanner
from pourbench.planners.rollout import rotation_error, run_to_goal

limit_blas_threads(1)


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
