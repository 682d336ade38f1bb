"""PourRobot-v0's rows of ``pourbench bench env``: environment steps per second with the robot
in the loop (Movo and Panda, NMPC-MP and mink), beside the single Pour-v0 env stepped in the
same process, alternating step by step so that both see the same machine load.

Each case resets (water, 100 g, seed 0), takes two warm-up steps, then steps a fixed pouring
action until it has had ``budget_s`` seconds and ``min_steps`` steps, resetting an episode
that ends as a training loop does. ``planner_ms_per_step``: the planner's own solve time in a
step (``RobotPourEnv.planner_time_s``), the rest is the MuJoCo substeps, the liquid and the
step's bookkeeping.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

ROBOT_CASES = (("movo", "nmpc"), ("movo", "mink"), ("panda", "nmpc"), ("panda", "mink"))


def robot_case(
    robot: str, planner: str, budget_s: float = 5.0, min_steps: int = 3
) -> dict[str, Any]:
    """Time PourRobot-v0 with ``robot`` and ``planner`` against a single Pour-v0 env."""
    from pourbench.envs.pour_v0 import PourEnv
    from pourbench.envs.robot_pour import RobotPourEnv

    options = {"target_g": 100.0}
    action = np.array([0.5, 1.0], np.float32)
    envs = {
        "robot": RobotPourEnv(robot=robot, planner=planner, liquid="water"),
        "pour": PourEnv(liquid="water"),
    }
    wall = dict.fromkeys(envs, 0.0)
    steps = dict.fromkeys(envs, 0)
    planner_s = 0.0
    for env in envs.values():
        env.reset(seed=0, options=options)
        for _ in range(2):
            env.step(action)
    while min(steps.values()) < min_steps or min(wall.values()) < budget_s:
        for name, env in envs.items():
            t0 = time.perf_counter()
            _, _, term, trunc, _ = env.step(action)
            if term or trunc:
                env.reset(options=options)
            wall[name] += time.perf_counter() - t0
            steps[name] += 1
            if name == "robot":
                planner_s += env.planner_time_s
    rate = {name: steps[name] / wall[name] for name in envs}
    particles = envs["robot"].solver.num_particles
    for env in envs.values():
        env.close()
    return {
        "robot": robot,
        "planner": planner,
        "env_steps_per_s": rate["robot"],
        "planner_ms_per_step": 1e3 * planner_s / steps["robot"],
        "pour_v0_env_steps_per_s": rate["pour"],
        "ratio_to_pour_v0": rate["robot"] / rate["pour"],
        "particles": particles,
    }
