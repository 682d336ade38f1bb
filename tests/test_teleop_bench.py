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
    rows = doc["rows"]
    assert len(rows) == 26 * 3
    for r in rows:
        for key in ("task", "variation", "method", "max_displacement_cm", "rmse_cm"):
            assert key in r
    assert {r["method"] for r in rows} == {"none", "standard", "skill_cpd"}
    assert (tmp_path / "teleop.md").exists() and (tmp_path / "teleop.json").exists()
    # no shared autonomy holds still, so its jump at reconnection is the largest
    mean = {
        m: sum(r["max_displacement_cm"] for r in rows if r["method"] == m) / 26
        for m in ("none", "standard", "skill_cpd")
    }
    assert mean["skill_cpd"] < mean["standard"] < mean["none"]
