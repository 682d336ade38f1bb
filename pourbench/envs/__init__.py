"""Gymnasium environments: ``pourbench/Pour-v0`` (single and vector) and
``pourbench/PourRobot-v0`` (the robot in the loop, single; in
:mod:`pourbench.envs.robot_pour`, not imported here so that the planners load only with it).

``import pourbench`` registers the ids (Gymnasium 1.x does not load ``gymnasium.envs`` entry
points by itself; without the import, ``gymnasium.make("pourbench:pourbench/Pour-v0")``
imports the package first). The single env is the batch of one of the vector env's
:class:`PourBatch`.
"""

from __future__ import annotations

from pourbench import ENV_IDS, register_envs
from pourbench.envs.action_handler import ACTION_MODES, ActionLimits, handle_actions
from pourbench.envs.core import PourBatch, PourConfig, default_solver_config
from pourbench.envs.curriculum import Lesson, lesson_at, load_curriculum
from pourbench.envs.observation import WeightFilter
from pourbench.envs.pour_v0 import PourEnv
from pourbench.envs.reward import ErrorHistory, RewardConfig, extrinsic_reward
from pourbench.envs.vector import PourVectorEnv

__all__ = [
    "ACTION_MODES",
    "ENV_IDS",
    "ActionLimits",
    "ErrorHistory",
    "Lesson",
    "PourBatch",
    "PourConfig",
    "PourEnv",
    "PourVectorEnv",
    "RewardConfig",
    "WeightFilter",
    "default_solver_config",
    "extrinsic_reward",
    "handle_actions",
    "lesson_at",
    "load_curriculum",
    "register_envs",
]
