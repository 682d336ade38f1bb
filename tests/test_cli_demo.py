"""The console script: the demo's accounting of grams, its recording, and bad input."""

from __future__ import annotations

import json
import re

import pytest

from pourbench.cli import main


def test_demo_accounts_for_every_gram_and_writes_a_recording(tmp_path, capsys) -> None:
    out = tmp_path / "demo.rrd"
    assert (
        main(["demo", "--scripted", "--seconds", "2.5", "--mass-g", "100", "--out", str(out)]) == 0
    )
    text = capsys.readouterr().out
    grams = {
        key: float(re.search(rf"{key}:\s+([-\d.]+) g", text).group(1))
        for key in ("receiving cup", "spilled", "source cup", "in flight", "force sensor")
    }
    total = grams["receiving cup"] + grams["spilled"] + grams["source cup"] + grams["in flight"]
    assert total == pytest.approx(100.0, abs=0.2)
    assert grams["receiving cup"] > 50.0  # 2.5 s of tilting pours most of it
    assert out.stat().st_size > 10_000  # particles and containers at 30 Hz


def test_demo_unknown_liquid_is_a_clear_error(capsys) -> None:
    assert main(["demo", "--liquid", "lava", "--seconds", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "unknown liquid 'lava'" in err and "Water" in err


@pytest.mark.parametrize(
    "argv, option",
    [
        (["demo", "--seconds", "nan"], "--seconds"),
        (["demo", "--seconds", "-1"], "--seconds"),
        (["demo", "--mass-g", "-5"], "--mass-g"),
        (["demo", "--mass-g", "inf"], "--mass-g"),
        (["demo", "--device", "gpu"], "--device"),
        (["eval", "--episodes", "0"], "--episodes"),
        (["eval", "--target-g", "nan"], "--target-g"),
        (["eval", "--seed", "-1"], "--seed"),
        (["view", "scene", "--robot", "r2d2"], "--robot"),
    ],
)
def test_bad_numbers_and_names_are_refused_while_parsing(argv, option, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert f"argument {option}:" in capsys.readouterr().err


def test_a_bad_run_keeps_the_previous_recording(tmp_path, capsys) -> None:
    out = tmp_path / "demo.rrd"
    out.write_bytes(b"an earlier recording")
    assert main(["demo", "--liquid", "lava", "--out", str(out)]) == 2
    assert main(["demo", "--out", str(tmp_path)]) == 2  # a folder, not a file
    assert "is a folder" in capsys.readouterr().err
    assert out.read_bytes() == b"an earlier recording"
    assert [p.name for p in tmp_path.iterdir()] == ["demo.rrd"]  # no partial file left


def test_view_writes_into_a_new_folder(tmp_path) -> None:
    out = tmp_path / "new" / "scene.rrd"
    assert main(["view", "scene", "--robot", "none", "--out", str(out)]) == 0
    assert out.stat().st_size > 1_000
    assert not out.with_name("scene.rrd.partial").exists()


def test_viewer_without_a_display_is_one_clear_error(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["view", "scene", "--viewer"]) == 2
    assert "--viewer needs a display" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no MUJOCO_LOG.TXT left behind


def test_display_check_passes_with_a_display_or_off_linux() -> None:
    from pourbench.view import check_display

    check_display({"DISPLAY": ":0"}, "linux")
    check_display({"WAYLAND_DISPLAY": "wayland-0"}, "linux")
    check_display({}, "darwin")  # macOS and Windows open windows without these variables


def test_bench_output_folder_is_checked_before_any_work(tmp_path, capsys) -> None:
    a_file = tmp_path / "afile"
    a_file.write_text("keep me")
    assert main(["bench", "env", "--out", str(a_file)]) == 2
    assert "is a file" in capsys.readouterr().err
    assert a_file.read_text() == "keep me"


def test_finished_is_the_ablations_alone(capsys) -> None:
    """``--finished`` reads the ablation's run records; another suite refuses it up front."""
    assert main(["bench", "env", "--quick", "--finished"]) == 2
    assert "--finished: bench env has no recorded runs" in capsys.readouterr().err


def _suite(name: str, rc: int, calls: list[str]):
    """A benchmark suite module that records its call and prints its JSON object."""
    import types

    def run(args) -> int:
        calls.append(name)
        if args.json:
            print(
                json.dumps({"suite": name, "rows": [{"out": args.out, "write": not args.no_write}]})
            )
        return rc

    return types.SimpleNamespace(run=run)


def test_bench_all_json_is_one_object_and_every_suite_runs(monkeypatch, capsys) -> None:
    """``bench all --json`` prints {"suites": [...]} (one JSON document), a suite that fails
    does not stop the next, and ``--quick`` without ``--out`` writes no table."""
    import sys

    calls: list[str] = []
    monkeypatch.setattr("pourbench.cli.BENCH_SUITES", ("a", "b"))
    monkeypatch.setitem(sys.modules, "pourbench.bench.a", _suite("a", 1, calls))
    monkeypatch.setitem(sys.modules, "pourbench.bench.b", _suite("b", 0, calls))
    assert main(["bench", "all", "--quick", "--json"]) == 1
    assert calls == ["a", "b"]
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert [d["suite"] for d in doc["suites"]] == ["a", "b"]
    assert doc["suites"][0]["rows"] == [{"out": "leaderboard", "write": False}]
    assert "leaderboard not written" in captured.err


def test_ctrl_c_ends_a_run_in_one_line_and_keeps_the_previous_recording(
    tmp_path, capsys, monkeypatch
) -> None:
    """Ctrl-C during the demo's simulation: exit status 130, one line, no traceback, and the
    recording already at --out is left as it was (the new one was still a .partial file)."""
    from pourbench.fluids.solver import PBFSolver

    out = tmp_path / "demo.rrd"
    out.write_bytes(b"an earlier recording")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(PBFSolver, "step", interrupted)
    assert main(["demo", "--scripted", "--seconds", "0.5", "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == "pourbench: interrupted" and "Traceback" not in err
    assert out.read_bytes() == b"an earlier recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.rrd"]  # no partial file left


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"seconds": float("nan")}, "seconds must be finite, got nan"),
        ({"seconds": float("inf")}, "seconds must be finite, got inf"),
        ({"seconds": -1.0}, "seconds must be > 0, got -1.0"),
        ({"seconds": 1e-9}, "seconds must be at least one solver step"),
        ({"mass_g": float("nan")}, "mass_g must be finite, got nan"),
        ({"mass_g": 0.0}, "mass_g must be > 0"),
        ({"device": "tpu"}, "device must be 'cpu' or 'cuda', got 'tpu'"),
    ],
)
def test_run_demo_called_directly_refuses_bad_numbers(tmp_path, kw, words) -> None:
    """``run_demo`` checks its values itself (not only the parser), before the scene is built
    or the recording started: the previous recording stays, no partial file is left."""
    import argparse

    from pourbench.demo import run_demo

    out = tmp_path / "demo.rrd"
    out.write_bytes(b"an earlier recording")
    args = {"liquid": "water", "mass_g": 20.0, "seconds": 0.5, "out": str(out), "device": "cpu"}
    with pytest.raises(ValueError, match=words):
        run_demo(argparse.Namespace(**{**args, **kw}))
    assert out.read_bytes() == b"an earlier recording"
    assert [p.name for p in tmp_path.iterdir()] == ["demo.rrd"]


