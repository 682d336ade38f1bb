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
from pourbench.envs.curriculum import draw_liquid, load_curriculum

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


def test_rehearsing_draws_every_lesson_up_to_the_current_one_alike() -> None:
    """Lesson k alone without rehearsal; with it, lessons 0…k and never a later one, about
    equally often (3000 draws: each share within 0.05 of 1/3, about five standard
    deviations)."""
    lessons = load_curriculum()
    rng = np.random.default_rng(0)
    names = [lesson.name for lesson in lessons]
    plain = {draw_liquid(lessons, 2, rng).name for _ in range(200)}
    assert plain == {f"lesson {names[2]}"}
    first = {draw_liquid(lessons, 0, rng, rehearse=True).name for _ in range(200)}
    assert first == {f"lesson {names[0]}"}
    second = {draw_liquid(lessons, 1, rng, rehearse=True).name for _ in range(200)}
    assert second == {f"lesson {names[0]}", f"lesson {names[1]}"}
    drawn = [draw_liquid(lessons, 2, rng, rehearse=True).name for _ in range(3000)]
    shares = [drawn.count(f"lesson {n}") / len(drawn) for n in names]
    assert all(abs(s - 1 / 3) < 0.05 for s in shares), shares


def test_a_rehearsing_env_pours_earlier_lessons_liquids() -> None:
    from pourbench.envs.pour_v0 import PourEnv

    env = PourEnv(rehearse=True)
    env.set_lesson(2)
    seen = set()
    for seed in range(8):
        env.reset(seed=seed)
        seen.add(env.batch.worlds[0].liquid.name)
    assert len(seen) >= 2 and seen <= {f"lesson {x.name}" for x in env.batch.lessons}
    env.close()
    with pytest.raises(ValueError, match="rehearse must be True or False, got 1"):
        PourEnv(rehearse=1)
