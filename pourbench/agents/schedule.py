"""Curriculum schedule for training (thesis §6.5.6, §6.6.1.2): the lessons of a curriculum
file (``pourbench/assets/curriculum.toml``: 25 % / 25 % / 50 % of the training steps) switched
on every world as training progresses.

:class:`CurriculumCallback` calls ``env_method("set_lesson", k)`` on the training VecEnv
(:class:`~pourbench.agents.sb3.SB3PourVecEnv` forwards it to every world of its vector env,
in this process and in the workers; SB3 wrappers pass it through). A lesson applies to
liquids drawn at later resets: an episode under way keeps its liquid. The lesson is logged
as ``curriculum/lesson`` (its index) at every rollout's end.
"""

from __future__ import annotations

from collections.abc import Callable

from stable_baselines3.common.callbacks import BaseCallback

from pourbench.envs.curriculum import lesson_at, load_curriculum
from pourbench.errors import check_positive


class CurriculumCallback(BaseCallback):
    """Switch lessons by training progress.

    Args:
        progress: a function of the model's ``num_timesteps`` giving the progress in [0, 1]
            (past 1 stays in the last lesson); :func:`step_progress` for a budget of steps.
        verbose: 1 prints each switch.

    Attributes:
        lesson: the index of the lesson set on the worlds (-1 before training starts).
        switches: ``(num_timesteps, lesson)`` of every switch, the first one included.
    """

    def __init__(self, progress: Callable[[int], float], verbose: int = 0) -> None:
        super().__init__(verbose)
        self.progress = progress
        self.lessons = load_curriculum()
        self.lesson = -1
        self.switches: list[tuple[int, int]] = []

    def _set(self) -> None:
        k = lesson_at(self.progress(self.num_timesteps), self.lessons)
        if k != self.lesson:
            self.training_env.env_method("set_lesson", k)
            self.lesson = k
            self.switches.append((self.num_timesteps, k))
            if self.verbose:
                name = self.lessons[k].name
                print(f"curriculum: lesson {k} ({name}) from step {self.num_timesteps}")

    def _on_training_start(self) -> None:
        self._set()

    def _on_step(self) -> bool:
        self._set()
        return True

    def _on_rollout_end(self) -> None:
        self.logger.record("curriculum/lesson", self.lesson)


def step_progress(total_steps: int) -> Callable[[int], float]:
    """Progress of a run with a budget of ``total_steps`` environment steps (all worlds)."""
    total = check_positive("total_steps", total_steps)
    return lambda steps: steps / total
