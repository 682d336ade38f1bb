"""The demo command: accounting of the printed grams, the recording, and bad input."""

from __future__ import annotations

import re

import pytest

from pourbench.cli import main


def test_demo_accounts_for_every_gram_and_writes_a_recording(tmp_path, capsys) -> None:
    out = tmp_path / "demo.rrd"
    assert main(["demo", "--seconds", "2.5", "--mass-g", "100", "--out", str(out)]) == 0
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
