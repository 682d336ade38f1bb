"""The training command: refuses bad input before any work, naming the value; never
overwrites a model; trains, checkpoints, resumes (step counter and ICM carried on) and plots."""

from __future__ import annotations

import json
import re
from dataclasses import asdict, replace

import numpy as np
import pytest

from pourbench.agents.train import main

TINY = ["--budget-s", "2", "--num-envs", "1", "--n-steps", "16", "--eval-episodes", "1"]
LSTM = ["--algorithm", "recurrent_ppo", "--policy", "lstm"]
SMALL = ["--num-envs", "2", "--workers", "1", "--n-steps", "32", "--batch-size", "64"]


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--liquid", "lava"], "unknown liquid 'lava'"),
        (["--eval-liquid", "lava"], "unknown liquid 'lava'"),
        (["--budget-s", "nan"], "budget_s"),
        (["--budget-s", "-1"], "budget_s"),
        (["--num-envs", "0"], "num_envs"),
        (["--eval-episodes", "0"], "eval_episodes"),
        (["--seed", "-3"], "seed"),
        (["--n-steps", "1", "--num-envs", "1"], "n_steps * num_envs"),
        (["--threads", "0"], "threads must be >= 1"),
        (["--resume"], "no model to resume"),
        (
            ["--algorithm", "a2c"],
            "algorithm must be one of ['ppo', 'recurrent_ppo', 'sac', 'tqc', 'crossq', 'td3'], "
            "got 'a2c'",
        ),
        (["--policy", "cnn"], "policy must be one of ['mlp', 'lstm'], got 'cnn'"),
        (["--budget-steps", "-5"], "budget_steps must be >= 1, got -5"),
        (["--budget-s", "-2"], "budget_s must be > 0, got -2.0"),
        (["--budget-steps", "10", "--budget-s", "5"], "give one budget"),
        (
            ["--algorithm", "recurrent_ppo", "--policy", "lstm", "--seq-len", "128"],
            "seq_len=128 is longer than the rollout, n_steps=64",
        ),
        (
            ["--algorithm", "recurrent_ppo", "--policy", "lstm", "--n-steps", "128"],
            "seq_len=64 is shorter than the rollout, n_steps=128",
        ),
        (["--policy", "lstm"], "policy 'lstm' does not go with algorithm 'ppo'"),
        (["--algorithm", "sac"], "algorithm 'sac' trains without the curiosity module"),
        (["--utd", "0.5"], "utd=0.5 sets an off-policy learner's updates"),
        (["--algorithm", "tqc", "--no-icm", "--utd", "-1"], "utd must be >= 0"),
        (["--ent-coef", "0.01"], "ent_coef=0.01 fixes the entropy coefficient of sac"),
        (["--algorithm", "td3", "--no-icm", "--ent-coef", "0.01"], "td3 has none to fix"),
        (["--algorithm", "sac", "--no-icm", "--ent-coef", "-1"], "ent_coef must be >= 0"),
        (["--algorithm", "crossq", "--no-icm", "--sde"], "CrossQ explores with its own noise"),
        (["--algorithm", "td3", "--no-icm", "--sde"], "TD3 explores with its own noise"),
        (["--algorithm", "sac", "--no-icm", "--init-std", "0.3"], "init_std=0.3 sets the spread"),
        (["--init-std", "0.3", "--residual", "0.2"], "init_std=0.3 sets the spread"),
        (["--init-std", "-1"], "init_std must be >= 0"),
        (["--workers", "3", "--num-envs", "2"], "workers=3 is more than num_envs=2"),
        (["--device", "tpu"], "device must be 'cpu' or 'cuda', got 'tpu'"),
        (["--target-g", "-5"], "target_g must be > 0, got -5.0"),
    ],
)
def test_bad_input_is_one_clear_line(tmp_path, capsys, argv, words) -> None:
    assert main([*argv, "--out", str(tmp_path / "run")]) == 2
    assert words in capsys.readouterr().err


