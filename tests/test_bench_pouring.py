"""``pourbench bench pouring``: Table 6.3's protocol and the novel containers, resumable, and
the same numbers however its episodes are spread over processes."""

from __future__ import annotations

import argparse
import json

import pytest

from pourbench.agents.loading import policy_metadata
from pourbench.argtypes import shipped_policies
from pourbench.bench import pouring
from pourbench.bench._jobs import job_key, run_jobs


def _result(error_g: float, success: bool = True, density: float = 1.0) -> dict:
    return {
        "error_g": error_g,
        "error_ml": error_g / density,
        "success": success,
        "collided": False,
        "sim_diverged": False,
    }


def test_the_tables_set_each_policy_beside_the_thesis() -> None:
    results = {
        ("pd", "ketchup", None, 150.0, 0): _result(4.0),
        ("pd", "ketchup", None, 150.0, 1): _result(12.0, success=False),
        ("random", "ketchup", None, 150.0, 0): _result(150.0, success=False),
        ("random", "ketchup", None, 150.0, 1): {**_result(150.0, False), "collided": True},
        ("pd", "water", None, 100.0, 0): _result(2.0),
        ("pd", "water", None, 100.0, 1): _result(3.0),
        ("random", "water", None, 100.0, 0): _result(100.0, False),
        ("random", "water", None, 100.0, 1): _result(100.0, False),
    }
    names = ("pd", "random")
    (ketchup,) = pouring.liquid_table(results, names, ("ketchup",), (150.0,), 2)
    (water,) = pouring.liquid_table(results, names, ("water",), (100.0,), 2)
    assert ketchup["thesis_lstm_g"] is None and ketchup["thesis_fnn_g"] is None  # never reached
    assert (ketchup["pd_g"], ketchup["pd_success"], ketchup["random_g"]) == (8.0, 0.5, 150.0)
    assert ketchup["flags"] == "random: collided 1"
    assert (water["thesis_lstm_g"], water["thesis_fnn_g"]) == (2.3, 5.13)  # Table 6.3, 100 g
    assert (water["pd_g"], water["pd_success"], water["flags"]) == (2.5, 1.0, "")

    means = pouring.table_means([ketchup, water], ["thesis_lstm_g", "pd_g", "random_g"])
    # over every cell a policy's mean counts ketchup at 150 g, which the thesis never reached
    assert means["all"] == {"thesis_lstm_g": 2.3, "pd_g": 5.25, "random_g": 125.0}
    # over the cells the thesis filled, every column averages the same cells
    assert means["thesis_cells"] == {"thesis_lstm_g": 2.3, "pd_g": 2.5, "random_g": 100.0}

    novel = {("pd", "water", "mug", 50.0, s): _result(e, density=1.25) for s, e in ((0, 1), (1, 4))}
    (row,) = pouring.container_table(novel, ("pd",), ("mug",), 2)
    assert (row["pd_g"], row["pd_ml"]) == (2.5, 2.0)


def test_a_stopped_run_resumes_from_its_log(tmp_path, monkeypatch) -> None:
    """Cells logged under this SHA come from the log; only the rest run, each appended as it
    finishes; another commit runs them all again. The results come back by pour."""
    log = tmp_path / "episodes.jsonl"
    sha = pouring.git_sha()
    jobs = [("pd", "water", None, target, 2) for target in (50.0, 100.0, 150.0)]
    logged = {"pours": [_result(1.5), _result(2.5)]}
    log.write_text(json.dumps({"key": job_key(sha, jobs[0]), "result": logged}) + "\n")
    ran = []

    def fake_pours(*job):
        ran.append(job)
        return {"pours": [_result(2.0)] * job[4]}

    monkeypatch.setattr(pouring, "pours", fake_pours)
    results = pouring.run_episodes(jobs, log, sha, workers=1)
    assert ran == jobs[1:]
    assert len(results) == 6
    assert results[("pd", "water", None, 50.0, 1)]["error_g"] == 2.5
    assert results[("pd", "water", None, 150.0, 0)]["error_g"] == 2.0
    assert len(log.read_text().splitlines()) == 3
    ran.clear()
    pouring.run_episodes(jobs, log, sha, workers=1)
    assert ran == []
    pouring.run_episodes(jobs, log, "another commit", workers=1)
    assert ran == jobs


