"""The planning view of the shipped robots: which joints, site and capsules make each arm.

Names follow the asset contract of :mod:`pourbench.scene`: Movo arms ``right_joint_1..7`` /
``left_joint_1..7`` with sites ``right_ee`` / ``left_ee``, capsules ``right_col_1..3`` /
``left_col_1..3`` and body boxes ``body_col_1..3``; Panda ``joint_1..7``, site ``ee``,
capsules ``col_1..5``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from pourbench.errors import UnknownNameError
from pourbench.planners.distance import Obstacle, obstacle_from_mujoco_geom
from pourbench.planners.kinematics import ArmKinematics


@dataclass(frozen=True)
class ArmSpec:
    """One plannable arm of a robot.

    Attributes:
        robot: robot name for :func:`pourbench.scene.robot_spec`.
        joints: the arm's joints in order.
        capsules: the arm's collision capsules (geom group 3).
        body_boxes: static collision geoms of the robot's body (obstacles for this arm).
        other_capsules: the other arm's capsules (Movo), an obstacle in dual-arm planning.
        speed_cap: cap on the joint-speed bound taken from the actuators (rad/s).
    """

    robot: str
    joints: tuple[str, ...]
    ee_site: str
    capsules: tuple[str, ...]
    body_boxes: tuple[str, ...] = ()
    other_capsules: tuple[str, ...] = ()
    speed_cap: float = 1.0


def _movo(side: str, other: str) -> ArmSpec:
    return ArmSpec(
        robot="movo",
        joints=tuple(f"{side}_joint_{i}" for i in range(1, 8)),
        ee_site=f"{side}_ee",
        capsules=tuple(f"{side}_col_{i}" for i in range(1, 4)),
        body_boxes=("body_col_1", "body_col_2", "body_col_3"),
        other_capsules=tuple(f"{other}_col_{i}" for i in range(1, 4)),
    )


ARMS: dict[str, ArmSpec] = {
    "movo": _movo("right", "left"),
    "movo_left": _movo("left", "right"),
    "panda": ArmSpec(
        robot="panda",
        joints=tuple(f"joint_{i}" for i in range(1, 8)),
        ee_site="ee",
        capsules=tuple(f"col_{i}" for i in range(1, 6)),
    ),
}
"""Plannable arms: ``movo`` is the Movo's right Jaco2, ``movo_left`` its left one."""


def arm_spec(name: str) -> ArmSpec:
    """The :class:`ArmSpec` called ``name``.

    Raises:
        UnknownNameError: ``name`` is not in :data:`ARMS` (a ``ValueError``).
    """
    if not isinstance(name, str) or name not in ARMS:
        raise UnknownNameError("robot", name, ARMS)
    return ARMS[name]


def robot_mjspec(arm: ArmSpec) -> mujoco.MjSpec:
    """A fresh MjSpec of the arm's robot (from :mod:`pourbench.scene`)."""
    from pourbench.scene import robot_spec

    return robot_spec(arm.robot)


def joint_speed_limits(model: mujoco.MjModel, joints: Sequence[str], cap: float) -> np.ndarray:
    """Joint-speed bounds (rad/s): each joint's actuator ``ctrlrange`` (velocity servos),
    capped at ``cap``; ``cap`` for joints without such an actuator."""
    out = np.full(len(joints), cap)
    for i, name in enumerate(joints):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        for a in range(model.nu):
            if model.actuator_trnid[a, 0] == jid and model.actuator_ctrllimited[a]:
                out[i] = min(cap, float(np.abs(model.actuator_ctrlrange[a]).max()))
    return out


def arm_kinematics(
    name: str, model: mujoco.MjModel | None = None, base_qpos: np.ndarray | None = None
) -> ArmKinematics:
    """:class:`ArmKinematics` of arm ``name`` on ``model`` (the robot alone by default).

    Raises:
        UnknownNameError: unknown arm name.
    """
    arm = arm_spec(name)
    if model is None:
        model = robot_mjspec(arm).compile()
    return ArmKinematics(model, arm.joints, arm.ee_site, arm.capsules, base_qpos=base_qpos)


def geom_obstacles(kin: ArmKinematics, geoms: Sequence[str], q: np.ndarray | None = None):
    """Planner obstacles for named geoms of the same model, posed with the arm at ``q``
    (default: home) and all other joints at ``kin.base_qpos``."""
    m = kin.model
    d = mujoco.MjData(m)
    d.qpos[:] = kin.full_qpos(kin.home() if q is None else q)
    mujoco.mj_kinematics(m, d)
    out: list[Obstacle] = []
    for g in geoms:
        gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g)
        if gid < 0:
            raise UnknownNameError("geom", g, [])
        out.append(
            obstacle_from_mujoco_geom(
                int(m.geom_type[gid]), d.geom_xpos[gid], d.geom_xmat[gid], m.geom_size[gid]
            )
        )
    return out
