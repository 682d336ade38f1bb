"""Warp initialises without its no-driver notice; everything else it prints gets through."""

from __future__ import annotations

import os
import subprocess
import sys

from pourbench.fluids import warp_setup


def test_only_the_no_driver_notice_is_dropped(monkeypatch, capfd) -> None:
    notice = f"{warp_setup.NO_DRIVER_NOTICE}. GPU execution will not be available.\n"

    def noisy_init() -> None:  # what Warp's native library does: writes to descriptor 2
        os.write(2, f"first line\n{notice}Warp CUDA error: something else\n".encode())

    monkeypatch.setattr(warp_setup.wp, "init", noisy_init)
    warp_setup.init_warp()
    err = capfd.readouterr().err
    assert err == "first line\nWarp CUDA error: something else\n"


def test_importing_the_solver_prints_nothing_on_stderr() -> None:
    code = "from pourbench.fluids import PBFSolver; PBFSolver(1)"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stderr == ""
    assert run.stdout == ""
