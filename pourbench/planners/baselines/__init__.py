"""Offline baselines: OMPL RRT-Connect / RRT / PRM* (the real library) and hand-written
STOMP and CHOMP."""

from pourbench.planners.baselines.chomp import ChompConfig, plan_chomp
from pourbench.planners.baselines.common import OfflinePlan, densify, path_min_distance
from pourbench.planners.baselines.ompl_planners import OMPL_PLANNERS, plan_ompl
from pourbench.planners.baselines.stomp import StompConfig, plan_stomp

__all__ = [
    "OMPL_PLANNERS",
    "ChompConfig",
    "OfflinePlan",
    "StompConfig",
    "densify",
    "path_min_distance",
    "plan_chomp",
    "plan_ompl",
    "plan_stomp",
]