@pytest.mark.slow
def test_cells_give_the_same_numbers_in_one_process_or_two(tmp_path) -> None:
    """A cell's pours follow one another in one env, each seeing the running average error
    of those before it (its own included once it ends); each cell is a fresh env, so spread
    over two processes the cells give what they give in this one."""
    jobs = [("pd", "water", None, 50.0, 2), ("random", "water", None, 50.0, 1),
            ("pd", "honey", "mug", 50.0, 1)]  # fmt: skip
    here = pouring.run_episodes(jobs, tmp_path / "one.jsonl", "sha", workers=1)
    spread = pouring.run_episodes(jobs, tmp_path / "two.jsonl", "sha", workers=2)
    assert here.keys() == spread.keys() and len(here) == 4
    for pour in here:
        a, b = dict(here[pour]), dict(spread[pour])
        a.pop("wall_s"), b.pop("wall_s")
        assert a == b, pour
    first, second = here[("pd", "water", None, 50.0, 0)], here[("pd", "water", None, 50.0, 1)]
    assert first["average_error_g"] == pytest.approx(first["error_g"])
    assert second["average_error_g"] == pytest.approx((first["error_g"] + second["error_g"]) / 2)
    assert first["error_g"] <= 10.0 and here[("random", "water", None, 50.0, 0)]["error_g"] == 50.0


def test_a_local_ray_gives_the_local_runs_numbers(tmp_path) -> None:
    """The same cells as Ray tasks on a local Ray of 2 CPUs (other processes) give what
    they give in this process, so a table made with ``--ray`` is the local run's."""
    import os

    import ray

    def traced(*job):  # sent to the Ray workers by value; pouring.pours by reference
        return {"pid": os.getpid(), **pouring.pours(*job)}

    jobs = [("pd", "water", None, 50.0, 1), ("random", "water", None, 50.0, 1)]
    here = run_jobs(traced, jobs, tmp_path / "one.jsonl", "sha", "here")
    ray.init(num_cpus=2, include_dashboard=False)
    try:
        spread = run_jobs(traced, jobs, tmp_path / "ray.jsonl", "sha", "ray", ray_address="local")
    finally:
        ray.shutdown()
    assert {here[j].pop("pid") for j in jobs} == {os.getpid()}
    assert os.getpid() not in {spread[j].pop("pid") for j in jobs}
    for job in jobs:
        (a,), (b,) = here[job]["pours"], spread[job]["pours"]
        a, b = dict(a), dict(b)
        a.pop("wall_s"), b.pop("wall_s")
        assert a == b, job


@pytest.mark.slow
def test_quick_pouring_table_is_written(tmp_path, monkeypatch) -> None:
    """The quick variant: water at 100 g and two novel containers at 50 g, by the PD baseline
    (within 10 g) and the random policy (which never pours in the thesis' action mode)."""
    monkeypatch.chdir(tmp_path)
    args = argparse.Namespace(quick=True, no_write=False, out=str(tmp_path), json=False)
    assert pouring.run(args) == 0
    data = json.loads((tmp_path / "pouring.json").read_text())
    (row,) = data["rows"]
    assert row["thesis_lstm_g"] == 2.3 and row["pd_g"] <= 10.0 and row["random_g"] == 100.0
    assert len(data["novel_containers"]) == 2
    assert "## Novel containers" in (tmp_path / "pouring.md").read_text()


@pytest.mark.parametrize("name", shipped_policies())
def test_the_table_says_how_each_shipped_policy_was_trained(name) -> None:
    """The training issue allows a PD warm start or a denser reward for a shipped policy
    only if the table says which was used: the line follows the policy's metadata."""
    settings = policy_metadata(name)["settings"]
    line = pouring.describe(name)
    assert ("residual over the PD" in line) == bool(settings["residual"])
    assert ("per gram of final error" in line) == bool(settings["final_error_per_g"])
    assert f"curiosity {'on' if settings['icm'] else 'off'}" in line
    assert f"on {settings['num_envs']} worlds" in line


