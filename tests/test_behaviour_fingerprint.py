"""Bit-for-bit fingerprints of Pour-v0, the vector env and the solver on the CPU.

A refactor that claims to change no behaviour must leave these hashes as they are. They hash
float64 copies of every observation, reward and flag of short random-action runs with each
reset's filled grams (and, for the single env, its particles' final positions: a random
policy rarely pours, so the observations alone barely see the liquid), and the particle
positions and velocities of a viscous two-cup pour (the implicit viscosity solve).

The hashes hold for one CPU's floating-point path: Warp's LLVM code generation may contract or
vectorise differently on another instruction set, so they are marked slow and kept out of CI.
Run them before and after a refactor (``pytest -m slow tests/test_behaviour_fingerprint.py``).
On a mismatch the test prints the new hashes; a change that means to alter
behaviour replaces the recorded ones in the same commit and says why.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from pourbench.envs.pour_v0 import PourEnv
from pourbench.envs.vector import PourVectorEnv
from pourbench.fluids.scenarios import tilt_schedule, two_cup_scene

pytestmark = pytest.mark.slow

RECORDED = {
    "single water thesis": "9c48dc52c85eb51a",
    "single honey free": "f765c7df5da549f7",
    "vector oil": "7781d29c86433889",
    "solver honey two-cup": "47e1c93cc885c673",
}


def _hash(arrays: list) -> str:
    digest = hashlib.sha256()
    for a in arrays:
        digest.update(np.ascontiguousarray(np.asarray(a, dtype=np.float64)).tobytes())
    return digest.hexdigest()[:16]


def _single(liquid: str, mode: str) -> str:
    env = PourEnv(liquid=liquid, action_mode=mode)
    rng = np.random.default_rng(1)
    obs, info = env.reset(seed=3, options={"target_g": 100.0})
    seen = [obs, info["initial_g"]]
    for _ in range(80):
        obs, reward, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        seen += [obs, [reward, term, trunc, info["error_g"], info["spilled_g"]]]
        if term or trunc:
            obs, info = env.reset(seed=4)
            seen += [info["initial_g"]]
    seen += [env.unwrapped.batch.solver.positions()]  # the liquid, poured or not
    env.close()
    return _hash(seen)


def _vector() -> str:
    env = PourVectorEnv(num_envs=3, liquid="oil")
    rng = np.random.default_rng(2)
    obs, info = env.reset(seed=5)
    seen = [obs, info["initial_g"]]
    for _ in range(60):
        obs, reward, term, trunc, _ = env.step(rng.uniform(-1, 1, env.action_space.shape))
        seen += [obs, reward, term, trunc]
    env.close()
    return _hash(seen)


def _solver() -> str:
    scene = two_cup_scene("honey", 150.0, num_worlds=2)
    seen = []
    for k in range(90):
        scene.set_tilt(tilt_schedule(k * scene.solver.config.dt * 4))
        scene.step(4)
        if k % 10 == 0:
            seen += [scene.solver.positions(), scene.solver.velocities()]
    return _hash(seen)


def test_behaviour_is_unchanged() -> None:
    measured = {
        "single water thesis": _single("water", "thesis"),
        "single honey free": _single("honey", "free"),
        "vector oil": _vector(),
        "solver honey two-cup": _solver(),
    }
    assert measured == RECORDED, f"behaviour changed; new hashes: {measured}"
