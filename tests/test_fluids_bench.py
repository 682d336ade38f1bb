"""``pourbench bench fluids --quick --json``: one JSON object with the documented rows."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest


def test_quick_bench_prints_one_json_object(tmp_path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "pourbench.cli", "bench", "fluids", "--quick", "--json",
         "--out", str(tmp_path)],
        capture_output=True, text=True, check=True, timeout=600,
    )  # fmt: skip
    doc = json.loads(out.stdout)  # exactly one JSON document on stdout (no Warp greeting)
    (row,) = doc["rows"]  # --quick: the 16k CPU case only
    assert row["device"] == "cpu" and row["iterations"] == 4
    assert 15_000 <= row["particles"] <= 17_000
    keys = ("particle_steps_per_s", "best_particle_steps_per_s", "baseline_particle_steps_per_s")
    for key in (*keys, "ms_per_step"):
        assert math.isfinite(row[key]) and row[key] > 0
    assert row["best_particle_steps_per_s"] >= row["particle_steps_per_s"]  # fastest ≥ median
    assert (tmp_path / "fluids.md").exists() and (tmp_path / "fluids.json").exists()


def test_bench_case_lists_keep_stdout_clean() -> None:
    """Listing the cases probes for CUDA, which starts Warp; its greeting must not reach
    stdout, or ``--json`` output is not one JSON document."""
    code = (  # each suite alone, as `pourbench bench <suite>` runs it
        "from pourbench.bench import {0}; assert {0}.cases(False)"
    )
    for suite in ("env", "fluids"):
        out = subprocess.run(
            [sys.executable, "-c", code.format(suite)],
            capture_output=True, text=True, check=True, timeout=300,
        )  # fmt: skip
        assert out.stdout == "", suite


@pytest.mark.parametrize("n", [2_000, 16_000, 128_000, 1_024_000])
def test_bench_block_holds_its_particles_in_a_shallow_column(n: int) -> None:
    """Every row's block holds about its particle count (within 7 %: 16k is 15,000), at most
    25 cm tall (the 2k and 16k blocks keep height 2a), inside its tank."""
    from pourbench.bench.fluids import BLOCK_MAX_LAYERS, _block

    d = 0.005
    pts, tank = _block(n, d)
    assert len(pts) == pytest.approx(n, rel=0.07)
    height = np.ptp(pts[:, 2]) + d
    assert height <= BLOCK_MAX_LAYERS * d + 1e-9
    width = np.ptp(pts[:, 0]) + d
    if n <= 16_000:
        assert height == pytest.approx(2.0 * width)
    assert np.all(tank.sdf(pts) >= 0.5 * d - 1e-9)  # inside the cavity, half a spacing clear


def test_the_neighbour_count_does_not_depend_on_the_time_budget() -> None:
    """A row's neighbours_mean is read at a fixed step: a run with no time budget (3 timed
    steps) and one allowed up to 50 timed steps report the same value, so it compares across
    machines and runs."""
    from pourbench.bench.fluids import run_case

    short = run_case("cpu", 2_000, budget_s=0.0)
    long = run_case("cpu", 2_000, budget_s=5.0)
    assert short["neighbours_mean"] == long["neighbours_mean"]
    assert 15.0 < short["neighbours_mean"] < 60.0  # an interior particle at rest has about 30


def test_device_choice_selects_rows_and_report() -> None:
    from pourbench.bench import _report, env, fluids

    assert {d for d, *_ in fluids.cases(False, "cpu")} == {"cpu"}
    cuda_rows = fluids.cases(False, "cuda")  # listing needs no device
    assert {d for d, *_ in cuda_rows} == {"cuda"}
    assert max(n for _, n, *_ in cuda_rows) >= 1_000_000  # the 1M+ target row
    assert {d for _, d, _ in env.cases(False, "cuda")} == {"cuda"}
    assert _report.report_stem("fluids", "cuda") == "fluids_cuda"
    assert _report.report_stem("fluids", "auto") == "fluids"
    assert _report.accelerator([{"device": "cpu"}]) is None


def test_cuda_bench_without_a_device_is_a_clear_error() -> None:
    from pourbench.fluids.solver import cuda_available

    if cuda_available():
        pytest.skip("the error path exists only on machines without CUDA")
    for suite in ("fluids", "planning"):
        out = subprocess.run(
            [sys.executable, "-m", "pourbench.cli", "bench", suite, "--device", "cuda"],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert out.returncode != 0 and "no CUDA device" in out.stderr, suite


def test_git_sha_ignores_tables_but_not_code(tmp_path, monkeypatch) -> None:
    """A suite's table written earlier in the same run does not mark the next suite's SHA
    dirty; a changed source file does."""
    from pourbench.bench._report import git_sha

    monkeypatch.delenv("POURBENCH_GIT_SHA", raising=False)
    monkeypatch.chdir(tmp_path)  # for the git commands below
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t"]
    (tmp_path / "leaderboard").mkdir()
    (tmp_path / "leaderboard" / "fluids.md").write_text("old\n")
    (tmp_path / "code.py").write_text("x = 1\n")
    subprocess.run(["git", "init", "-q"], check=True)
    subprocess.run([*git, "add", "."], check=True)
    subprocess.run([*git, "commit", "-qm", "init"], check=True)
    (tmp_path / "leaderboard" / "fluids.md").write_text("new\n")
    assert not git_sha(tmp_path).endswith("-dirty")
    (tmp_path / "code.py").write_text("x = 2\n")
    assert git_sha(tmp_path).endswith("-dirty")
    monkeypatch.setenv("POURBENCH_GIT_SHA", "abc1234")
    assert git_sha(tmp_path) == "abc1234 (copied tree)"


@pytest.mark.parametrize("suite", ["planning", "teleop"])
def test_cuda_bench_of_a_cpu_only_suite_is_a_clear_error(suite, monkeypatch) -> None:
    """With a device present, a suite without a CUDA path refuses ``--device cuda`` instead of
    running on the CPU and writing a ``_cuda`` table."""
    import argparse

    from pourbench import cli
    from pourbench.fluids import solver

    monkeypatch.setattr(solver, "cuda_available", lambda: True)
    args = argparse.Namespace(suite=suite, device="cuda")
    with pytest.raises(ValueError, match="has no CUDA path"):
        cli._cmd_bench(args)


def test_env_bench_runs_past_an_episode_end() -> None:
    """The single-env case steps longer than an episode (250 steps): it resets the ended
    episode as a training loop does, instead of stepping a finished one (ResetNeeded)."""
    from pourbench.bench import env
    from pourbench.envs.core import PourConfig

    assert PourConfig().max_steps < 260
    row = env.run_case("single", "cpu", 1, budget_s=0.0, min_steps=260)
    assert row["worlds"] == 1 and row["env_steps_per_s"] > 0
    assert 0.3 < row["g_per_particle"] < 0.7  # 8 mm particles of water, about 0.5 g each


def test_env_bench_times_the_robot_beside_pour_v0() -> None:
    """A PourRobot-v0 row: the robot's and Pour-v0's rates from the same alternating run, the
    planner's share, and the cup's fill (8 mm particles of water, about 0.5 g each)."""
    from pourbench.bench.env_robot import robot_case

    row = robot_case("panda", "mink", budget_s=0.0, min_steps=2)
    assert (row["robot"], row["planner"]) == ("panda", "mink")
    assert row["ratio_to_pour_v0"] == pytest.approx(
        row["env_steps_per_s"] / row["pour_v0_env_steps_per_s"]
    )
    assert 0.0 < row["planner_ms_per_step"] < 1e3 / row["env_steps_per_s"]
    assert 150 < row["particles"] < 700


def _pair(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"body_md": None}, "body_md must be a str, got None"),
        ({"title": 5}, "title must be a str"),
        ({"rows": None}, "rows must be a list of dicts, got None"),
        ({"rows": "abc"}, "rows must be a list of dicts, got 'abc'"),
        ({"rows": [1]}, r"rows\[0\] must be a dict"),
        ({"rows": [{"a": object()}]}, r"rows\[0\]\['a'\] is not a JSON value"),
        ({"extra": 3}, "extra must be a dict or None"),
        ({"suite": "../escaped"}, "suite must be a plain file stem"),
        ({"suite": "a/b"}, "suite must be a plain file stem"),
        ({"suite": ""}, "suite must be a plain file stem"),
        ({"suite": None}, "suite must be a plain file stem"),
    ],
)
def test_a_refused_report_leaves_the_previous_pair(tmp_path, kw, words) -> None:
    """Bad input is refused before either file is written: the earlier JSON and markdown stay
    together, nothing is written outside ``out`` and no temporary file is left."""
    from pourbench.bench._report import write_report

    out = tmp_path / "lb"
    write_report("s", [{"a": 1}], out=out, title="t", body_md="old")
    before = _pair(out)
    args = {"suite": "s", "rows": [{"a": 2}], "title": "t", "body_md": "new", **kw}
    suite = args.pop("suite")
    with pytest.raises(ValueError, match=words):
        write_report(suite, out=out, **args)
    assert _pair(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lb"]


@pytest.mark.parametrize("key", ["load", "git_sha", "command", "suite", "rows"])
def test_extra_may_not_overwrite_the_reports_own_fields(tmp_path, key) -> None:
    """An ``extra`` field named as a provenance field (or ``suite`` / ``rows``) would make the
    JSON disagree with the markdown: it is refused before anything is written."""
    from pourbench.bench._report import STAMP_KEYS, write_report
    from pourbench.errors import InvalidParameterError
    from pourbench.provenance import provenance

    assert set(provenance()) <= set(STAMP_KEYS)
    with pytest.raises(InvalidParameterError, match=f"extra must not set .*'{key}'"):
        write_report("s", [{"a": 1}], out=tmp_path / "lb", title="t", body_md="b", extra={key: "x"})
    assert list(tmp_path.iterdir()) == []


def test_a_report_whose_markdown_path_is_a_folder_keeps_its_json(tmp_path) -> None:
    from pourbench.bench._report import write_report

    write_report("s", [{"a": 1}], out=tmp_path, title="t", body_md="old")
    (tmp_path / "s.md").unlink()
    (tmp_path / "s.md").mkdir()
    before = (tmp_path / "s.json").read_bytes()
    with pytest.raises(ValueError, match="is a folder"):
        write_report("s", [{"a": 2}], out=tmp_path, title="t", body_md="new")
    assert (tmp_path / "s.json").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json", "s.md"]


def test_a_long_run_stamps_the_sha_it_started_at(tmp_path) -> None:
    """``git_sha_at_start``: a run that commits were made during is stamped with the code it
    ran, in both files; without it, the SHA at writing."""
    from pourbench.bench._report import git_sha, write_report

    json_path, md_path = write_report(
        "s", [], out=tmp_path, title="t", body_md="b", git_sha_at_start="abc1234"
    )
    assert json.loads(json_path.read_text())["git_sha"] == "abc1234"
    assert "- git SHA: `abc1234`" in md_path.read_text()
    json_path, _ = write_report("s", [], out=tmp_path, title="t", body_md="b")
    assert json.loads(json_path.read_text())["git_sha"] == git_sha()


def test_a_report_records_the_load_it_was_timed_under(tmp_path, monkeypatch) -> None:
    """The machine's load averages at writing go into both files beside the core count, so a
    table timed while other processes shared the cores says so."""
    import os

    from pourbench.bench._report import write_report

    monkeypatch.setattr(os, "getloadavg", lambda: (2.5, 2.0, 1.25))
    json_path, md_path = write_report("s", [], out=tmp_path, title="t", body_md="b")
    want = f"2.50 / 2.00 / 1.25 (1 / 5 / 15 min) on {os.cpu_count()} cores"
    assert json.loads(json_path.read_text())["load"] == want
    assert f"- load at writing: {want}" in md_path.read_text()


def test_report_json_is_strict_with_numpy_values_and_nan_as_null(tmp_path) -> None:
    """NaN is written as null (a missing value, as rows write None), ±inf as "inf" / "-inf"
    (no obstacle: an infinite clearance, not a missing one); NumPy values as plain numbers."""
    from pourbench.bench._report import write_report

    rows = [{"a": np.int64(2), "b": np.float32(0.5), "c": float("nan"), "d": np.array([1, 2])}]
    json_path, md_path = write_report(
        "s", rows, out=tmp_path, title="t", body_md="b", extra={"x": float("inf"), "y": -np.inf}
    )

    def refuse(name):
        raise AssertionError(f"{name} in the JSON")

    doc = json.loads(json_path.read_text(), parse_constant=refuse)
    assert doc["rows"] == [{"a": 2, "b": 0.5, "c": None, "d": [1, 2]}]
    assert (doc["x"], doc["y"]) == ("inf", "-inf")
    assert md_path.read_text().startswith("# t\n")
    assert not list(tmp_path.glob("*.partial"))


def test_unknown_bench_device_is_refused() -> None:
    from pourbench.bench._report import devices

    with pytest.raises(ValueError, match="device must be 'auto', 'cpu' or 'cuda', got 'gpu'"):
        devices("gpu", quick=True)


def test_timed_pours_step_every_case_in_turn_through_the_same_pour() -> None:
    """Two pours timed against each other take the same steps, one each in turn: the fixed
    solve uses exactly its ``iterations`` every step and the adaptive one never fewer."""
    import dataclasses

    from pourbench.bench.fluids_viscosity import timed_pours
    from pourbench.envs.core import default_solver_config

    base = default_solver_config()
    fixed = dataclasses.replace(base, max_iterations=base.iterations)
    runs = timed_pours({"fixed": ("water", fixed), "adaptive": ("water", base)}, seconds=0.05)
    steps = round(0.05 / base.dt)
    for run in runs.values():
        assert len(run.density_iterations) == steps
        assert run.seconds > 0.0
    assert np.all(runs["fixed"].density_iterations == base.iterations)
    assert np.all(runs["adaptive"].density_iterations >= base.iterations)
