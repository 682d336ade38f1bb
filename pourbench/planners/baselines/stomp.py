"""STOMP (Kalakrishnan et al., 2011), written here by hand in numpy.

Stochastic trajectory optimisation in joint space: noisy rollouts drawn from N(0, R⁻¹) with
R = AᵀA the finite-difference acceleration cost, per-waypoint costs turned into
probabilities with ``exp(−h·(S − min S)/(max S − min S))``, the probability-weighted noise
smoothed by M (R⁻¹ with columns scaled to max 1/T) and added to the trajectory. The waypoint
cost is the obstacle hinge ``Σ max(0, d_safe + margin − sd)`` over every capsule–obstacle
pair, with sd from :mod:`pourbench.planners.distance`. Start and goal are fixed (a joint-space
goal, as in the thesis).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pourbench.errors import check_finite, check_int
from pourbench.planners.baselines.common import (
    OfflinePlan,
    check_endpoints,
    path_min_distance,
    second_difference_matrix,
)
from pourbench.planners.distance import Obstacle, capsule_obstacle_distances, check_obstacles
from pourbench.planners.kinematics import ArmKinematics


@dataclass(frozen=True)
class StompConfig:
    """STOMP parameters.

    Attributes:
        waypoints: trajectory waypoints including start and goal.
        rollouts: noisy rollouts per iteration.
        noise_std: scale of the exploration noise (rad).
        h: sensitivity of the exponentiated cost.
        margin: extra distance beyond the safety distance the obstacle cost pushes to (m).
        smooth_weight: weight of the acceleration cost in the trajectory cost.
    """

    waypoints: int = 30
    rollouts: int = 16
    max_iters: int = 100
    noise_std: float = 0.25
    h: float = 10.0
    margin: float = 0.03
    smooth_weight: float = 1e-3

    def __post_init__(self) -> None:
        check_int("waypoints", self.waypoints, minimum=3)
        check_int("rollouts", self.rollouts, minimum=1)
        check_int("max_iters", self.max_iters, minimum=1)
        for name in ("noise_std", "h", "margin", "smooth_weight"):
            check_finite(name, getattr(self, name), minimum=0.0)


def _waypoint_costs(kin, obstacles, Q, threshold) -> tuple[np.ndarray, float]:
    """Obstacle hinge cost per waypoint, and the smallest signed distance (m)."""
    st = kin.forward_many(Q, jacobians=False)
    sd = capsule_obstacle_distances(st.seg_a, st.seg_b, st.radius, obstacles).sd
    return np.maximum(threshold - sd, 0.0).reshape(len(Q), -1).sum(axis=1), float(sd.min())


def plan_stomp(
    kin: ArmKinematics,
    obstacles: Sequence[Obstacle],
    q_start: np.ndarray,
    q_goal: np.ndarray,
    *,
    safety_distance: float,
    config: StompConfig | None = None,
    seed: int | np.random.Generator | None = 0,
) -> OfflinePlan:
    """Optimise a joint path from ``q_start`` to ``q_goal`` (rad) around ``obstacles``.

    Success = the path (checked at 0.01 rad steps) keeps ``safety_distance``.

    Raises:
        InvalidParameterError: ``q_start``/``q_goal`` not ``kin.n`` finite numbers, a NaN or
            negative ``safety_distance``, an entry of ``obstacles`` that is not one, or a
            ``seed`` that is not an integer >= 0, None or a ``numpy.random.Generator``.
    """
    c = config or StompConfig()
    q_start, q_goal, safety_distance = check_endpoints(kin, q_start, q_goal, safety_distance)
    obstacles = check_obstacles(obstacles)
    if isinstance(seed, np.random.Generator):
        rng = seed
    else:
        rng = np.random.default_rng(None if seed is None else check_int("seed", seed, minimum=0))
    t0 = time.perf_counter()
    T = c.waypoints - 2
    A = second_difference_matrix(T)
    R = A.T @ A
    Rinv = np.linalg.inv(R)
    M = Rinv / (T * Rinv.max(axis=0, keepdims=True))
    L = np.linalg.cholesky(Rinv / Rinv.max())  # unit-scale noise, smooth in time
    theta = q_start + np.linspace(0.0, 1.0, c.waypoints)[1:-1, None] * (q_goal - q_start)
    threshold = safety_distance + c.margin
    n = kin.n
    it = 0
    while it < c.max_iters:
        it += 1
        if not obstacles:
            break
        _, sd_min = _waypoint_costs(kin, obstacles, theta, threshold)
        # Stop once every waypoint keeps the safety distance (the dense check follows).
        if sd_min >= safety_distance + 0.25 * c.margin:
            break
        eps = c.noise_std * np.einsum("tk,rkn->rtn", L, rng.standard_normal((c.rollouts, T, n)))
        batch = (theta[None] + eps).reshape(-1, n)  # all rollouts in one batched call
        S = _waypoint_costs(kin, obstacles, batch, threshold)[0].reshape(c.rollouts, T)
        S += c.smooth_weight * np.einsum("rtn,tk,rkn->rt", eps, R, eps) / n
        lo, hi = S.min(axis=0), S.max(axis=0)
        P = np.exp(-c.h * (S - lo) / np.maximum(hi - lo, 1e-12))
        P /= P.sum(axis=0, keepdims=True)
        dtheta = M @ np.einsum("rt,rtn->tn", P, eps)
        theta = theta + dtheta
    path = np.vstack([q_start, theta, q_goal])
    clear = path_min_distance(kin, obstacles, path)
    ok = clear >= safety_distance
    reason = "collision-free" if ok else f"clearance {clear:.3f} m < safety"
    return OfflinePlan(path, bool(ok), time.perf_counter() - t0, reason, iterations=it)
