"""MuJoCo scene composition with MjSpec: robots, table, containers, sensors.

Robots are MJCF files under ``pourbench/assets/mjcf`` (``movo.xml``, ``panda.xml``). Each has a
keyframe ``home``; its arm actuators are integrated-velocity servos (``ctrl`` = joint velocity in
rad/s within the robot's velocity limits, activation = joint position target), and its bodies
carry gravity compensation, so the robot stands still at ``home`` with zero controls.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import mujoco

from pourbench.errors import UnknownNameError

ROBOTS: tuple[str, ...] = ("movo", "panda")
"""Names accepted by :func:`load_robot` and :func:`robot_spec`."""

MJCF_DIR = Path(str(resources.files("pourbench") / "assets" / "mjcf"))


def robot_path(name: str) -> Path:
    """Path of a robot's MJCF file.

    Raises:
        UnknownNameError: ``name`` is not one of :data:`ROBOTS`.
    """
    if name not in ROBOTS:
        raise UnknownNameError("robot", name, ROBOTS)
    return MJCF_DIR / f"{name}.xml"


def robot_spec(name: str) -> mujoco.MjSpec:
    """A fresh, editable :class:`mujoco.MjSpec` of robot ``name`` ("movo" or "panda")."""
    return mujoco.MjSpec.from_file(str(robot_path(name)))


def load_robot(name: str) -> mujoco.MjModel:
    """Compiled model of robot ``name`` ("movo" or "panda") alone, base fixed at the origin."""
    return robot_spec(name).compile()
