"""Initialise Warp once, without its CUDA-driver notice on machines that have no GPU, and
load the solver's kernel modules before any timed work, saying so when they must compile.

Warp's native library writes "Warp CUDA warning: Could not find or load the NVIDIA CUDA
driver …" to the process's stderr when it initialises on a machine without the driver. CPU is
pourbench's default, so on such machines that line would open the output of every command.
:func:`init_warp` initialises Warp with file descriptor 2 captured and writes everything else
it printed back to stderr. A run that asks for ``device="cuda"`` there still gets pourbench's
own error (:func:`pourbench.fluids.solver.cuda_available` is checked first).

Warp compiles a kernel module on its first launch and caches the binary. The first run after
an install or an update of the kernels compiles for minutes; :func:`load_kernels` does it up
front with a line on stderr, so that no progress bar times the compile as a step.
"""

from __future__ import annotations

import os
import sys
import tempfile
from types import ModuleType

import warp as wp

NO_DRIVER_NOTICE = "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver"


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
            lines = captured.read().decode(errors="replace").splitlines(keepends=True)
            rest = "".join(line for line in lines if not line.startswith(NO_DRIVER_NOTICE))
            if rest:
                sys.stderr.write(rest)
                sys.stderr.flush()


_LOADED: set[tuple[str, str]] = set()  # (module, device) pairs this process has loaded


def load_kernels(modules: list[ModuleType], device: wp.context.Device) -> None:
    """Load ``modules``' kernels for ``device`` now; a line on stderr first when any of them
    is not in Warp's kernel cache and so compiles."""
    modules = [m for m in modules if (m.__name__, str(device)) not in _LOADED]
    block_dim = 1 if device.is_cpu else None  # Warp launches CPU kernels with block_dim 1
    cache = wp.config.kernel_cache_dir
    missing = [
        m.__name__
        for m in modules
        if not os.path.isdir(
            os.path.join(cache, wp.get_module(m.__name__).get_module_identifier(block_dim))
        )
    ]
    if missing:
        print(
            f"pourbench: compiling the liquid solver's Warp kernels for {device} "
            f"({', '.join(missing)}): the first run after an install takes minutes, later "
            "runs load them from Warp's cache",
            file=sys.stderr,
            flush=True,
        )
    for m in modules:
        wp.load_module(m, device=device, block_dim=block_dim)
        _LOADED.add((m.__name__, str(device)))