def test_the_training_line_names_the_start_and_the_reward(monkeypatch) -> None:
    settings = {
        "residual": 0.2,
        "warm_start_steps": 8000,
        "final_error_per_g": 0.02,
        "icm": True,
        "curriculum": False,
        "num_envs": 32,
    }
    meta = {
        "algorithm": "recurrent_ppo",
        "policy": "lstm",
        "steps": 1000,
        "wall_time_s": 60.4,
        "settings": settings,
        "checkpoint": {"file": "best_model.zip", "timesteps": 640},
    }
    import pourbench.agents.loading as loading

    monkeypatch.setattr(loading, "policy_metadata", lambda name: meta)
    assert pouring.describe("x") == (
        "`x`: recurrent_ppo (lstm), 1000 steps in 60 s on 32 worlds, a residual over the PD "
        "baseline (scale 0.2), reward Algorithm 5 + 0.02 per gram of final error, curiosity "
        "on, curriculum off, checkpoint best_model.zip at 640 steps."
    )
    monkeypatch.setitem(settings, "residual", 0.0)
    monkeypatch.setitem(settings, "final_error_per_g", 0.0)
    line = pouring.describe("x")
    assert "cloned from 8000 steps of the PD" in line and "reward Algorithm 5," in line
    assert "gSDE" not in line
    monkeypatch.setitem(settings, "sde", True)
    assert "of the PD, exploring with gSDE, reward" in pouring.describe("x")
    monkeypatch.setitem(settings, "progress_per_g", 0.05)
    monkeypatch.setitem(settings, "directed_tilt", True)
    assert "+ 0.05 per gram of progress, the directed tilt, curiosity on" in pouring.describe("x")
    monkeypatch.setitem(settings, "directed_tilt", False)
    monkeypatch.setitem(settings, "tilt_target", True)
    monkeypatch.setitem(settings, "directed_approach", True)
    line = pouring.describe("x")
    assert "progress, the tilt target, the directed approach, curiosity on" in line
    monkeypatch.setitem(settings, "ent_coef", 0.015)
    assert "exploring with gSDE, entropy coefficient 0.015, reward" in pouring.describe("x")


def test_a_novel_container_too_small_for_the_target_is_named_not_averaged() -> None:
    small = {"too_small": "target_g=50 g is more than container 'spoon' holds 3 g"}
    results = {
        **{("pd", "water", "spoon", 50.0, s): small for s in range(2)},
        **{("pd", "water", "mug", 50.0, s): _result(2.0 * (s + 1)) for s in range(2)},
    }
    spoon, mug = pouring.container_table(results, ("pd",), ("spoon", "mug"), 2)
    assert spoon == {"container": "spoon", "pd_g": None, "pd_ml": None, "note": small["too_small"]}
    assert mug == {"container": "mug", "pd_g": 3.0, "pd_ml": 3.0, "note": ""}


def test_the_table_points_to_the_from_scratch_runs(tmp_path) -> None:
    """The training issue asks that the from-scratch runs be shown beside the shipped
    policies: the line quotes the ablation's final evaluations with their spread and the
    reward they trained on, or says how to make them."""
    assert "run `pourbench bench ablation`" in pouring.ablation_line(tmp_path)
    rows = [
        {
            "variant": v,
            "steps": n,
            "final_eval_error_g": e,
            "final_eval_sd_g": sd,
            "random_eval_error_g": 86.26,
        }
        for v, n, e, sd in (("ppo", 200704, 37.164, 24.11), ("td3", 200000, 96.21, 2.764))
    ]
    (tmp_path / "ablation.json").write_text(json.dumps({"git_sha": "abc1234", "rows": rows}))
    line = pouring.ablation_line(tmp_path)
    assert "`ppo` 37.16 ± 24.11 g, `td3` 96.21 ± 2.76 g (mean" in line
    assert "at `abc1234`, 200000–200704 steps a run" in line and "errs by 86.26 g" in line
    assert "shaping 1 + 0.05 per gram of progress" in line
