"""Motion planners: NMPC-MP (thesis chapter 4), a mink differential-IK controller, and
offline baselines (OMPL RRT-Connect / RRT / PRM*, hand-written STOMP and CHOMP).

A library: it uses MuJoCo models and never imports :mod:`pourbench.envs`.
"""

from pourbench.planners.distance import (
    Box,
    Capsule,
    DistanceResult,
    Obstacle,
    Sphere,
    capsule_obstacle_distances,
)
from pourbench.planners.kinematics import ArmKinematics, ArmState, point_jacobian
from pourbench.planners.nmpc import HESSIANS, NMPCConfig, NMPCPlanner, NMPCResult
from pourbench.planners.rollout import Rollout, rotation_error, run_to_goal

__all__ = [
    "HESSIANS",
    "ArmKinematics",
    "ArmState",
    "Box",
    "Capsule",
    "DistanceResult",
    "NMPCConfig",
    "NMPCPlanner",
    "NMPCResult",
    "Obstacle",
    "Rollout",
    "Sphere",
    "capsule_obstacle_distances",
    "point_jacobian",
    "rotation_error",
    "run_to_goal",
]
