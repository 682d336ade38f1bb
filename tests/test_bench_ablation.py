"""``pourbench bench ablation``: training runs that differ only in curiosity and the
curriculum, and an off-policy learner, over seeds; their table and figure, and a finished
run read back instead of retrained."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from pourbench.bench import ablation
from pourbench.errors import InvalidParameterError


def test_the_variants_differ_only_in_curiosity_and_curriculum() -> None:
    assert ablation.VARIANTS == {
        "ppo": {"icm": False, "curriculum": False},
        "ppo_icm": {"icm": True, "curriculum": False},
        "ppo_icm_curriculum": {"icm": True, "curriculum": True},
    }


def test_the_off_policy_variant_is_sac_on_water_with_the_same_terms() -> None:
    assert ablation.variant_names() == ["ppo", "ppo_icm", "ppo_icm_curriculum", "sac"]
    assert ablation.settings("ppo_icm") == {
        "algorithm": "recurrent_ppo",
        "policy": "lstm",
        "icm": True,
        "curriculum": False,
        **ablation.DENSE,
    }
    sac = ablation.settings("sac")
    assert sac["algorithm"] == "sac" and not sac["icm"] and not sac["curriculum"]
    same = {k: v for k, v in ablation.DENSE.items() if k != "directed_tilt"}
    assert {k: sac[k] for k in same} == same
    assert sac["tilt_target"] and not sac["directed_tilt"] and sac["directed_approach"]
    assert sac["ent_coef"] > 0 and sac["utd"] > 0
    from pourbench.agents.train import TrainArgs

    for name in ablation.variant_names():
        # combinations the training accepts, at the ablation's step budget
        TrainArgs(**ablation.settings(name), budget_steps=ablation.BUDGET_STEPS)


def _run(evals: list[tuple[float, float]], train_s: list[float], pours) -> dict:
    return {
        "eval/mean_abs_error_g": evals,
        "eval/train_s": [(s, t) for (s, _), t in zip(evals, train_s, strict=True)],
        "pour/error_g": pours,
    }


def test_a_row_holds_the_seeds_final_and_best_evaluations(tmp_path) -> None:
    def result(steps: int, train_s: float, final_g: float) -> dict:
        return {
            "timesteps": steps,
            "total_train_s": train_s,
            "mean_abs_error_g": final_g,
            "random_mean_abs_error_g": 120.0,
        }

    results = {"ppo": [result(1000, 1800.0, 12.0), result(1002, 3600.0, 20.0)]}
    runs = {
        "ppo": [
            _run([(100.0, 40.0), (200.0, 9.0)], [900.0, 1800.0], [(950.0, 30.0), (1000.0, 40.0)]),
            _run([(102.0, 60.0), (204.0, 30.0)], [1800.0, 3600.0], [(64.0, 80.0), (990.0, 50.0)]),
        ]
    }
    (row,) = ablation.rows_of(results, runs)
    assert row == {
        "variant": "ppo",
        "seeds": 2,
        "steps": 1001,
        "train_h": 0.75,
        "final_eval_error_g": 16.0,
        "final_eval_sd_g": 4.0,
        "best_eval_error_g": 9.0,
        "final_training_error_g": 40.0,  # the points past 900 steps of each run
        "first_step_at_10g": "200, never",
        "random_eval_error_g": 120.0,
    }
    by_steps = ablation.band(runs["ppo"], "eval/mean_abs_error_g")
    np.testing.assert_allclose(by_steps, [[101, 50, 40, 60], [202, 19.5, 9, 30]])
    by_time = ablation.band(runs["ppo"], "eval/mean_abs_error_g", "eval/train_s")
    np.testing.assert_allclose(by_time[:, 0], [1350.0, 2700.0])
    png = ablation.plot(runs, tmp_path / "a.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_finished_run_evaluated_on_other_liquids_is_refused_not_read_back(tmp_path) -> None:
    """A curriculum run evaluated on Table 6.2's six liquids (train's default) does not enter
    the water table; the error names the folder and nothing is overwritten."""
    out = tmp_path / "full" / "ppo_icm_curriculum" / "seed0"
    out.mkdir(parents=True)
    args = {"curriculum": True, "liquid": "water", "out": str(out)}  # no eval_liquid: default
    written = json.dumps({"timesteps": 200_000, "args": args})
    (out / "result.json").write_text(written)
    with pytest.raises(
        InvalidParameterError,
        match="evaluated on water, ink, oil, glycerine, honey, ketchup, not water",
    ):
        ablation.train_variant("ppo_icm_curriculum", 0, quick=False, runs=tmp_path)
    assert (out / "result.json").read_text() == written


def test_a_finished_run_with_other_settings_is_refused_not_read_back(tmp_path) -> None:
    """A run finished before its variant's settings changed is not read back as the new
    variant: the error names each setting that differs, and nothing is overwritten."""
    out = tmp_path / "full" / "ppo" / "seed0"
    out.mkdir(parents=True)  # a run of the thesis' reward alone, before the dense terms
    args = {
        "algorithm": "recurrent_ppo",
        "policy": "lstm",
        "icm": False,
        "curriculum": False,
        "eval_liquid": "water",
    }
    written = json.dumps({"timesteps": 200_000, "args": args})
    (out / "result.json").write_text(written)
    with pytest.raises(InvalidParameterError, match=r"shaping=0\.0, not 1\.0, progress_per_g"):
        ablation.train_variant("ppo", 0, quick=False, runs=tmp_path)
    assert (out / "result.json").read_text() == written


@pytest.mark.slow
def test_quick_ablation_trains_every_variant_and_reads_them_back(tmp_path, monkeypatch, capsys):
    """The quick variant trains each variant once (seed 0, 256 steps), writes the table and
    the figure, and a second call reads the finished runs back instead of training again.
    With --json, stdout is the one JSON object even while it trains (training logs to
    stderr)."""
    monkeypatch.chdir(tmp_path)
    args = argparse.Namespace(quick=True, no_write=False, out=str(tmp_path / "lb"), json=True)
    assert ablation.run(args) == 0
    assert isinstance(json.loads(capsys.readouterr().out), dict)
    data = json.loads((tmp_path / "lb" / "ablation.json").read_text())
    assert [r["variant"] for r in data["rows"]] == ablation.variant_names()
    assert all(r["steps"] >= 256 and r["seeds"] == 1 for r in data["rows"])
    assert (tmp_path / "lb" / "ablation.png").is_file()
    for name in ablation.variant_names():
        folder = tmp_path / "runs/ablation/quick" / name / "seed0"
        state = json.loads((folder / "state.json").read_text())
        chosen = {k: v for k, v in ablation.settings(name).items() if k != "num_envs"}
        assert {k: state["args"][k] for k in chosen} == chosen
        assert state["args"]["seed"] == 0 and state["args"]["budget_steps"] == 256
        assert state["args"]["eval_liquid"] == "water"
        assert ablation.curves(folder)["eval/train_s"]  # the wall time beside each evaluation
    capsys.readouterr()
    assert ablation.run(args) == 0
    assert capsys.readouterr().err.count("read back") == len(ablation.variant_names())


def test_a_finished_run_keeps_a_record_that_a_fresh_clone_reads_back(tmp_path, monkeypatch):
    """A full run that reaches the budget writes its result and curves beside the report; a
    clone without the runs folder reads the record back instead of training, and a record of
    other settings is refused like a run."""
    trained = []

    def train_once(name, seed, quick, runs):
        out = runs / "full" / name / f"seed{seed}"
        (out / "logs" / "0").mkdir(parents=True)
        (out / "logs" / "0" / "progress.csv").write_text(
            "time/total_timesteps,eval/mean_abs_error_g,eval/train_s,pour/error_g\n"
            "100000,40.5,1800,\n200000,9.5,3600,12.0\n"
        )
        trained.append((name, seed))
        args = {**ablation.settings(name), "budget_steps": ablation.BUDGET_STEPS}
        args |= {"eval_liquid": "water", "out": str(out)}
        return {"timesteps": ablation.BUDGET_STEPS, "args": args, "mean_abs_error_g": 9.5}

    monkeypatch.setattr(ablation, "train_variant", train_once)
    records = tmp_path / "lb" / ablation.RECORDS
    result, series = ablation.finished_run("ppo", 1, False, tmp_path / "runs", records)
    assert trained == [("ppo", 1)] and result["mean_abs_error_g"] == 9.5
    assert series["eval/mean_abs_error_g"] == [(100000.0, 40.5), (200000.0, 9.5)]
    assert (records / "ppo-seed1.json").is_file()

    import shutil

    shutil.rmtree(tmp_path / "runs")  # a fresh clone: the record alone
    again = ablation.finished_run("ppo", 1, False, tmp_path / "runs", records)
    assert trained == [("ppo", 1)] and again == (result, series)

    record = json.loads((records / "ppo-seed1.json").read_text())
    others = [
        ("icm", True, "icm=True, not False"),
        ("budget_steps", 400_000, "budget_steps=400000, not 200000"),
    ]
    for key, other, said in others:
        changed = json.loads(json.dumps(record))
        changed["result"]["args"][key] = other  # another variant, or another step-size fall
        (records / "ppo-seed1.json").write_text(json.dumps(changed))
        with pytest.raises(InvalidParameterError, match=rf"ppo-seed1\.json.*{said}"):
            ablation.finished_run("ppo", 1, False, tmp_path / "runs", records)
    assert trained == [("ppo", 1)]


def test_the_committed_records_are_runs_of_the_ablation_as_it_stands() -> None:
    """Every record in leaderboard/ablation_runs/ was trained with its variant's settings and
    budget and reached it: the next ablation reads it back rather than refusing it."""
    from pathlib import Path

    records = Path(__file__).parents[1] / "leaderboard" / ablation.RECORDS
    for path in sorted(records.glob("*-seed*.json")):
        name, seed = path.stem.rsplit("-seed", 1)
        result, series = ablation.finished_run(name, int(seed), False, records=records)
        assert result["timesteps"] >= ablation.BUDGET_STEPS
        assert len(series["eval/mean_abs_error_g"]) == 10, path


def test_finished_reports_the_recorded_runs_and_trains_none(tmp_path, monkeypatch) -> None:
    """``--finished`` builds the table and figure from the records alone: a variant without
    one is left out of the table and named as not yet trained, and nothing is trained."""
    import shutil
    from pathlib import Path

    def refuse(*_):
        raise AssertionError("--finished trained a run")

    monkeypatch.setattr(ablation, "train_variant", refuse)
    committed = Path(__file__).parents[1] / "leaderboard" / ablation.RECORDS
    records = tmp_path / "lb" / ablation.RECORDS
    records.mkdir(parents=True)
    for stem in ("ppo-seed0", "ppo-seed1", "ppo_icm-seed0"):
        shutil.copy(committed / f"{stem}.json", records)
    args = argparse.Namespace(
        quick=False, no_write=False, out=str(tmp_path / "lb"), json=False, finished=True
    )
    assert ablation.run(args) == 0
    data = json.loads((tmp_path / "lb" / "ablation.json").read_text())
    assert [(r["variant"], r["seeds"]) for r in data["rows"]] == [("ppo", 2), ("ppo_icm", 1)]
    kept = json.loads((records / "ppo-seed1.json").read_text())
    assert data["rows"][0]["best_eval_error_g"] <= kept["result"]["mean_abs_error_g"]
    report = (tmp_path / "lb" / "ablation.md").read_text()
    assert "not yet trained `ppo_icm_curriculum` seed 0" in report and "`sac` seed 2" in report
    assert (tmp_path / "lb" / "ablation.png").is_file()

    empty = argparse.Namespace(**{**vars(args), "out": str(tmp_path / "none")})
    with pytest.raises(InvalidParameterError, match="no finished run's record"):
        ablation.run(empty)
    with pytest.raises(InvalidParameterError, match="not with --quick"):
        ablation.run(argparse.Namespace(**{**vars(args), "quick": True}))


def test_runs_logged_at_different_steps_are_matched_by_step() -> None:
    """Training curves of seeds that logged at different steps (an off-policy run logs every
    few episodes) are compared at the same steps over the whole budget, not cut to the
    shortest run's number of entries."""
    sparse = {"pour/error_g": [(0.0, 100.0), (100.0, 50.0), (200.0, 10.0)]}
    dense = {"pour/error_g": [(float(s), 100.0 - 0.25 * s) for s in range(0, 201, 10)]}
    rows = ablation.band([sparse, dense], "pour/error_g")
    np.testing.assert_array_equal(rows[:, 0], [0.0, 100.0, 200.0])
    np.testing.assert_allclose(rows[:, 1], [100.0, 62.5, 30.0])  # means at those steps
    np.testing.assert_allclose(rows[:, 2], [100.0, 50.0, 10.0])
    np.testing.assert_allclose(rows[:, 3], [100.0, 75.0, 50.0])
