"""The PPO training script: refuses bad input before any work, never overwrites a model,
checkpoints and resumes (step counter carried on)."""

from __future__ import annotations

import argparse
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
        (["--n-steps", "1", "--num-envs", "1"], "n_steps * num_envs"),
        (["--threads", "0"], "threads must be >= 1"),
        (["--resume"], "no model to resume"),
    ],
)
def test_bad_input_is_one_clear_line(tmp_path, capsys, argv, words) -> None:
    assert main([*argv, "--out", str(tmp_path / "run")]) == 2
    assert words in capsys.readouterr().err


def test_pourbench_train_takes_the_same_flags(tmp_path, capsys) -> None:
    from dataclasses import fields

    from pourbench.agents.train import TrainArgs
    from pourbench.cli import build_parser
    from pourbench.cli import main as cli_main

    assert cli_main(["train", "--num-envs", "0", "--out", str(tmp_path / "run")]) == 2
    assert "num_envs must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
    parser = build_parser()
    args = parser.parse_args(["train", "--budget-s", "30", "--resume"])
    assert (args.budget_s, args.resume, args.num_envs) == (30.0, True, TrainArgs().num_envs)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help for a in sub.choices["train"]._actions}
    for f in fields(TrainArgs):  # every setting has its line of help
        assert helps[f.name] and "default" not in helps[f.name], f.name


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


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"eval_episodes": 1.5}, "eval_episodes must be an integer, got 1.5"),
        ({"num_envs": 1.5}, "num_envs must be an integer, got 1.5"),
        ({"num_envs": True}, "num_envs must be an integer, got True"),
        ({"num_envs": float("nan")}, "num_envs must be an integer, got nan"),
        ({"n_steps": 2.5}, "n_steps must be an integer, got 2.5"),
        ({"threads": 0}, "threads must be >= 1"),
        ({"seed": 1.5}, "seed must be an integer, got 1.5"),
        ({"seed": float("nan")}, "seed must be an integer, got nan"),
        ({"seed": True}, "seed must be an integer, got True"),
        ({"seed": None}, "seed must be an integer, got None"),
        ({"budget_s": "5"}, "budget_s must be a number, got '5'"),
        ({"target_g": float("inf")}, "target_g must be finite"),
        ({"checkpoint_s": 0}, "checkpoint_s must be > 0"),
        ({"resume": "no"}, "resume must be True or False, got 'no'"),
        ({"out": None}, "out must be a non-empty folder path, got None"),
        ({"out": ""}, "out must be a non-empty folder path"),
        ({"liquid": None}, "liquid must be a liquid name"),
        ({"n_steps": 1, "num_envs": 1}, r"n_steps \* num_envs .* must be >= 2"),
    ],
)
def test_bad_settings_are_refused_before_any_training(kw, words) -> None:
    """Refused when the settings are made: a run never trains (and saves a model) only to
    fail in its evaluation and leave the model without result.json."""
    from pourbench.agents.train import TrainArgs

    with pytest.raises(ValueError, match=words):
        TrainArgs(**kw)


def test_good_settings_are_kept() -> None:
    from pathlib import Path

    from pourbench.agents.train import TrainArgs

    args = TrainArgs(n_steps=2, num_envs=1, seed=0, out=Path("runs") / "x", budget_s=5)
    assert (args.out, args.budget_s, args.n_steps) == (str(Path("runs/x")), 5, 2)


def test_resuming_a_corrupt_model_names_the_file(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "model.zip").write_text("not a model")
    assert main([*TINY, "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "model.zip" in err and "is not a readable PPO model" in err
    assert (out / "model.zip").read_text() == "not a model"
    assert sorted(p.name for p in out.iterdir()) == ["model.zip"]