def test_training_on_cuda_without_a_gpu_is_refused(tmp_path, capsys) -> None:
    from pourbench.fluids.solver import cuda_available

    if cuda_available():
        pytest.skip("this machine has a CUDA device")
    assert main(["--device", "cuda", "--out", str(tmp_path / "run")]) == 2
    assert "device='cuda': Warp sees no CUDA device" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_pourbench_train_takes_the_same_flags(tmp_path, capsys) -> None:
    from dataclasses import fields

    from pourbench.agents.train import TrainArgs, parse_args
    from pourbench.cli import main as cli_main

    assert cli_main(["train", "--num-envs", "0", "--out", str(tmp_path / "run")]) == 2
    assert "pourbench train: error: num_envs must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
    args = parse_args(["--budget-s", "30", "--resume", "--no-icm"], "pourbench train")
    assert (args.budget_s, args.resume, args.icm, args.num_envs) == (30.0, True, False, 32)
    with pytest.raises(SystemExit):
        cli_main(["train", "--help"])
    helps = " ".join(capsys.readouterr().out.split())
    for f in fields(TrainArgs):  # every setting has its flag and its line of help
        assert f"--{f.name.replace('_', '-')}" in helps, f.name
    assert "training budget in wall-clock seconds over all sessions" in helps


def test_an_output_path_that_is_a_file_is_refused(tmp_path, capsys) -> None:
    a_file = tmp_path / "afile"
    a_file.write_text("keep me")
    assert main(["--out", str(a_file)]) == 2
    assert "is a file" in capsys.readouterr().err and a_file.read_text() == "keep me"


@pytest.mark.slow
def test_init_std_starts_a_policy_from_scratch_with_that_spread(tmp_path) -> None:
    """``--init-std 0.3``: the saved model's spread per action is 0.3 after one rollout's
    update (PPO moves log σ by far less than the 1.2 between SB3's σ = 1 and 0.3), and the
    policy's mean is untouched (not a residual, no head zeroed)."""
    from pourbench.agents.loading import load_model

    out = tmp_path / "run"
    argv = [*SMALL, "--no-icm", "--no-curriculum", "--budget-steps", "64", "--eval-episodes"]
    assert main([*argv, "1", "--init-std", "0.3", "--out", str(out)]) == 0
    model = load_model(out / "model.zip")
    std = model.policy.log_std.exp().detach().numpy()
    np.testing.assert_allclose(std, [0.3, 0.3], rtol=0.05)
    assert model.policy.action_net.weight.abs().sum() > 0.0


