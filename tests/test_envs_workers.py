"""The vector env's worker processes: world k gives the same numbers for any number of
workers (and those of the single env with seed + k: observations, rewards, flags and info,
autoresets included), a dead worker raises in the parent, close ends every worker."""

from __future__ import annotations

import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from world_probes import positions

import pourbench  # noqa: F401  (registers the ids)
from pourbench.envs.pour_v0 import PourEnv
from pourbench.envs.vector import PourVectorEnv
from pourbench.envs.workers import WorkerError, default_workers, split
from pourbench.errors import InvalidParameterError

ABOVE = (-0.02, 0.0, 0.12)
N, SEED, STEPS, MAX_STEPS = 3, 21, 13, 5  # every world truncates twice: two autoresets


def _vector_rollout(workers: int, mode: str, actions: np.ndarray) -> list:
    venv = gym.make_vec(
        "pourbench/Pour-v0",
        num_envs=N,
        vectorization_mode="vector_entry_point",
        workers=workers,
        autoreset_mode=mode,
        max_steps=MAX_STEPS,
    )
    assert isinstance(venv, PourVectorEnv) and venv.workers == workers
    out = [venv.reset(seed=SEED, options={"start": ABOVE})]
    out += [venv.step(a) for a in actions]
    out.append(venv.call_world(N - 1, positions))
    venv.close()
    return out


def _assert_same(a: object, b: object) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _assert_same(a[k], b[k])
    elif isinstance(a, tuple | list):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    elif isinstance(a, np.ndarray) and a.dtype == object:
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    else:
        np.testing.assert_array_equal(a, b)


def _assert_world_info(vector_info: dict, k: int, info: dict) -> None:
    """World ``k``'s entries of a vector env's info are the single env's ``info``, bit for
    bit (an autoreset step carries the reset's info, as the single env's reset returns)."""
    for key, value in info.items():
        assert vector_info[f"_{key}"][k], key
        assert vector_info[key][k] == value, (key, vector_info[key][k], value)


@pytest.mark.parametrize("mode", ["next_step", "same_step"])
def test_world_k_is_the_same_for_any_number_of_workers(mode: str) -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, (STEPS, N, 2))
    actions[:, 0] = [1.0, 0.0]  # world 0 pours
    one = _vector_rollout(1, mode, actions)
    for workers in (2, 3):
        _assert_same(_vector_rollout(workers, mode, actions), one)
    if mode == "same_step":
        return
    # ... and world k is the single env given seed + k, through its autoresets
    k = N - 1
    env = PourEnv(max_steps=MAX_STEPS)
    obs, info = env.reset(seed=SEED + k, options={"start": ABOVE})
    np.testing.assert_array_equal(obs, one[0][0][k])
    _assert_world_info(one[0][1], k, info)
    done = False
    for t in range(STEPS):
        if done:  # next-step autoreset: the vector env resets the world, ignoring the action
            obs, info = env.reset()
            rew, term, trunc, done = 0.0, False, False, False
        else:
            obs, rew, term, trunc, info = env.step(actions[t, k])
            done = term or trunc
        np.testing.assert_array_equal(obs, one[t + 1][0][k])
        assert (rew, term, trunc) == (one[t + 1][1][k], one[t + 1][2][k], one[t + 1][3][k])
        _assert_world_info(one[t + 1][4], k, info)
    # the same liquid (the particles' storage order follows the solver's re-sort schedule,
    # which counts the steps the vector env's world held still before its autoresets)
    x, y = env.unwrapped.batch.solver.positions(), one[-1]
    np.testing.assert_array_equal(x[np.lexsort(x.T)], y[np.lexsort(y.T)])


def test_a_dead_worker_raises_in_the_parent_and_close_ends_every_worker() -> None:
    venv = PourVectorEnv(3, workers=3, liquid="water")
    venv.reset(seed=0)
    procs = [g.proc for g in venv._groups[1:]]
    assert len(procs) == 2 and all(p.poll() is None for p in procs)
    procs[1].kill()
    with pytest.raises(WorkerError, match=r"worker 2 \(worlds 2-2\) died"):
        venv.step(np.zeros((3, 2)))
    assert all(p.poll() is not None for p in procs)  # the other worker was ended too
    with pytest.raises(InvalidParameterError, match="closed"):
        venv.step(np.zeros((3, 2)))
    venv = PourVectorEnv(2, workers=2, liquid="water")
    proc = venv._groups[1].proc
    venv.reset(seed=0)
    venv.close()
    assert proc.poll() == 0  # it finished on request
    venv.close()  # a second close is harmless


