"""README's Python examples run as printed, and do what the text around them says."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)


def _run(code: str) -> str:
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=False
    )
    assert run.returncode == 0, run.stderr[-3000:]
    return run.stdout


def _block(word: str) -> str:
    (block,) = [b for b in BLOCKS if word in b]
    return block


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_every_example_runs(index: int) -> None:
    _run(BLOCKS[index])


@pytest.mark.slow
def test_nmpc_reaches_the_goal_past_the_ball() -> None:
    success, steps, error_m = _run(_block("NMPCPlanner")).split()
    assert success == "True" and int(steps) < 150 and float(error_m) <= 0.005


@pytest.mark.slow
def test_the_skill_takes_over_during_the_outage_and_hands_back() -> None:
    out = _run(_block("SkillCPD"))
    states = re.findall(r"'(\w+)'\)", out)  # each transition's new state
    assert states == ["skill", "handback", "direct"], out
