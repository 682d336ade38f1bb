"""``pourbench bench teleop --quick --json``: one JSON object with the documented rows."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import pytest


@pytest.mark.slow
def test_quick_bench_prints_one_json_object(tmp_path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "pourbench.cli", "bench", "teleop", "--quick", "--json",
         "--out", str(tmp_path)],
        capture_output=True, text=True, check=True, timeout=600,
    )  # fmt: skip
    doc = json.loads(out.stdout)  # exactly one JSON document on stdout
    rows = [r for r in doc["rows"] if r["library_size"] == 26]  # Table 5.1's rows
    assert len(rows) == 26 * 3
    open_set = [r for r in doc["rows"] if r["library_size"] == 21]
    assert {r["skill"] for r in open_set} == set("ABCDEFGHIJKLMNOPQRSTUVWXYZ")
    assert doc["open_set"]["rates"]["letter not in library"]["runs"] == 5
    for r in rows:
        for key in ("task", "variation", "method", "max_displacement_cm", "rmse_cm"):
            assert key in r
    assert {r["method"] for r in rows} == {"none", "standard", "skill_cpd"}
    # every confusion is a wrong letter of a Table 5.1 run, and its count is those runs'
    wrong = {(r["skill"], r["label"]) for r in rows if r["label"] not in (None, r["skill"])}
    assert {(c["letter"], c["recognised_as"]) for c in doc["confusions"]} == wrong
    assert (tmp_path / "teleop.md").exists() and (tmp_path / "teleop.json").exists()
    assert (tmp_path / "teleop_confidence.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # no shared autonomy holds still, so its jump at reconnection is the largest
    mean = {
        m: sum(r["max_displacement_cm"] for r in rows if r["method"] == m) / 26
        for m in ("none", "standard", "skill_cpd")
    }
    assert mean["skill_cpd"] < mean["standard"] < mean["none"]


def _cores_and_threads() -> tuple[set[int], list[tuple[str, int]]]:
    from threadpoolctl import threadpool_info

    return os.sched_getaffinity(0), [(m["filepath"], m["num_threads"]) for m in threadpool_info()]


@pytest.mark.parametrize("fails", [False, True])
def test_the_suite_gives_its_cores_back(monkeypatch, request, fails) -> None:
    """The suite runs on one CPU with BLAS / OpenMP on one thread, and afterwards (also when
    it fails) the process has its CPUs and thread limits back, so the suites ``bench all``
    runs after it, and their workers, are not held to one core."""
    from threadpoolctl import threadpool_limits

    from pourbench.bench import teleop

    if not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs a process that may run on two CPUs")
    allowed = os.sched_getaffinity(0)
    request.addfinalizer(lambda: os.sched_setaffinity(0, allowed))  # should this test fail
    during = []

    def body(args, pinned):
        during.append(_cores_and_threads())
        if fails:
            raise RuntimeError("the suite failed")
        return 0

    monkeypatch.setattr(teleop, "_run", body)
    with threadpool_limits(2):  # a limit other than the suite's
        before = _cores_and_threads()
        assert any(n == 2 for _, n in before[1]), "no BLAS / OpenMP library loaded"
        if fails:
            with pytest.raises(RuntimeError, match="the suite failed"):
                teleop.run(argparse.Namespace())
        else:
            assert teleop.run(argparse.Namespace()) == 0
        after = _cores_and_threads()
    ((cpus, threads),) = during
    assert len(cpus) == 1 and all(n == 1 for _, n in threads)
    assert after == before, "the suite kept this process on one core"


def test_confusions_count_the_wrong_letters_of_table_5_1s_held_out_runs() -> None:
    from pourbench.bench.teleop import _confusions

    def row(skill, label, switched, method="skill_cpd", cls="identical"):
        return {
            "method": method,
            "operator": "held-out demo",
            "task": "2d",
            "class": cls,
            "skill": skill,
            "label": label,
            "switched": switched,
        }

    rows = [
        row("A", "N", True),
        row("A", "N", False),
        row("A", "A", True),
        row("A", "A", True),
        row("K", "X", False),
        row("K", "K", True),
        row("A", "N", True, method="standard"),  # the same recognition, counted once
        row("B", "U", True, cls="letter not in library"),  # not a Table 5.1 class
    ]
    out, lines = _confusions(rows)
    assert [(c["letter"], c["recognised_as"], c["runs"], c["of"]) for c in out] == [
        ("A", "N", 2, 4),
        ("K", "X", 1, 2),
    ]
    assert out[0]["rate"] == 0.5
    assert (
        lines[0] == "- A recognised as N: 2 of 4 runs (50 %), 1 of them switched to the wrong skill"
    )
    assert _confusions([row("A", "A", True)]) == ([], ["- none"])
