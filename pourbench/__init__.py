"""pourbench: MuJoCo + Warp liquid-pouring and assistive-teleoperation benchmark.

Subpackages, in import order: ``assets`` → ``scene`` → ``fluids`` → ``envs`` → ``agents``
→ ``bench``. ``planners`` and ``teleop`` are standalone libraries.
"""

from __future__ import annotations

import os
import sys

__version__ = "0.1.0"


def _headless_gl_default() -> None:
    """Let MuJoCo render offscreen on a Linux machine without a display.

    MuJoCo picks its OpenGL backend once, when it is first imported, and its default (GLFW)
    needs a display. Without one, and unless the user chose a backend (``MUJOCO_GL``), EGL is
    chosen where its library is installed (else OSMesa where that is), so
    ``render_mode="rgb_array"`` works on servers and in CI. Where neither is installed nothing
    is chosen: MuJoCo imports the backend it is told to at its own import, so a missing one
    would break ``import mujoco`` itself, not only rendering (rendering then fails with an
    error naming ``MUJOCO_GL``).
    """
    if (
        sys.platform.startswith("linux")
        and "MUJOCO_GL" not in os.environ
        and not os.environ.get("DISPLAY")
        and not os.environ.get("WAYLAND_DISPLAY")
        and "mujoco" not in sys.modules
    ):
        from ctypes.util import find_library

        for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
            if find_library(library):
                os.environ["MUJOCO_GL"] = backend
                break


_headless_gl_default()


POUR_ID = "pourbench/Pour-v0"
ROBOT_POUR_ID = "pourbench/PourRobot-v0"
ENV_IDS: tuple[str, ...] = (POUR_ID, ROBOT_POUR_ID)
"""The Gymnasium ids :func:`register_envs` registers."""


def register_envs() -> None:
    """Register the Gymnasium ids ``pourbench/...`` (the ``gymnasium.envs`` entry point).

    Importing the environments is deferred to ``gymnasium.make``; registration only records
    entry-point strings, so ``import pourbench`` stays light.
    """
    from gymnasium.envs.registration import register, registry

    if POUR_ID not in registry:
        register(
            id=POUR_ID,
            entry_point="pourbench.envs.pour_v0:PourEnv",
            vector_entry_point="pourbench.envs.vector:PourVectorEnv",
        )
    if ROBOT_POUR_ID not in registry:
        register(
            id=ROBOT_POUR_ID,
            entry_point="pourbench.envs.robot_pour:RobotPourEnv",
        )


try:  # register on import when Gymnasium is installed
    register_envs()
except ImportError:  # pragma: no cover - gymnasium is a core dependency
    pass

__all__ = ["ENV_IDS", "POUR_ID", "ROBOT_POUR_ID", "__version__", "register_envs"]