def test_worker_counts() -> None:
    assert default_workers(1) == 1
    assert 1 <= default_workers(64) <= 64
    assert split(10, 3) == [(0, 4), (4, 3), (7, 3)]
    assert PourVectorEnv(1).workers == 1  # one world: in this process
    for bad, match in [(0, "workers must be >= 1"), (3, "at most one worker per world")]:
        with pytest.raises(InvalidParameterError, match=match):
            PourVectorEnv(2, workers=bad)
    with pytest.raises(InvalidParameterError, match="unknown environment setting 'liquidd'"):
        PourVectorEnv(2, workers=2, liquidd="water")  # refused before any worker starts


def test_bench_row_with_workers_counts_every_world_and_the_host_share() -> None:
    from pourbench.bench import env

    assert env.workers_for("vector", "cpu") == (1, 2) and env.workers_for("single", "cpu") == (1,)
    row = env.run_case("vector", "cpu", 3, budget_s=0.0, min_steps=1, workers=2)
    assert row["workers"] == 2 and row["worlds"] == 3 and row["env_steps_per_s"] > 0
    assert row["particles"] > 3 * 100 and 0.3 < row["g_per_particle"] < 0.9
    assert 0.0 <= row["host_share"] < 1.0
    assert row["baseline_env_steps_per_s"] > 0 and row["speedup_vs_baseline"] > 0


def test_the_baseline_batch_steps_like_the_env_it_replaced() -> None:
    """The timing baseline (the step before the batched one) pours, measures and observes as
    the environment does: its scale reads MuJoCo's sensor, which tracks the poured grams."""
    from pourbench.bench.env_baseline import LoopedPourBatch

    batch = LoopedPourBatch(1)
    batch.reset_world(
        0, seed=1, options={"liquid": "water", "start": ABOVE, "target_g": 60.0, "initial_g": 120.0}
    )
    batch.flush()
    for k in range(40):
        obs, _, term, trunc, info = batch.step(np.array([[1.0 if k < 20 else -1.0, 0.0]]))
        if term[0] or trunc[0]:
            break
    assert obs.shape == (1, 12) and info["poured_g"][0] > 50.0
    assert info["measured_g"][0] == pytest.approx(info["poured_g"][0], abs=8.0)


def test_a_refused_reset_in_the_workers_changes_nothing_and_the_env_goes_on() -> None:
    """Bad reset options raise pourbench's own error from every group (the same one as in
    this process), no world is reset, and the env keeps stepping."""
    from world_probes import world_steps

    from pourbench.errors import UnknownNameError

    venv = PourVectorEnv(2, workers=2, liquid="water")
    venv.reset(seed=0)
    venv.step(np.zeros((2, 2)))
    with pytest.raises(UnknownNameError, match="unknown liquid 'mercury'"):
        venv.reset(options={"liquid": "mercury"})
    assert [venv.call_world(k, world_steps) for k in range(2)] == [1, 1]
    obs, *_ = venv.step(np.zeros((2, 2)))
    assert obs.shape == (2, 12) and np.all(np.isfinite(obs))
    venv.close()


def test_a_reset_one_world_refuses_resets_no_world_in_any_group() -> None:
    """A refusal that depends on one world's own draw (a target more grams of its curriculum
    liquid than any container holds) comes before any world is reset, in either group:
    world 0, whose denser liquid was accepted, keeps its episode."""
    from world_probes import largest_capacity_per_density, liquid_name, world_steps

    from pourbench.envs.curriculum import draw_liquid, load_curriculum
    from pourbench.errors import CapacityError

    lessons = load_curriculum(None)
    density = {s: draw_liquid(lessons, 0, np.random.default_rng(s)).density for s in range(40)}
    light, heavy = min(density, key=density.get), max(density, key=density.get)
    assert density[heavy] > density[light] * 1.1
    venv = PourVectorEnv(2, workers=2)
    venv.reset(seed=[5, 6])
    venv.step(np.zeros((2, 2)))
    before = [venv.call_world(k, liquid_name) for k in range(2)]
    per_density = venv.call_world(0, largest_capacity_per_density)
    target = 0.85 * per_density * (density[light] + density[heavy]) / 2
    with pytest.raises(CapacityError, match="more than any training pouring container holds"):
        venv.reset(seed=[heavy, light], options={"target_g": target})
    assert [venv.call_world(k, world_steps) for k in range(2)] == [1, 1]
    assert [venv.call_world(k, liquid_name) for k in range(2)] == before
    obs, info = venv.reset(seed=[heavy, heavy], options={"target_g": target})
    assert np.all(info["target_g"] == target) and np.all(np.isfinite(obs))
    venv.close()


