"""Gymnasium environments: ``pourbench/Pour-v0`` (single and vector).

``import pourbench`` registers the ids (also reachable through the ``gymnasium.envs`` entry
point). The single env is the batch of one of the vector env's :class:`PourBatch`.
"""

from __future__ import annotations

from pourbench import register_envs
from pourbench.envs.action_handler import ACTION_MODES, ActionLimits, handle_actions
from pourbench.envs.core import PourBatch, PourConfig, default_solver_config
from pourbench.envs.curriculum import Lesson, lesson_at, load_curriculum
from pourbench.envs.observation import WeightFilter
from pourbench.envs.reward import ErrorHistory, RewardConfig, extrinsic_reward

ENV_IDS: tuple[str, ...] = ("pourbench/Pour-v0",)


__all__ = [
    "ACTION_MODES",
    "ENV_IDS",
    "ActionLimits",
    "ErrorHistory",
    "Lesson",
    "PourBatch",
    "PourConfig",
    "RewardConfig",
    "WeightFilter",
    "default_solver_config",
    "extrinsic_reward",
    "handle_actions",
    "lesson_at",
    "load_curriculum",
    "register_envs",
]
