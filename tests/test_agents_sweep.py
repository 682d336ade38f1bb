"""``pourbench sweep``: configs checked at the boundary, trials on a real local Ray that
finish, write their table and resume from their checkpoints after a kill."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pourbench.agents.sweep import load_sweep, run_sweep, sample_config
from pourbench.cli import main
from pourbench.errors import PourbenchError

TINY = """
[sweep]
name = "tiny"
[train]
algorithm = "ppo"
num_envs = 2
n_steps = 32
batch_size = 64
budget_steps = {budget}
eval_every_steps = 128
eval_episodes = 1
eval_liquid = "water"
curriculum = false
[search]
seed = [0, 1]
"""


def _write(tmp_path: Path, text: str, name: str = "sweep.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, words",
    [
        ("[sweeep]\nname = 'x'", "sweeep: unknown section"),
        ("[sweep]\nsamples = 0\n[search]\nseed = [0]", "sweep.samples: must be at least 1"),
        ("[sweep]\nsamples = 'two'\n[search]\nseed = [0]", "sweep.samples: must be int"),
        ("[sweep]\ncolour = 1\n[search]\nseed = [0]", "sweep.colour: unknown key"),
        ("[train]\nlr = 0.1\n[search]\nseed = [0]", "train.lr: not a setting"),
        ("[train]\nout = 'x'\n[search]\nseed = [0]", "train.out: set by the sweep"),
        ("[train]\nbudget_steps = -5\n[search]\nseed = [0]", "train: budget_steps"),
        ("[train]\neval_liquid = 'lava'\n[search]\nseed = [0]", "train: unknown liquid 'lava'"),
        ("[train]\nseed = 1", "search: no setting to search"),
        ("[train]\nseed = 1\n[search]\nseed = [0]", "search.seed: also given in [train]"),
        ("[search]\nseed = []", "search.seed: an empty grid"),
        ("[search]\nalgorithm = ['ppo', 'dqn']", "search.algorithm: "),
        ("[search]\nlearning_rate = {loguniform = [0, 1e-3]}", "search.learning_rate: loguniform"),
        ("[search]\nlearning_rate = {normal = [0, 1]}", "unknown distribution 'normal'"),
        ("[search]\nlearning_rate = {uniform = [1e-3, 1e-4]}", "needs low < high"),
        ("[search]\nlearning_rate = {uniform = [-1.0, 1e-4]}", "search.learning_rate: "),
        ("[search]\nseed = {randint = [0.5, 3]}", "randint takes integers"),
        ("[search\nseed = [0]", "not valid TOML"),
        ("[search]\nnum_envs = {uniform = [2, 8]}", "search.num_envs: uniform draws floats"),
        ("[search]\nbatch_size = {loguniform = [8, 64]}", "batch_size is an integer"),
        (
            "[train]\nicm = false\ncurriculum = false\n"
            "[search]\nalgorithm = ['ppo', 'sac']\ntarget_kl = [0.0, 0.02]",
            "search: the trial {'algorithm': 'sac', 'target_kl': 0.02}: target_kl=0.02 limits",
        ),
        (
            "[train]\nicm = false\ncurriculum = false\n"
            "[search]\nalgorithm = ['ppo', 'sac']\ntarget_kl = {uniform = [0.0, 0.02]}",
            "the trial {'algorithm': 'sac', 'target_kl': 0.02}",
        ),
        (
            "[sweep]\ncpus_per_trial = 4\n[train]\nnum_envs = 2\n[search]\nseed = [0, 1]",
            "workers=4 is more than num_envs=2 (each trial's workers is sweep.cpus_per_trial, 4)",
        ),
        (
            "[sweep]\ncpus_per_trial = 4\n[search]\nnum_envs = [8, 2]",
            "the trial {'num_envs': 2}: workers=4 is more than num_envs=2",
        ),
    ],
)
def test_a_malformed_config_names_the_file_and_the_key(tmp_path, capsys, text, words) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(PourbenchError, match="^" + str(path).replace(".", r"\.")) as info:
        load_sweep(path)
    assert words in str(info.value)
    assert main(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out" / "sweep").exists()


def test_a_missing_config_is_named(tmp_path) -> None:
    with pytest.raises(PourbenchError, match=r"nowhere\.toml: cannot read"):
        load_sweep(tmp_path / "nowhere.toml")


def test_a_config_that_is_not_utf8_is_named(tmp_path, capsys) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes("[search]\n# réglages\nseed = [0]\n".encode("latin-1"))
    with pytest.raises(PourbenchError, match=r"latin1\.toml: cannot read .*utf-8"):
        load_sweep(path)
    assert main(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_the_sample_config_is_a_grid_with_a_draw() -> None:
    from ray.tune.search.sample import Float

    sweep = load_sweep(sample_config())
    space = sweep.param_space()
    assert space["icm"] == {"grid_search": [True, False]}
    assert space["seed"] == {"grid_search": [0, 1, 2]}
    rate = space["learning_rate"]
    assert isinstance(rate, Float) and (rate.lower, rate.upper) == (1e-4, 1e-3)
    args = sweep.trial_args({"icm": False, "seed": 2, "learning_rate": 3e-4}, Path("o"), False)
    assert (args.icm, args.seed, args.learning_rate, args.num_envs) == (False, 2, 3e-4, 16)
    assert (args.workers, args.threads, args.out, args.resume) == (1, 1, "o", False)


def test_without_ray_the_sweep_says_how_to_install_it(tmp_path, monkeypatch, capsys) -> None:
    path = _write(tmp_path, TINY.format(budget=256))
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(PourbenchError, match=r"pip install 'pourbench\[ray\]'"):
        run_sweep(path, tmp_path / "out")
    assert main(["bench", "pouring", "--quick", "--ray"]) == 2
    assert "pip install 'pourbench[ray]'" in capsys.readouterr().err
    assert main(["bench", "fluids", "--quick", "--ray"]) == 2
    assert "bench fluids has no Ray path" in capsys.readouterr().err


def test_a_sweep_folder_resumes_only_with_the_config_it_was_started_with(tmp_path) -> None:
    """The record a sweep writes when it starts lets the same config resume; a changed one
    is refused, naming the folder and every key that changed, and so is a folder without a
    record (or with a malformed one). Nothing in the folder changes."""
    from pourbench.agents.sweep import CONFIG_RECORD, check_resume, config_record

    sweep = load_sweep(_write(tmp_path, TINY.format(budget=256)))
    folder = tmp_path / "tiny"
    folder.mkdir()
    with pytest.raises(PourbenchError, match=f"{folder} holds a sweep with no record"):
        check_resume(folder, sweep)
    (folder / CONFIG_RECORD).write_text(json.dumps(config_record(sweep)))
    check_resume(folder, sweep)  # the same config resumes
    changed = TINY.format(budget=512).replace("seed = [0, 1]", "seed = [0, 2]\nicm = [false]")
    changed = load_sweep(_write(tmp_path, changed.replace("[sweep]", "[sweep]\nsamples = 2")))
    with pytest.raises(PourbenchError) as refused:
        check_resume(folder, changed)
    assert str(refused.value).startswith(
        f"{folder} was started with another config: search.icm, search.seed, "
        "sweep.samples, train.budget_steps changed"
    )
    assert json.loads((folder / CONFIG_RECORD).read_text()) == config_record(sweep)
    (folder / CONFIG_RECORD).write_text("{")
    with pytest.raises(PourbenchError, match="not a sweep config record"):
        check_resume(folder, sweep)


@pytest.mark.slow
def test_a_tiny_sweep_finishes_and_writes_its_table(tmp_path) -> None:
    """Two trials of 256 steps on a local Ray: each evaluated at 128 and 256 steps, then
    beside the PD and a random policy; the table, its JSON and the curves are written."""
    path = _write(tmp_path, TINY.format(budget=256))
    rows = run_sweep(path, tmp_path / "out")
    folder = tmp_path / "out" / "tiny"
    data = json.loads((folder / "sweep.json").read_text())
    assert data["rows"] == json.loads(json.dumps(rows))
    assert sorted(r["seed"] for r in rows) == [0, 1]
    for row in rows:
        assert row["status"] == "done" and row["timesteps"] == 256
        assert row["pd_error_g"] < row["random_error_g"]
        assert row["best_error_g"] <= row["final_error_g"]
    assert (folder / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| seed=0 | 0 | 256 |" in (folder / "sweep.md").read_text()


@pytest.mark.slow
def test_a_killed_sweep_resumes_its_trials_from_their_checkpoints(tmp_path) -> None:
    """The sweep's command is killed (with its Ray) once a trial has reported its first
    checkpoint; run again, the same command resumes that trial from it: the run's second
    session starts at the checkpoint's steps and ends at the budget."""
    path = _write(tmp_path, TINY.format(budget=512))
    out = tmp_path / "out"
    command = [sys.executable, "-m", "pourbench.cli", "sweep", str(path), "--out", str(out)]
    proc = subprocess.Popen(command, cwd=tmp_path, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.monotonic() + 600
    try:
        while not list((out / "tiny").glob("run_trial_*/checkpoint_000000/model.zip")):
            assert proc.poll() is None, "the sweep ended before its first checkpoint"
            assert time.monotonic() < deadline, "no checkpoint within 10 minutes"
            time.sleep(1.0)
        time.sleep(15.0)  # Tune records the checkpoint in its experiment state; training goes on
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    changed = _write(tmp_path, TINY.format(budget=1024), "changed.toml")
    assert main(["sweep", str(changed), "--out", str(out)]) == 2  # refused: budget_steps changed
    assert main(["sweep", str(path), "--out", str(out)]) == 0
    rows = json.loads((out / "tiny" / "sweep.json").read_text())["rows"]
    assert [r["status"] for r in rows] == ["done", "done"]
    resumed = 0
    for state in (out / "tiny").glob("run_trial_*/run/state.json"):
        history = json.loads(state.read_text())["history"]
        assert history[-1]["timesteps"] == 512
        if len(history) > 1:
            assert 128 <= history[0]["timesteps"] < 512
            resumed += 1
    assert resumed >= 1


@pytest.mark.parametrize(
    "left, resume",
    [
        (["model.zip", "icm.pt", "state.json"], True),  # a checkpoint before the first report
        (["model.zip"], False),  # died while writing its first checkpoint
        ([], False),  # died before it
    ],
)
def test_a_trial_that_dies_before_its_first_report_restarts(tmp_path, monkeypatch, left,
                                                            resume) -> None:  # fmt: skip
    """With no Tune checkpoint, a restarted trial resumes the checkpoint its run wrote (the
    run's state.json beside its model), or starts afresh from an empty run folder: a run
    folder holding a model without --resume would be refused in every retry."""
    import types

    from ray import tune

    import pourbench.agents.train
    from pourbench.agents.sweep import run_trial

    run = tmp_path / "trial" / "run"
    run.mkdir(parents=True)
    for name in left:
        (run / name).write_text(name)
    context = types.SimpleNamespace(get_trial_dir=lambda: str(tmp_path / "trial"))
    monkeypatch.setattr(tune, "get_context", lambda: context)
    monkeypatch.setattr(tune, "get_checkpoint", lambda: None)
    trained = []

    def train(args, command=None, report=None):
        trained.append((args, sorted(p.name for p in run.iterdir()) if run.exists() else []))

    monkeypatch.setattr(pourbench.agents.train, "train", train)
    run_trial({"icm": True, "curriculum": True, "seed": 0, "learning_rate": 3e-4},
              load_sweep(sample_config()))  # fmt: skip
    [(args, files)] = trained
    assert (args.resume, args.out) == (resume, str(run))
    assert files == (sorted(left) if resume else [])
