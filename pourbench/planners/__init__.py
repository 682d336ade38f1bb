"""Motion planners: NMPC-MP (thesis chapter 4), a mink differential-IK controller, and
offline baselines (OMPL RRT-Connect / RRT / PRM*, hand-written STOMP and CHOMP).

A library: it uses MuJoCo models and never imports :mod:`pourbench.envs`.
"""

from pourbench.geometry.rotation import rotation_error
from pourbench.planners.distance import (
    Box,
    Capsule,
    DistanceResult,
    Obstacle,
    Sphere,
    capsule_obstacle_distances,
)
from pourbench.planners.kinematics import ArmKinematics, ArmState, point_jacobian
from pourbench.planners.mink_controller import MinkController, MinkResult
from pourbench.planners.nmpc import HESSIANS, NMPCConfig, NMPCPlanner, NMPCResult
from pourbench.planners.robots import ARMS, ArmSpec, arm_kinematics, arm_spec, geom_obstacles
from pourbench.planners.rollout import Rollout, run_to_goal
from pourbench.planners.world import PlanningWorld

__all__ = [
    "ARMS",
    "HESSIANS",
    "ArmKinematics",
    "ArmSpec",
    "ArmState",
    "Box",
    "Capsule",
    "DistanceResult",
    "MinkController",
    "MinkResult",
    "NMPCConfig",
    "NMPCPlanner",
    "NMPCResult",
    "Obstacle",
    "PlanningWorld",
    "Rollout",
    "Sphere",
    "arm_kinematics",
    "arm_spec",
    "capsule_obstacle_distances",
    "geom_obstacles",
    "point_jacobian",
    "rotation_error",
    "run_to_goal",
]
