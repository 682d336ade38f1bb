"""OMPL sampling planners (the real library): RRT-Connect, RRT and PRM* in joint space.

Validity of a state = MuJoCo ``mj_geomDistance`` clearance between the arm's collision geoms
and every obstacle geom of a :class:`~pourbench.planners.world.PlanningWorld` ≥ the same
safety distance NMPC-MP uses. Paths are returned as OMPL found them (no shortcutting), as in
the thesis' comparison.
"""

from __future__ import annotations

import time

import numpy as np

from pourbench.errors import InvalidParameterError, UnknownNameError, check_int, check_positive
from pourbench.planners.baselines.common import OfflinePlan, check_endpoints
from pourbench.planners.kinematics import ArmKinematics
from pourbench.planners.world import PlanningWorld

OMPL_PLANNERS: tuple[str, ...] = ("rrtconnect", "rrt", "prmstar")


def plan_ompl(
    world: PlanningWorld,
    kin: ArmKinematics,
    q_start: np.ndarray,
    q_goal: np.ndarray,
    planner: str = "rrtconnect",
    *,
    safety_distance: float,
    time_limit: float = 5.0,
    span: float = np.pi,
    resolution: float = 0.002,
    seed: int = 0,
) -> OfflinePlan:
    """Plan from ``q_start`` to ``q_goal`` (rad) with an OMPL planner.

    Args:
        world: MuJoCo world for validity checks.
        kin: the arm (joint order, limits, the full configuration of the other joints).
        q_goal: goal configuration (e.g. from mink IK).
        planner: ``"rrtconnect"``, ``"rrt"`` or ``"prmstar"``.
        safety_distance: clearance a valid state needs (m).
        time_limit: planning time limit (s); PRM* uses all of it (it keeps improving).
        span: half-width of the joint box around start/goal for joints without limits (rad).
        resolution: motion-check resolution as a fraction of the space's extent.
        seed: random seed: OMPL's seed generator is reseeded on every call, so the same
            problem with the same seed gives the same path with RRT-Connect and RRT (PRM*
            grows its roadmap for the whole ``time_limit``, so its path also depends on
            the machine's speed).

    Raises:
        UnknownNameError: unknown planner name.
        InvalidParameterError: ``q_start``/``q_goal`` not ``kin.n`` finite numbers, a NaN or
            negative ``safety_distance``, ``time_limit`` or ``span`` not finite and > 0,
            ``resolution`` not in (0, 1), or a negative ``seed``.
    """
    if planner not in OMPL_PLANNERS:
        raise UnknownNameError("planner", planner, OMPL_PLANNERS)
    q_start, q_goal, _ = check_endpoints(kin, q_start, q_goal, safety_distance)
    check_positive("time_limit", time_limit)
    check_positive("span", span)
    if not check_positive("resolution", resolution) < 1.0:  # OMPL wants a fraction in (0, 1)
        raise InvalidParameterError(f"resolution must be in (0, 1), got {resolution!r}")
    check_int("seed", seed, minimum=0)
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    classes = {"rrtconnect": og.RRTConnect, "rrt": og.RRT, "prmstar": og.PRMstar}
    ou.setLogLevel(ou.LOG_ERROR)
    # The planner and sampler made below draw their seeds from OMPL's seed generator, so
    # reseeding it makes this call reproducible. OMPL rejects 0, and logs an error on every
    # reseed after the first ("changing seed now will not lead to deterministic sampling",
    # true only of RNGs that already exist): silence that one line.
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)
    try:
        ou.RNG.setSeed(int(seed) + 1)
    finally:
        ou.setLogLevel(level)
    n = kin.n
    lo = np.where(np.isfinite(kin.lower), kin.lower, np.minimum(q_start, q_goal) - span)
    hi = np.where(np.isfinite(kin.upper), kin.upper, np.maximum(q_start, q_goal) + span)
    # IK and path ends may sit a hair outside a joint limit; OMPL rejects out-of-bounds states.
    q_start = np.clip(q_start, lo, hi)
    q_goal = np.clip(q_goal, lo, hi)
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(lo[i]))
        bounds.setHigh(i, float(hi[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    qbuf = np.zeros(n)

    def valid(state) -> bool:
        for i in range(n):
            qbuf[i] = state[i]
        return world.clearance(kin.full_qpos(qbuf)) >= safety_distance

    ss.setStateValidityChecker(valid)
    start, goal = space.allocState(), space.allocState()
    for i in range(n):
        start[i] = float(q_start[i])
        goal[i] = float(q_goal[i])
    ss.setStartAndGoalStates(start, goal)
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(resolution)
    ss.setPlanner(classes[planner](si))
    t0 = time.perf_counter()
    status = ss.solve(time_limit)
    elapsed = time.perf_counter() - t0
    exact = bool(status) and ss.haveExactSolutionPath()
    if not exact:
        return OfflinePlan(np.array([q_start]), False, elapsed, f"OMPL: {status}")
    path = ss.getSolutionPath()
    pts = np.array([[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())])
    return OfflinePlan(pts, True, elapsed, "exact solution")
