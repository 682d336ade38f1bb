"""``pourbench bench ablation``: three training runs that differ only in curiosity and the
curriculum, their table and figure, and a finished run read back instead of retrained."""

from __future__ import annotations

import argparse
import json

import pytest

from pourbench.bench import ablation
from pourbench.errors import InvalidParameterError


def test_the_variants_differ_only_in_curiosity_and_curriculum() -> None:
    assert ablation.VARIANTS == {
        "ppo": {"icm": False, "curriculum": False},
        "ppo_icm": {"icm": True, "curriculum": False},
        "ppo_icm_curriculum": {"icm": True, "curriculum": True},
    }


def test_a_row_holds_the_final_and_best_evaluation(tmp_path) -> None:
    result = {
        "timesteps": 1000,
        "total_train_s": 1800.0,
        "mean_abs_error_g": 12.0,
        "random_mean_abs_error_g": 120.0,
    }
    runs = {
        "ppo": {
            "eval/mean_abs_error_g": [(100.0, 40.0), (200.0, 9.0)],
            "pour/error_g": [(64.0, 80.0), (900.0, 50.0), (950.0, 30.0), (1000.0, 40.0)],
        }
    }
    (row,) = ablation.rows_of({"ppo": result}, runs)
    assert row == {
        "variant": "ppo",
        "steps": 1000,
        "train_h": 0.5,
        "final_eval_error_g": 12.0,
        "best_eval_error_g": 9.0,
        "final_training_error_g": 35.0,  # the points past 900 of 1000 steps
        "random_eval_error_g": 120.0,
    }
    png = ablation.plot(runs, tmp_path / "a.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_finished_run_evaluated_on_other_liquids_is_refused_not_read_back(tmp_path) -> None:
    """A curriculum run evaluated on Table 6.2's six liquids (train's default) does not enter
    the water table; the error names the folder and nothing is overwritten."""
    out = tmp_path / "full" / "ppo_icm_curriculum"
    out.mkdir(parents=True)
    args = {"curriculum": True, "liquid": "water", "out": str(out)}  # no eval_liquid: default
    written = json.dumps({"timesteps": 200_000, "args": args})
    (out / "result.json").write_text(written)
    with pytest.raises(
        InvalidParameterError,
        match="evaluated on water, ink, oil, glycerine, honey, ketchup, not water",
    ):
        ablation.train_variant("ppo_icm_curriculum", quick=False, runs=tmp_path)
    assert (out / "result.json").read_text() == written


@pytest.mark.slow
def test_quick_ablation_trains_three_runs_and_reads_them_back(tmp_path, monkeypatch, capsys):
    """The quick variant trains the three runs (256 steps each), writes the table and the
    figure, and a second call reads the finished runs back instead of training again. With
    --json, stdout is the one JSON object even while it trains (training logs to stderr)."""
    monkeypatch.chdir(tmp_path)
    args = argparse.Namespace(quick=True, no_write=False, out=str(tmp_path / "lb"), json=True)
    assert ablation.run(args) == 0
    assert isinstance(json.loads(capsys.readouterr().out), dict)
    data = json.loads((tmp_path / "lb" / "ablation.json").read_text())
    assert [r["variant"] for r in data["rows"]] == list(ablation.VARIANTS)
    assert all(r["steps"] == 256 for r in data["rows"])
    assert (tmp_path / "lb" / "ablation.png").is_file()
    for name, flags in ablation.VARIANTS.items():
        state = json.loads((tmp_path / "runs/ablation/quick" / name / "state.json").read_text())
        assert {k: state["args"][k] for k in flags} == flags
        assert state["args"]["seed"] == 0 and state["args"]["budget_steps"] == 256
        assert state["args"]["eval_liquid"] == "water"
    capsys.readouterr()
    assert ablation.run(args) == 0
    assert capsys.readouterr().err.count("read back") == 3