@pytest.mark.parametrize(
    "path, words",
    [
        (None, "output path must be a path"),
        (5, "output path must be a path"),
        ("", "output path must be a non-empty path"),
        ("od/a\0b", "contains a NUL character"),
        ("od/newdir/", "ends with a separator; give a file name"),
        ("x" * 300 + ".json", r"output path .x+\.json.: \w"),
        ("x" * 245 + ".rrd", r"output path .x+\.rrd.: \w"),  # fits, but not its .partial
    ],
)
def test_bad_output_paths_are_refused(tmp_path, monkeypatch, path, words) -> None:
    from pourbench.errors import InvalidParameterError
    from pourbench.outputs import check_output_path

    monkeypatch.chdir(tmp_path)
    with pytest.raises(InvalidParameterError, match=words):
        check_output_path(path)
    assert list(tmp_path.iterdir()) == []  # no folder made


def test_output_folder_checks(tmp_path, monkeypatch) -> None:
    from pourbench.outputs import OutputPathError, check_output_folder, check_output_path

    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputPathError, match="must be a path"):
        check_output_folder(None)
    with pytest.raises(OutputPathError, match="NUL"):
        check_output_folder("a\0b")
    assert check_output_path("new/x.json").parent.is_dir()  # good paths as before
    assert check_output_folder("") == check_output_folder(".")  # the current folder


