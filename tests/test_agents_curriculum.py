"""The curriculum in training: lessons switch at 25 % and 50 % of the steps on every world,
and an episode's ``info["liquid"]`` says when its liquid was drawn from a lesson."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor
from toy_envs import Toy

from pourbench.agents.schedule import CurriculumCallback, step_progress
from pourbench.envs.curriculum import load_curriculum

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_lessons_switch_at_a_quarter_and_a_half_of_the_steps() -> None:
    envs = [Toy(7), Toy(4)]
    venv = VecMonitor(DummyVecEnv([lambda e=e: e for e in envs]))
    model = PPO("MlpPolicy", venv, n_steps=50, batch_size=50, n_epochs=1, seed=0, device="cpu")
    seen: list[tuple[int, int, int]] = []

    class Watch(BaseCallback):  # runs after the curriculum's own step
        def _on_step(self) -> bool:
            seen.append((self.num_timesteps, envs[0].lesson, envs[1].lesson))
            return True

    schedule = CurriculumCallback(step_progress(400))
    model.learn(400, callback=[schedule, Watch()])
    assert schedule.switches == [(0, 0), (100, 1), (200, 2)]
    for steps, a, b in seen:  # every world, at every step
        expected = 0 if steps < 100 else 1 if steps < 200 else 2
        assert a == b == expected, steps
    assert seen[-1][0] == 400


def test_a_lesson_liquid_is_named_after_its_lesson() -> None:
    from pourbench.agents.sb3 import SB3PourVecEnv

    lessons = load_curriculum()
    rng = np.random.default_rng(0)
    assert lessons[1].sample(rng).name == "lesson oil-like"
    venv = SB3PourVecEnv(2, seed=0, workers=1, liquid=None, max_steps=1)
    venv.env_method("set_lesson", 2)
    venv.reset()
    _, _, done, infos = venv.step(np.zeros((2, 2), np.float32))
    assert done.all() and [i["liquid"] for i in infos] == ["lesson honey-like"] * 2
    venv.close()
    named = SB3PourVecEnv(1, seed=0, workers=1, liquid="water", max_steps=1)
    named.reset()
    _, _, _, infos = named.step(np.zeros((1, 2), np.float32))
    assert not infos[0]["liquid"].startswith("lesson")
    named.close()
