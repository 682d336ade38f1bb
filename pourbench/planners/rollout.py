"""Closed-loop execution of an online planner (NMPC-MP or the mink controller).

The robot follows ``q⁺ = q + u·t_s`` exactly (the planners' own model): each control period
the planner is called once and its first input is applied for ``t_s`` seconds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pourbench.errors import (
    InvalidParameterError,
    check_array,
    check_finite,
    check_int,
    check_positive,
    check_quat,
)
from pourbench.geometry.rotation import rotation_error
from pourbench.planners.distance import Obstacle
from pourbench.planners.kinematics import ArmKinematics


class OnlinePlanner(Protocol):
    """Anything with ``plan(q, goal_pos, goal_quat, obstacles)`` returning ``.u``,
    ``.solve_time_s`` and ``.iterations``."""

    def plan(self, q0, goal_pos, goal_quat, obstacles=()): ...


@dataclass
class Rollout:
    """A closed-loop run towards one goal.

    Attributes:
        qs: joint positions at every control step, (T + 1, n) in rad.
        ee: end-effector positions, (T + 1, 3) in m.
        quat: end-effector quaternions, (T + 1, 4).
        us: applied inputs, (T, n) in rad/s.
        solve_times: planner wall time per call, (T,) in s.
        iterations: solver iterations per call, (T,).
        success: reached within the tolerances before ``max_steps``.
        reason: ``"reached"`` or ``"goal not reached within max_steps"``.
        pos_error: final position error (m).
        rot_error: final rotation error (rad).
    """

    qs: np.ndarray
    ee: np.ndarray
    quat: np.ndarray
    us: np.ndarray
    solve_times: np.ndarray
    iterations: np.ndarray
    success: bool
    reason: str
    pos_error: float
    rot_error: float


def run_to_goal(
    planner: OnlinePlanner,
    kin: ArmKinematics,
    q0: np.ndarray,
    goal_pos: np.ndarray,
    goal_quat: np.ndarray,
    *,
    ts: float,
    max_steps: int,
    pos_tol: float = 1e-3,
    rot_tol: float = 1e-2,
    obstacles: Sequence[Obstacle] | Callable[[int], Sequence[Obstacle]] = (),
    stop_at_goal: bool = True,
    on_step: Callable[[int, np.ndarray], None] | None = None,
) -> Rollout:
    """Run ``planner`` in closed loop until the goal pose is reached or ``max_steps`` pass.

    Args:
        kin: the arm's kinematics (for the measured end-effector pose).
        q0: start configuration (n,) in rad.
        goal_pos: goal position (3,) in m.
        goal_quat: goal orientation (w, x, y, z).
        ts: control period (s).
        max_steps: control steps allowed.
        pos_tol: position tolerance (m).
        rot_tol: rotation tolerance (rad).
        obstacles: a fixed list, or a function of the step index (moving obstacles).
        stop_at_goal: stop as soon as the goal is reached (else run all ``max_steps``).
        on_step: called with (step, q) after every step (e.g. clearance checks).

    Returns:
        A :class:`Rollout`; an unreachable goal gives ``success=False``, not an exception.

    Raises:
        InvalidParameterError: ``q0``, the goal, ``ts``, ``max_steps`` or a tolerance is bad
            (NaN, wrong shape, zero quaternion, ``ts`` ≤ 0 or not the planner's own period).
    """
    q = check_array("q0", q0, (kin.n,)).copy()
    goal_pos = check_array("goal_pos", goal_pos, (3,))
    goal_quat = check_quat("goal_quat", goal_quat)
    goal_quat = goal_quat / np.linalg.norm(goal_quat)
    ts = check_positive("ts", ts)
    own = getattr(getattr(planner, "config", None), "ts", getattr(planner, "ts", None))
    if isinstance(own, int | float) and not np.isclose(ts, own, rtol=1e-9, atol=0.0):
        raise InvalidParameterError(f"ts {ts!r} differs from the planner's control period {own!r}")
    check_int("max_steps", max_steps, minimum=0)
    check_finite("pos_tol", pos_tol, minimum=0.0)
    check_finite("rot_tol", rot_tol, minimum=0.0)
    qs, ee, quats, us, times, iters = [q.copy()], [], [], [], [], []
    p, xi = kin.ee_pose(q)
    ee.append(p)
    quats.append(xi)
    reached = False
    for step in range(max_steps):
        if np.linalg.norm(p - goal_pos) <= pos_tol and rotation_error(xi, goal_quat) <= rot_tol:
            reached = True
            if stop_at_goal:
                break
        obs = obstacles(step) if callable(obstacles) else obstacles
        res = planner.plan(q, goal_pos, goal_quat, obs)
        q = q + np.asarray(res.u) * ts
        p, xi = kin.ee_pose(q)
        qs.append(q.copy())
        ee.append(p)
        quats.append(xi)
        us.append(np.asarray(res.u, dtype=float).copy())
        times.append(res.solve_time_s)
        iters.append(res.iterations)
        if on_step is not None:
            on_step(step, q)
    pos_err = float(np.linalg.norm(p - goal_pos))
    rot_err = rotation_error(xi, goal_quat)
    success = reached or (pos_err <= pos_tol and rot_err <= rot_tol)  # at goal now or before
    return Rollout(
        qs=np.array(qs),
        ee=np.array(ee),
        quat=np.array(quats),
        us=np.array(us) if us else np.zeros((0, len(q))),
        solve_times=np.array(times),
        iterations=np.array(iters, dtype=int),
        success=success,
        reason="reached" if success else "goal not reached within max_steps",
        pos_error=pos_err,
        rot_error=rot_err,
    )