def test_an_atomic_write_whose_partial_sibling_is_a_folder_keeps_the_old_file(tmp_path):
    from pourbench.outputs import OutputPathError, write_text_atomic

    target = write_text_atomic(tmp_path / "t.json", "old")
    (tmp_path / "t.json.partial").mkdir()
    with pytest.raises(OutputPathError, match=r"t\.json\.partial' is a folder"):
        write_text_atomic(target, "new")
    assert target.read_text() == "old" and (tmp_path / "t.json.partial").is_dir()


@pytest.mark.parametrize(
    ("shipped", "expected"),
    [([], None), (["pournet-gru"], None), (["pournet-mlp"], "pournet-mlp")],
)
def test_the_demo_policy_is_a_shipped_pournet_or_none(monkeypatch, shipped, expected) -> None:
    """None (the scripted tilt) unless ``pournet-lstm`` or ``pournet-mlp`` ships."""
    import pourbench.demo as demo

    monkeypatch.setattr(demo, "shipped_policies", lambda: shipped)
    assert demo.demo_policy() == expected


@pytest.mark.parametrize(
    ("shipped", "expected"),
    [(["pournet-mlp"], "pournet-mlp"), (["pournet-mlp", "pournet-lstm"], "pournet-lstm")],
)
def test_demo_pours_with_the_shipped_policy_once_it_exists(
    tmp_path, monkeypatch, capsys, shipped, expected
):
    """With a PourNet policy shipped, the demo is one Pour-v0 episode of it, the LSTM before
    the MLP: here the PD baseline stands in for it (the demo asks load_policy for the
    shipped name), and the grams it prints add up and match the target within the PD's
    error."""
    import pourbench.agents.loading as loading
    import pourbench.demo as demo

    asked, load = [], loading.load_policy

    def shipped_pd(name, seed=0):
        asked.append(name)
        return load("pd", seed)

    monkeypatch.setattr(demo, "shipped_policies", lambda: shipped)
    monkeypatch.setattr(loading, "load_policy", shipped_pd)
    out = tmp_path / "pour.rrd"
    argv = ["demo", "--mass-g", "200", "--target-g", "100", "--out", str(out)]
    assert main(argv) == 0
    assert asked == [expected]
    text = capsys.readouterr().out
    grams = {
        key: float(re.search(rf"{key}:\s+([-\d.]+) g", text).group(1))
        for key in ("receiving container", "spilled", "pouring container", "target")
    }
    assert grams["target"] <= 10.0
    assert abs(grams["receiving container"] - 100.0) == pytest.approx(grams["target"], abs=0.01)
    total = grams["receiving container"] + grams["spilled"] + grams["pouring container"]
    assert total == pytest.approx(200.0, abs=2.0)  # whole particles, some still in flight
    assert out.stat().st_size > 10_000
    assert main([*argv, "--target-g", "250"]) == 2  # more than the container starts with
    assert "target_g (250 g) must be below mass_g (200 g)" in capsys.readouterr().err


def test_the_listings_are_headed_tables_of_names_the_library_accepts(capsys) -> None:
    """``pourbench liquids`` and ``containers`` print a header, a rule and one row per entry,
    each row's first cell a name that the liquid or container look-up takes as printed."""
    from pourbench.containers import container_names, get_container
    from pourbench.fluids import liquid_names, liquid_profile

    for command, names, lookup in (
        ("liquids", liquid_names(), liquid_profile),
        ("containers", container_names(), get_container),
    ):
        assert main([command]) == 0
        header, rule, *rows = capsys.readouterr().out.splitlines()
        assert header.split()[0] == "name" and set(rule.replace(" ", "")) == {"-"}
        assert len(rows) == len(names)
        printed = [re.split(r"\s{2,}", row)[0] for row in rows]
        for name in printed:
            lookup(name)  # raises for a name it does not take
        assert "dish soap" in printed or command == "containers"
