"""Training's wall-clock budget stops a real PPO run and checkpoints at its interval; the
plot reads every session's progress.csv in step order."""

from __future__ import annotations

import itertools
import time

import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import DummyVecEnv
from toy_envs import Toy

from pourbench.agents.callbacks import BudgetCallback, PourStatsCallback
from pourbench.agents.plots import plot_training, read_progress

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_a_wall_clock_budget_stops_training_and_checkpoints() -> None:
    model = PPO("MlpPolicy", DummyVecEnv([Toy]), n_steps=16, batch_size=16, device="cpu")
    model.learn(32)  # torch's first update takes a second of its own
    saved: list[float] = []
    budget = BudgetCallback(1.0, 0.2, lambda: saved.append(time.perf_counter()))
    t0 = time.perf_counter()
    model.learn(10**9, callback=budget)
    took = time.perf_counter() - t0
    assert 1.0 <= took < 10.0  # stops at the first step past the budget
    assert 0 < model.num_timesteps < 10**9
    # checkpoints come no more often than every 0.2 s, and at least once in the second
    # (how many depends on how long the machine takes for a PPO update)
    assert saved and saved[0] - t0 >= 0.2
    assert all(b - a >= 0.2 for a, b in itertools.pairwise(saved))


def test_the_plot_reads_every_session_in_step_order(tmp_path) -> None:
    for session, rows in {"0": [(64, 0.5, 1), (128, 0.3, 2)], "1": [(192, 0.2, 2)]}.items():
        folder = tmp_path / "logs" / session
        folder.mkdir(parents=True)
        lines = ["time/total_timesteps,icm/intrinsic_reward,curriculum/lesson,rollout/ep_rew_mean"]
        lines += [f"{s},{r},{k}," for s, r, k in rows]
        (folder / "progress.csv").write_text("\n".join(lines) + "\n")
    series = read_progress(sorted(tmp_path.glob("logs/*/progress.csv")))
    assert series["icm/intrinsic_reward"] == [(64, 0.5), (128, 0.3), (192, 0.2)]
    assert series["curriculum/lesson"] == [(64, 1), (128, 2), (192, 2)]
    assert "rollout/ep_rew_mean" not in series  # empty cells are no points
    png = plot_training(tmp_path)
    assert png == tmp_path / "training.png" and png.read_bytes()[:4] == b"\x89PNG"


def test_the_running_average_is_logged_over_the_worlds_that_have_one() -> None:
    """Worlds whose episodes all timed out have no completed episode (their average reads
    0): they are left out of ``pour/average_error_g``, and a rollout where no world has one
    logs none."""
    model = PPO("MlpPolicy", DummyVecEnv([Toy]), n_steps=16, batch_size=16, device="cpu")
    model.set_logger(Logger(None, []))
    stats = PourStatsCallback()
    stats.init_callback(model)

    def step(dones: list[bool], errors: list[float], averages: list[float]) -> None:
        infos = [  # a world with a completed episode has a nonzero average here
            {"error_g": e, "average_error_g": a, "completed_episodes": int(a > 0)}
            for e, a in zip(errors, averages, strict=True)
        ]
        stats.locals = {"dones": dones, "infos": infos}
        stats.on_step()

    step([True, True, False], [90.0, 80.0, 0.0], [0.0, 0.0, 0.0])
    stats.on_rollout_end()
    logged = model.logger.name_to_value
    assert logged["pour/error_g"] == 85.0 and "pour/average_error_g" not in logged
    step([True, False, True], [4.0, 0.0, 100.0], [6.0, 0.0, 0.0])
    step([False, True, False], [0.0, 12.0, 0.0], [0.0, 10.0, 0.0])
    stats.on_rollout_end()
    assert logged["pour/error_g"] == pytest.approx(116 / 3)
    assert logged["pour/average_error_g"] == 8.0  # worlds 0 and 1; world 2 has none
