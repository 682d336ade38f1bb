"""Warp initialises without its no-driver notice; everything else it prints gets through."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

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
    from pourbench.fluids import PBFSolver

    PBFSolver(1)  # the kernels compiled into Warp's cache, if this is the first solver
    code = "from pourbench.fluids import PBFSolver; PBFSolver(1)"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stderr == ""
    assert run.stdout == ""


@pytest.mark.slow
def test_a_solver_says_when_its_kernels_compile(tmp_path) -> None:
    """With an empty kernel cache the first solver says it compiles, before any step; the
    next process loads them from the cache without a word."""
    env = {**os.environ, "WARP_CACHE_PATH": str(tmp_path)}
    code = "from pourbench.fluids import PBFSolver; PBFSolver(1); print('built')"
    runs = [
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
        for _ in range(2)
    ]
    assert runs[0].returncode == 0 and runs[0].stdout == "built\n", runs[0].stderr
    assert "compiling the liquid solver's Warp kernels for cpu" in runs[0].stderr
    assert runs[1].stderr == "" and runs[1].stdout == "built\n"
