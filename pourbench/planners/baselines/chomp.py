"""CHOMP (Ratliff et al., 2009; Zucker et al., 2013), written here by hand in numpy.

Covariant gradient descent on a joint trajectory with fixed end points:
``ξ ← ξ − (1/η) A⁻¹ (∇F_smooth + λ ∇F_obs)``, A = KᵀK from finite-difference velocities.
The obstacle potential is CHOMP's smoothed hinge on ``d = sd − d_safe``: ``−d + ε/2`` for
d < 0, ``(d − ε)²/(2ε)`` for 0 ≤ d < ε, 0 beyond; its gradient uses the same analytic
signed-distance gradient as NMPC-MP (``nᵀ J(p)``). Simplification: the workspace-velocity
weighting and curvature term of the original functional are left out.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pourbench.errors import check_finite, check_int, check_positive
from pourbench.planners.baselines.common import OfflinePlan, check_endpoints, path_min_distance
from pourbench.planners.distance import Obstacle, capsule_obstacle_distances, check_obstacles
from pourbench.planners.kinematics import ArmKinematics, point_jacobian


@dataclass(frozen=True)
class ChompConfig:
    """CHOMP parameters.

    Attributes:
        waypoints: trajectory waypoints including start and goal.
        eta: step regulariser (larger = smaller steps).
        obstacle_weight: λ, weight of the obstacle potential.
        epsilon: width of the smoothed hinge (m).
        max_step: largest joint change per iteration and waypoint (rad).
    """

    waypoints: int = 30
    max_iters: int = 200
    eta: float = 5.0
    obstacle_weight: float = 20.0
    epsilon: float = 0.05
    max_step: float = 0.1

    def __post_init__(self) -> None:
        check_int("waypoints", self.waypoints, minimum=3)
        check_int("max_iters", self.max_iters, minimum=1)
        check_positive("eta", self.eta)
        check_finite("obstacle_weight", self.obstacle_weight, minimum=0.0)
        check_positive("epsilon", self.epsilon)
        check_positive("max_step", self.max_step)


def plan_chomp(
    kin: ArmKinematics,
    obstacles: Sequence[Obstacle],
    q_start: np.ndarray,
    q_goal: np.ndarray,
    *,
    safety_distance: float,
    config: ChompConfig | None = None,
) -> OfflinePlan:
    """Optimise a joint path from ``q_start`` to ``q_goal`` (rad) around ``obstacles``.

    Success = the path (checked at 0.01 rad steps) keeps ``safety_distance``.

    Raises:
        InvalidParameterError: ``q_start``/``q_goal`` not ``kin.n`` finite numbers, a NaN or
            negative ``safety_distance``, or an entry of ``obstacles`` that is not one.
    """
    c = config or ChompConfig()
    t0 = time.perf_counter()
    q_start, q_goal, safety_distance = check_endpoints(kin, q_start, q_goal, safety_distance)
    obstacles = check_obstacles(obstacles)
    T = c.waypoints - 2
    K = np.eye(T + 1, T) - np.eye(T + 1, T, k=-1)  # finite-difference velocities
    A = K.T @ K
    e = np.zeros((T + 1, kin.n))
    e[0] = -q_start
    e[-1] = q_goal
    b = K.T @ e  # ∇F_smooth = A ξ + b... with sign: F = ½|Kξ + e|² → ∇ = Aξ + Kᵀe
    Ainv = np.linalg.inv(A)
    xi = q_start + np.linspace(0.0, 1.0, c.waypoints)[1:-1, None] * (q_goal - q_start)
    it = 0
    while it < c.max_iters:
        it += 1
        grad_s = A @ xi + b
        grad_o = np.zeros_like(xi)
        worst = np.inf
        if obstacles and kin.num_capsules:
            st = kin.forward_many(xi)
            dist = capsule_obstacle_distances(st.seg_a, st.seg_b, st.radius, obstacles)
            d = dist.sd - safety_distance  # (T, K, L)
            worst = float(d.min())
            dc = np.where(d < 0.0, -1.0, np.where(d < c.epsilon, (d - c.epsilon) / c.epsilon, 0))
            PJ = point_jacobian(
                st.body_pos[:, :, None], st.body_jacp[:, :, None], st.body_jacr[:, :, None],
                dist.point_robot,
            )  # fmt: skip
            dsd = np.einsum("tkla,tklan->tkln", dist.normal, PJ)
            grad_o = np.einsum("tkl,tkln->tn", dc, dsd)
        step = Ainv @ (grad_s + c.obstacle_weight * grad_o) / c.eta
        big = np.abs(step).max()
        if big > c.max_step:
            step *= c.max_step / big
        xi = xi - step
        if worst >= 0.0 and big < 1e-4:
            break
    path = np.vstack([q_start, xi, q_goal])
    clear = path_min_distance(kin, obstacles, path)
    ok = clear >= safety_distance
    reason = "collision-free" if ok else f"clearance {clear:.3f} m < safety"
    return OfflinePlan(path, bool(ok), time.perf_counter() - t0, reason, iterations=it)
