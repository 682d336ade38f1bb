"""A tiny deterministic environment for the agents' tests (real SB3 training, in
milliseconds)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np


class Toy(gym.Env):
    """A deterministic 3-value state moved by a 1-value action; terminates after ``length``
    steps with reward 1 (and -0.1 a step before). Records every transition it makes."""

    observation_space = gym.spaces.Box(-10.0, 10.0, (3,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, length: int = 5, offset: float = 0.0) -> None:
        self.length, self.offset = length, offset
        self.log: list[tuple[np.ndarray, np.ndarray, np.ndarray, float, bool]] = []

    def _obs(self) -> np.ndarray:
        return np.array([self.t / self.length, self.x, self.offset], np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t, self.x = 0, 0.0
        return self._obs(), {}

    def step(self, action):
        before = self._obs()
        a = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        self.t += 1
        self.x = float(np.clip(self.x + 0.5 * a[0], -10, 10))
        done = self.t >= self.length
        reward = 1.0 if done else -0.1
        self.log.append((before, a.copy(), self._obs(), reward, done))
        return self._obs(), reward, done, False, {}

    def set_lesson(self, k: int) -> None:
        self.lesson = k
