"""``pourbench bench teleop --quick --json``: one JSON object with the documented rows."""

from __future__ import annotations

import json
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
    assert (tmp_path / "teleop.md").exists() and (tmp_path / "teleop.json").exists()
    assert (tmp_path / "teleop_confidence.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # no shared autonomy holds still, so its jump at reconnection is the largest
    mean = {
        m: sum(r["max_displacement_cm"] for r in rows if r["method"] == m) / 26
        for m in ("none", "standard", "skill_cpd")
    }
    assert mean["skill_cpd"] < mean["standard"] < mean["none"]
