"""Initialise Warp once, without its CUDA-driver notice on machines that have no GPU.

Warp's native library writes "Warp CUDA warning: Could not find or load the NVIDIA CUDA
driver …" to the process's stderr when it initialises on a machine without the driver. CPU is
pourbench's default, so on such machines that line would open the output of every command.
:func:`init_warp` initialises Warp with file descriptor 2 captured and writes everything else
it printed back to stderr. A run that asks for ``device="cuda"`` there still gets pourbench's
own error (:func:`pourbench.fluids.solver.cuda_available` is checked first).
"""

from __future__ import annotations

import os
import sys
import tempfile

import warp as wp

NO_DRIVER_NOTICE = "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver"


def without_no_driver_notice(text: str) -> str:
    """``text`` less the lines that start with Warp's no-driver notice."""
    lines = text.splitlines(keepends=True)
    return "".join(line for line in lines if not line.startswith(NO_DRIVER_NOTICE))


def init_warp() -> None:
    """Initialise Warp (idempotent); its native stderr output passes through, filtered."""
    wp.config.log_level = wp.LOG_WARNING  # no greeting or module-load lines on stdout
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable descriptor 2 (embedded interpreters)
        wp.init()
        return
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            rest = without_no_driver_notice(captured.read().decode(errors="replace"))
            if rest:
                sys.stderr.write(rest)
                sys.stderr.flush()
