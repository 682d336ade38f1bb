"""What every offline baseline returns, and helpers to check and execute a joint path."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_array, check_finite, check_positive
from pourbench.planners.distance import Obstacle, capsule_obstacle_distances, check_obstacles
from pourbench.planners.kinematics import ArmKinematics


@dataclass
class OfflinePlan:
    """A joint-space path from an offline planner.

    Attributes:
        path: waypoints (N, n) in rad, first = start, last = goal when ``success``.
        success: a collision-free path (by the planner's own check) was found.
        planning_time_s: wall time of planning (s).
        reason: short status text.
        iterations: optimiser iterations (STOMP/CHOMP), 0 for sampling planners.
    """

    path: np.ndarray
    success: bool
    planning_time_s: float
    reason: str
    iterations: int = 0


def densify(path: np.ndarray, max_step: float) -> np.ndarray:
    """Linear interpolation of a joint path so no joint moves more than ``max_step`` (rad).

    Raises:
        InvalidParameterError: ``path`` is not a non-empty finite (N, n) array, or
            ``max_step`` is not finite and > 0.
    """
    path = check_path("path", path)
    check_positive("max_step", max_step)
    out = [path[0]]
    for a, b in itertools.pairwise(path):
        k = max(1, int(np.ceil(np.max(np.abs(b - a)) / max_step)))
        for s in np.arange(1, k + 1) / k:
            out.append(a + s * (b - a))
    return np.array(out)


def path_min_distance(
    kin: ArmKinematics, obstacles: Sequence[Obstacle], path: np.ndarray, max_step: float = 0.01
) -> float:
    """Smallest capsule–obstacle signed distance along a densified path (m); inf if none."""
    obstacles = check_obstacles(obstacles)
    path = check_path("path", path, kin.n)
    check_positive("max_step", max_step)
    if not obstacles or kin.num_capsules == 0:
        return float("inf")
    dense = densify(path, max_step)
    st = kin.forward_many(dense, jacobians=False)
    return float(capsule_obstacle_distances(st.seg_a, st.seg_b, st.radius, obstacles).sd.min())


def check_path(name: str, path: object, n: int | None = None) -> np.ndarray:
    """``path`` as a finite (N ≥ 1, n) float array (``n`` joints when given)."""
    arr = check_array(name, path, (None, n))
    if len(arr) == 0:
        raise InvalidParameterError(f"{name} must have at least one waypoint, got none")
    return arr


def check_endpoints(
    kin: ArmKinematics, q_start: object, q_goal: object, safety_distance: object
) -> tuple[np.ndarray, np.ndarray, float]:
    """Validated start and goal (``kin.n`` finite joint values each) and safety distance."""
    qs = check_array("q_start", q_start, (kin.n,))
    qg = check_array("q_goal", q_goal, (kin.n,))
    check_finite("safety_distance", safety_distance, minimum=0.0)
    return qs, qg, safety_distance  # type: ignore[return-value]


def second_difference_matrix(T: int) -> np.ndarray:
    """(T + 2, T) finite-difference acceleration operator on T interior waypoints (the two
    fixed end points enter through a separate offset)."""
    return np.eye(T + 2, T) - 2.0 * np.eye(T + 2, T, k=-1) + np.eye(T + 2, T, k=-2)