def test_pourbench_errors_pickle_as_themselves() -> None:
    """A worker's error reaches the parent pickled: pourbench's errors keep type and text."""
    import pickle

    from pourbench.errors import ProfileFileError, UnknownNameError

    for exc in (UnknownNameError("liquid", "mercury", ["water"]), ProfileFileError("a", "k", "x")):
        back = pickle.loads(pickle.dumps(exc))
        assert type(back) is type(exc) and str(back) == str(exc)


def test_the_step_profile_accounts_for_the_whole_step_and_unwraps() -> None:
    """``python -m pourbench.bench.env_profile``: the parts add up to the step's wall time,
    the kernels are most of it, every launch of a step is counted, and the timers are gone
    afterwards."""
    import warp as wp

    from pourbench.bench import env_profile
    from pourbench.fluids.step import StepLaunches

    launch, capture_launch = StepLaunches.launch, wp.capture_launch
    parts, facts = env_profile.step_parts(1, 3)
    assert sum(parts.values()) == pytest.approx(facts["ms_per_env_step"], rel=1e-6)
    assert parts["solver kernels (graph replays)"] > 0.5 * facts["ms_per_env_step"]
    kernels = env_profile.kernel_times(1, 2)
    assert kernels["predict"][1] == kernels["collide"][1] == 12.0  # once a substep
    assert kernels["density_sums"][1] == 36.0  # three iterations a substep
    assert StepLaunches.launch is launch and wp.capture_launch is capture_launch


def _repo() -> Path:
    root = Path(__file__).resolve().parents[1]
    if subprocess.run(["git", "-C", str(root), "rev-parse"], capture_output=True).returncode:
        pytest.skip("needs the project's git checkout")
    return root


def test_bench_row_beside_a_pinned_commit_steps_that_commits_code(tmp_path) -> None:
    """A case alternates with Pour-v0 from an earlier commit's source tree, in child
    processes of this venv that import pourbench from that tree (checked by the children),
    one per worker: here HEAD's own tree, whose kernels this suite has compiled."""
    from pourbench.bench import env
    from pourbench.bench.env_pinned import source_tree

    tree = source_tree("HEAD", _repo(), root=tmp_path)
    assert (tree / "pourbench" / "envs").is_dir() and len(tree.name) == 40
    assert source_tree("HEAD", _repo(), root=tmp_path) == tree  # extracted once
    row = env.run_case("vector", "cpu", 2, budget_s=0.0, min_steps=2, workers=2, pinned=tree)
    assert row["pinned_env_steps_per_s"] > 0 and row["speedup_vs_pinned"] > 0
    row = env.run_case("single", "cpu", 1, budget_s=0.0, min_steps=2, pinned=tree)
    assert row["speedup_vs_pinned"] == pytest.approx(
        row["env_steps_per_s"] / row["pinned_env_steps_per_s"]
    )


def test_a_pinned_comparison_is_refused_before_any_work(capsys) -> None:
    """An unknown commit, or --against for a suite without the comparison, is refused in one
    line before anything runs; the default leaves the comparison out of --quick runs."""
    from pourbench.bench import env
    from pourbench.cli import main

    _repo()
    assert main(["bench", "env", "--quick", "--against", "0000000"]) == 2
    assert "--against 0000000: no such commit" in capsys.readouterr().err
    assert main(["bench", "fluids", "--quick", "--against", "HEAD"]) == 2
    assert "--against: bench fluids has no pinned comparison" in capsys.readouterr().err
    assert env.pinned_tree(None, quick=True) == (None, None)
    assert env.pinned_tree("none", quick=False) == (None, None)
