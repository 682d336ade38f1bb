"""``pourbench bench ablation``: three training runs that differ only in curiosity and the
curriculum, their table and figure, and a finished run read back instead of retrained."""

from __future__ import annotations

import argparse
import json

import pytest

from pourbench.bench import ablation


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
            "pour/average_error_g": [(64.0, 80.0), (128.0, 30.0)],
        }
    }
    (row,) = ablation.rows_of({"ppo": result}, runs)
    assert row == {
        "variant": "ppo",
        "steps": 1000,
        "train_h": 0.5,
        "final_eval_error_g": 12.0,
        "best_eval_error_g": 9.0,
        "final_average_error_g": 30.0,
        "random_eval_error_g": 120.0,
    }
    png = ablation.plot(runs, tmp_path / "a.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_quick_ablation_trains_three_runs_and_reads_them_back(tmp_path, monkeypatch, capsys):
    """The quick variant trains the three runs (256 steps each), writes the table and the
    figure, and a second call reads the finished runs back instead of training again."""
    monkeypatch.chdir(tmp_path)
    args = argparse.Namespace(quick=True, no_write=False, out=str(tmp_path / "lb"), json=False)
    assert ablation.run(args) == 0
    data = json.loads((tmp_path / "lb" / "ablation.json").read_text())
    assert [r["variant"] for r in data["rows"]] == list(ablation.VARIANTS)
    assert all(r["steps"] == 256 for r in data["rows"])
    assert (tmp_path / "lb" / "ablation.png").is_file()
    for name, flags in ablation.VARIANTS.items():
        state = json.loads((tmp_path / "runs/ablation/quick" / name / "state.json").read_text())
        assert {k: state["args"][k] for k in flags} == flags
        assert state["args"]["seed"] == 0 and state["args"]["budget_steps"] == 256
    capsys.readouterr()
    assert ablation.run(args) == 0
    assert capsys.readouterr().err.count("read back") == 3
