"""The PPO training script: refuses bad input before any work, never overwrites a model,
checkpoints and resumes (step counter carried on)."""

from __future__ import annotations

import json

import pytest

from pourbench.agents.train import main

TINY = ["--budget-s", "2", "--num-envs", "1", "--n-steps", "16", "--eval-episodes", "1"]


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--liquid", "lava"], "unknown liquid 'lava'"),
        (["--budget-s", "nan"], "budget_s"),
        (["--budget-s", "-1"], "budget_s"),
        (["--num-envs", "0"], "num_envs"),
        (["--eval-episodes", "0"], "eval_episodes"),
        (["--seed", "-3"], "seed"),
        (["--resume"], "no model to resume"),
    ],
)
def test_bad_input_is_one_clear_line(tmp_path, capsys, argv, words) -> None:
    assert main([*argv, "--out", str(tmp_path / "run")]) == 2
    assert words in capsys.readouterr().err


def test_an_output_path_that_is_a_file_is_refused(tmp_path, capsys) -> None:
    a_file = tmp_path / "afile"
    a_file.write_text("keep me")
    assert main(["--out", str(a_file)]) == 2
    assert "is a file" in capsys.readouterr().err and a_file.read_text() == "keep me"


@pytest.mark.slow
def test_training_resumes_and_never_overwrites(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert main([*TINY, "--out", str(out)]) == 0
    first = json.loads((out / "result.json").read_text())["timesteps"]
    model = (out / "model.zip").read_bytes()
    assert main([*TINY, "--out", str(out)]) == 2  # a second run into the same folder
    assert "pass --resume" in capsys.readouterr().err
    assert (out / "model.zip").read_bytes() == model
    assert main([*TINY, "--out", str(out), "--resume"]) == 0
    assert json.loads((out / "result.json").read_text())["timesteps"] > first
    assert not list(out.glob("*.partial*"))