@pytest.mark.slow
def test_a_tiny_run_trains_checkpoints_resumes_and_plots(tmp_path, capsys) -> None:
    """PPO + ICM + curriculum for 256 steps, then resumed to 512: the step count, the ICM
    and the lesson carry on, each session logs what TensorBoard shows, the plot is written."""
    import csv

    import torch

    out = tmp_path / "run"
    run = [*SMALL, "--eval-episodes", "1", "--eval-every-steps", "128", "--out", str(out)]
    assert main([*run, "--budget-steps", "256"]) == 0
    state = json.loads((out / "state.json").read_text())
    assert state["timesteps"] == 256 and state["sessions"] == 1
    result = json.loads((out / "result.json").read_text())
    assert result["timesteps"] == 256
    # the PD baseline and the random policy on the same episodes as the policy
    assert result["pd_mean_abs_error_g"] < result["random_mean_abs_error_g"]
    model = (out / "model.zip").read_bytes()
    icm = torch.load(out / "icm.pt", weights_only=True)["icm"]
    assert (out / "training.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "lesson 1 (oil-like) from step 64" in printed
    assert "lesson 2 (honey-like) from step 128" in printed
    assert "evaluation at 128 steps" in printed and "evaluation at 256 steps" in printed
    # a curriculum run is evaluated on Table 6.2's six liquids, here one pour of each
    assert re.search(r"evaluation at 128 steps: .* over 6 episodes", printed)
    # the best of the evaluations at 128 and 256 steps and the final one is kept
    errors = [
        float(e) for e in re.findall(r"evaluation at \d+ steps: mean abs error ([\d.]+)", printed)
    ]
    best = result["best"]
    assert best == json.loads((out / "state.json").read_text())["best"]
    final = result["mean_abs_error_g"]  # the final evaluation, after the last update
    assert best["eval_mean_abs_error_g"] == pytest.approx(min([*errors, final]), abs=0.005)
    assert best["timesteps"] in (128, 256) and (out / "best_model.zip").is_file()
    with open(out / "logs" / "0" / "progress.csv") as f:
        rows = list(csv.DictReader(f))
    keys = set(rows[0])
    for key in ("icm/inverse_loss", "icm/forward_loss", "icm/intrinsic_reward",
                "curriculum/lesson", "eval/mean_abs_error_g", "eval/success_rate",
                "eval/ketchup/mean_abs_error_g"):  # fmt: skip
        assert key in keys, key
    assert list((out / "logs" / "0").glob("events.out.tfevents.*"))

    assert main([*run, "--budget-steps", "256"]) == 2  # a second run into the same folder
    assert "pass --resume" in capsys.readouterr().err
    assert (out / "model.zip").read_bytes() == model
    assert main([*run, "--budget-steps", "256", "--resume"]) == 2  # nothing left to train
    assert "spent its budget" in capsys.readouterr().err
    assert main([*run, "--budget-steps", "512", "--resume", "--no-icm"]) == 2
    assert "has icm=True, not False" in capsys.readouterr().err

    assert main([*run, "--budget-steps", "512", "--resume"]) == 0
    printed = capsys.readouterr().out
    assert "resuming" in printed and "at 256 timesteps" in printed
    assert "curriculum: lesson 2 (honey-like) from step 256" in printed
    state = json.loads((out / "state.json").read_text())
    assert state["timesteps"] == 512 and state["sessions"] == 2
    assert [h["timesteps"] for h in state["history"]] == [256, 512]
    assert all(h["git_sha"] and h["machine"] and "--budget-steps" in h["command"]
               for h in state["history"])  # fmt: skip
    resumed = torch.load(out / "icm.pt", weights_only=True)["icm"]
    assert not torch.equal(resumed["encoder.0.weight"], icm["encoder.0.weight"])  # trained on
    assert resumed["obs_count"] > icm["obs_count"]  # from the saved statistics, not afresh
    assert (out / "logs" / "1" / "progress.csv").exists()
    assert not list(out.glob("*.partial*"))


def test_a_linear_schedule_falls_to_zero_at_the_end_of_the_budget(tmp_path) -> None:
    """Adam's step size at each update is the learning rate times the share of the step
    budget left (SB3 updates after each rollout of 64 steps here); a resumed run counts the
    steps it has taken against the budget it is given (a new run of 256 steps would start at
    0.875 of the rate, not 0.375)."""
    import csv

    out = tmp_path / "run"
    run = [
        *SMALL,
        *("--no-icm", "--no-curriculum", "--eval-episodes", "1", "--eval-every-steps", "0"),
        *("--lr-schedule", "linear", "--learning-rate", "0.001", "--out", str(out)),
    ]
    assert main([*run, "--budget-steps", "256"]) == 0
    assert main([*run, "--budget-steps", "512", "--resume"]) == 0
    rates = []
    for session in ("0", "1"):
        with open(out / "logs" / session / "progress.csv") as f:
            rows = csv.DictReader(f)
            rates += [float(r["train/learning_rate"]) for r in rows if r["train/learning_rate"]]
    # updates at 64, 128 and 192 steps of the 256-step budget, then at 320, 384 and 448 of
    # the 512-step one (SB3 logs an update with the next rollout, so a session's last is not)
    assert rates == pytest.approx([0.00075, 0.0005, 0.00025, 0.000375, 0.00025, 0.000125])


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"algorithm": "dqn"}, "algorithm must be one of .* got 'dqn'"),
        ({"budget_steps": 0}, "budget_steps must be >= 1, got 0"),
        ({"budget_steps": 1.5}, "budget_steps must be an integer, got 1.5"),
        ({"icm": "yes"}, "icm must be True or False, got 'yes'"),
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
        ({"eval_liquid": None}, "eval_liquid must be a liquid name or '', got None"),
        ({"n_steps": 1, "num_envs": 1}, r"n_steps \* num_envs .* must be >= 2"),
        ({"warm_start_steps": -1}, "warm_start_steps must be >= 0, got -1"),
        ({"clone_epochs": 0}, "clone_epochs must be >= 1, got 0"),
        ({"dagger_rounds": -1}, "dagger_rounds must be >= 0, got -1"),
        ({"dagger_rounds": 2}, "dagger_rounds=2 relabels .* needs warm_start_steps > 0"),
        ({"learning_rate": 0.0}, "learning_rate must be > 0"),
        ({"lr_schedule": "cosine"}, r"lr_schedule must be one of \['constant', 'linear'\]"),
        ({"lr_schedule": "linear", "budget_s": 60.0}, "lr_schedule='linear' runs over the step"),
        ({"target_kl": -0.01}, "target_kl must be >= 0"),
        ({"clone_std": -0.1}, "clone_std must be >= 0"),
        ({"warm_start_lessons": "some"}, "warm_start_lessons must be 'first' or 'all', got 'some'"),
        (
            {"clone_std": 0.03},
            "clone_std=0.03 is the cloned or residual policy's spread: .* warm_start",
        ),
        ({"final_error_per_g": float("nan")}, "final_error_per_g must be finite"),
        ({"sde": 1}, "sde must be True or False, got 1"),
        ({"rehearse": "yes"}, "rehearse must be True or False, got 'yes'"),
        ({"rehearse": True, "curriculum": False}, "rehearse=True draws .* needs the curriculum"),
        (
            {"algorithm": "sac", "icm": False, "curriculum": False, "target_kl": 0.02},
            "target_kl=0.02 limits PPO's updates; sac has none",
        ),
        (
            {"algorithm": "tqc", "icm": False, "curriculum": False, "warm_start_steps": 64},
            "warm_start_steps=64: the PD warm start clones into PPO or RecurrentPPO, not tqc",
        ),
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
    assert "state.json" in err and "missing or unreadable" in err
    (out / "state.json").write_text(json.dumps({"args": asdict(_args(TINY)), "timesteps": 0,
                                                "train_s": 0.0, "sessions": 1}))  # fmt: skip
    assert main([*TINY, "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "model.zip" in err and "is not a saved Stable-Baselines3 model" in err
    assert (out / "model.zip").read_text() == "not a model"
    assert sorted(p.name for p in out.iterdir()) == ["model.zip", "state.json"]


def _args(argv: list[str]):
    from pourbench.agents.train import parse_args

    return parse_args(argv, "pourbench train")


@pytest.mark.slow
@pytest.mark.parametrize(
    "flags, algorithm",
    [
        (
            [*LSTM, "--warm-start-steps", "64", "--clone-epochs", "2", "--dagger-rounds", "1"],
            "recurrent_ppo",
        ),
        (["--algorithm", "sac", "--no-icm", "--no-curriculum", "--tilt-target"], "sac"),
        (["--algorithm", "tqc", "--no-icm", "--utd", "0.5"], "tqc"),
        (["--algorithm", "crossq", "--no-icm", "--no-curriculum", "--utd", "1"], "crossq"),
    ],
)
def test_lstm_and_off_policy_runs_save_models_that_load_policy_reads(
    tmp_path, flags, algorithm
) -> None:
    import numpy as np

    from pourbench.agents import load_policy
    from pourbench.agents.loading import algorithm_of

    out = tmp_path / algorithm
    argv = [*SMALL, "--n-steps", "64", "--budget-steps", "128", "--eval-episodes", "1"]
    every = "128" if "--warm-start-steps" in flags else "0"
    assert main([*argv, *flags, "--eval-every-steps", every, "--out", str(out)]) == 0
    assert algorithm_of(out / "model.zip") == algorithm
    state = json.loads((out / "state.json").read_text())
    if "--warm-start-steps" in flags:  # 64 steps of 2 worlds' PD demonstrations, cloned
        warm = state["warm_start"]
        assert warm["steps"] == 64 and warm["seconds"] > 0 and warm["std"] >= 0.1
        # the clone evaluated on the episodes of every later evaluation, before PPO trains
        assert warm["eval_mean_abs_error_g"] >= 0 and 0 <= warm["eval_success_rate"] <= 1
        assert len(warm["dagger_mean_abs_error_g"]) == 1  # one DAgger round's rollout
        assert json.loads((out / "result.json").read_text())["warm_start"] == warm
    else:
        assert "warm_start" not in state
    assert (out / "training.png").exists()
    act = load_policy(out / "model.zip")
    obs = np.zeros(12, np.float32)
    assert act(obs, True).shape == (2,)
    if "--tilt-target" in flags:  # the saved model keeps the map it trained through
        from pourbench.agents.directed import model_map
        from pourbench.agents.loading import load_model

        np.testing.assert_allclose(
            model_map(load_model(out / "model.zip")).tilt_target, (2.4, 0.08)
        )


def test_the_warm_start_demonstrates_every_lesson_and_leaves_the_first() -> None:
    """``--warm-start-lessons all``: the PD's demonstrations are split evenly over the
    lessons: each part's worlds pour liquids of its lesson's viscosity range, and the worlds
    go on in the first lesson."""
    import numpy as np

    from pourbench.agents.sb3 import SB3PourVecEnv
    from pourbench.agents.train import lesson_rollout
    from pourbench.envs.curriculum import load_curriculum

    lessons = load_curriculum()
    env = SB3PourVecEnv(2, seed=0, workers=1, liquid=None, lesson=0)
    try:
        demos = lesson_rollout(env, 3, list(range(len(lessons))))
        after = env.reset()
    finally:
        env.close()
    assert demos.obs.shape == (3, 2 * len(lessons), 12) and demos.starts[0].all()

    def in_lesson(obs: np.ndarray, k: int) -> bool:
        low, high = np.log10(np.array(lessons[k].ranges["viscosity_pa_s"]) * 1000.0)
        return bool(np.all((obs[:, 3] >= low - 1e-5) & (obs[:, 3] <= high + 1e-5)))

    for k in range(len(lessons)):  # obs feature 3: log10 of the viscosity in mPa·s
        assert in_lesson(demos.obs[0, 2 * k : 2 * k + 2], k)
    assert in_lesson(after, 0) and not in_lesson(after, 2)


def test_a_run_from_before_a_setting_existed_resumes_with_its_default(tmp_path) -> None:
    """A state.json without ``rehearse`` (written before the setting existed) resumes a run
    that leaves it off, and is refused for one that turns it on."""
    from pourbench.agents.train import _read_state

    out = tmp_path / "run"
    out.mkdir()
    (out / "model.zip").write_bytes(b"")
    args = _args(TINY)
    saved = {k: v for k, v in asdict(args).items() if k != "rehearse"}
    (out / "state.json").write_text(json.dumps(_state(saved)))
    assert _read_state(out, args)["args"] == saved
    with pytest.raises(ValueError, match="has rehearse=False, not True"):
        _read_state(out, replace(args, rehearse=True))


def _state(args: dict) -> dict:
    """A state.json as a checkpoint writes it, with the settings ``args``."""
    return {"args": args, "timesteps": 16, "train_s": 1.0, "sessions": 1, "history": []}


SAC = ["--algorithm", "sac", "--no-icm"]


@pytest.mark.parametrize(
    "saved, argv, words",
    [
        ([], ["--batch-size", "32"], "has batch_size=256, not 32"),
        ([], ["--icm-eta", "0.5"], "has icm_eta=0.02, not 0.5"),
        ([], ["--target-g", "100"], "has target_g=0.0, not 100.0"),
        ([], ["--directed-tilt"], "has directed_tilt=False, not True"),
        ([], ["--directed-approach"], "has directed_approach=False, not True"),
        ([], ["--tilt-target"], "has tilt_target=False, not True"),
        (SAC, [*SAC, "--ent-coef", "0.02"], "has ent_coef=0.0, not 0.02"),
        (["--no-curriculum"], ["--no-curriculum", "--liquid", "honey"],
         "has liquid='water', not 'honey'"),
    ],
)  # fmt: skip
def test_a_resume_that_changes_a_restored_setting_is_refused(tmp_path, capsys, saved, argv,
                                                             words) -> None:  # fmt: skip
    """SB3 restores batch_size from model.zip, the ICM's eta and the target (and, without the
    curriculum, the liquid) set the worlds and every evaluation: a resume that changes one is
    refused, naming both values, before anything is built or written."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "model.zip").write_bytes(b"a checkpoint")
    state = json.dumps(_state(asdict(_args([*TINY, *saved]))))
    (out / "state.json").write_text(state)
    assert main([*TINY, *argv, "--out", str(out), "--resume"]) == 2
    assert words in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["model.zip", "state.json"]
    assert (out / "state.json").read_text() == state
    assert (out / "model.zip").read_bytes() == b"a checkpoint"


def test_with_the_curriculum_a_resume_may_change_the_unused_liquid(tmp_path) -> None:
    from pourbench.agents.train import _read_state

    out = tmp_path / "run"
    out.mkdir()
    (out / "model.zip").write_bytes(b"")
    args = _args(TINY)
    (out / "state.json").write_text(json.dumps(_state(asdict(args))))
    assert _read_state(out, replace(args, liquid="honey"))["timesteps"] == 16


@pytest.mark.parametrize(
    "state, words",
    [
        ([], "holds a list, not an object"),
        ({"args": []}, "'args' must be an object, got []"),
        ({"args": {}}, "timesteps must be an integer, got None"),
        ({"args": {}, "timesteps": 3, "sessions": 1, "train_s": "1"}, "train_s must be a number"),
        ({**_state({}), "history": 5}, "'history' must be a list, got 5"),
        ({**_state({}), "best": {"timesteps": 3}}, "'best' must be an object with"),
        (b"\xff{}", "UnicodeDecodeError"),
    ],
)
def test_a_malformed_state_file_is_refused_in_one_line(tmp_path, capsys, state, words) -> None:
    """A state.json that is not what a checkpoint writes is refused naming the file, with
    nothing written."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "model.zip").write_bytes(b"a checkpoint")
    raw = state if isinstance(state, bytes) else json.dumps(state).encode()
    (out / "state.json").write_bytes(raw)
    assert main(["--out", str(out), "--resume"]) == 2  # the settings of "args": {}
    err = capsys.readouterr().err
    assert "state.json" in err and "missing or unreadable" in err and words in err, err
    assert sorted(p.name for p in out.iterdir()) == ["model.zip", "state.json"]
    assert (out / "state.json").read_bytes() == raw


@pytest.mark.slow
def test_an_off_policy_run_resumes_with_its_replay_buffer(tmp_path, capsys) -> None:
    """A SAC run checkpoints its replay buffer beside the model; resumed, it continues with
    the transitions it had collected (128 steps, then 64 more), and its model records the
    handler's tolerance that its deterministic action averages under."""
    from stable_baselines3.common.save_util import load_from_pkl

    from pourbench.agents.directed import HANDLER_ATTRIBUTE
    from pourbench.agents.loading import load_model
    from pourbench.envs.core import PourConfig

    out = tmp_path / "sac"
    run = [
        *SMALL,
        *("--algorithm", "sac", "--no-icm", "--no-curriculum", "--eval-episodes", "1"),
        *("--eval-every-steps", "0", "--out", str(out)),
    ]
    assert main([*run, "--budget-steps", "128"]) == 0
    assert load_from_pkl(out / "replay_buffer.pkl").size() * 2 == 128  # 2 worlds a row
    assert getattr(load_model(out / "model.zip"), HANDLER_ATTRIBUTE) == PourConfig().tolerance_g
    assert main([*run, "--budget-steps", "192", "--resume"]) == 0
    assert "no replay buffer" not in capsys.readouterr().out
    assert load_from_pkl(out / "replay_buffer.pkl").size() * 2 == 192

    (out / "replay_buffer.pkl").unlink()
    assert main([*run, "--budget-steps", "256", "--resume"]) == 0
    assert "the resumed run starts with none" in capsys.readouterr().out
    assert load_from_pkl(out / "replay_buffer.pkl").size() * 2 == 64
    assert not list(out.glob("*.partial*"))
