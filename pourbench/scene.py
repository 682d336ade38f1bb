"""MuJoCo scene composition with MjSpec: robots, table, containers, sensors.

Robots are MJCF files under ``pourbench/assets/mjcf`` (``movo.xml``, ``panda.xml``). Each has a
keyframe ``home``; its arm actuators are integrated-velocity servos (``ctrl`` = joint velocity in
rad/s within the robot's velocity limits, activation = joint position target), and its bodies
carry gravity compensation, so the robot stands still at ``home`` with zero controls.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial.distance import cdist

from pourbench.containers import (
    Container,
    add_container_body,
    container_names,
    get_container,
)
from pourbench.errors import InvalidParameterError, UnknownNameError, check_positive

ROBOTS: tuple[str, ...] = ("movo", "panda")
"""Names accepted by :func:`load_robot` and :func:`robot_spec`."""

MJCF_DIR = Path(str(resources.files("pourbench") / "assets" / "mjcf"))


def robot_spec(name: str) -> mujoco.MjSpec:
    """A fresh, editable :class:`mujoco.MjSpec` of robot ``name`` ("movo" or "panda").

    Raises:
        UnknownNameError: ``name`` is not one of :data:`ROBOTS`.
    """
    if name not in ROBOTS:
        raise UnknownNameError("robot", name, ROBOTS)
    return mujoco.MjSpec.from_file(str(MJCF_DIR / f"{name}.xml"))


def load_robot(name: str) -> mujoco.MjModel:
    """Compiled model of robot ``name`` ("movo" or "panda") alone, base fixed at the origin."""
    return robot_spec(name).compile()


# ----------------------------------------------------------------------------------- pour scenes

TABLE_HEIGHT = 0.75
"""Height of the table top, m (mocap and Panda scenes)."""
TABLE_HALF_XY = (0.4, 0.5)
"""Half extents (m) of the table top of the robot-free scene, centred under the receiving
container."""
MOVO_TABLE_HEIGHT = 0.6
"""Height of the table in front of the Movo, m: below anything its grippers hold at home."""

STATIC_CONTYPE = 1
"""Contact bit of static geoms (floor, table, obstacles): robots and containers touch them."""
_STATIC = {"contype": STATIC_CONTYPE, "conaffinity": 0}

_PANDA_PEDESTAL = 0.2  # the Panda stands on a 0.2 m pedestal beside the table


@dataclass(frozen=True)
class PourScene:
    """A composed pouring scene.

    Attributes:
        spec: the MjSpec it was compiled from (edit and recompile to extend it).
        model: the compiled model.
        robot: "movo", "panda" or None.
        pouring: the pouring container; its body is called ``"pouring"``.
        receiving: the receiving container; its body is called ``"receiving"``.
        scale_force: force sensor (3 values, N, in the sensor site frame) that weighs the
            receiving container: the left F/T sensor on the Movo, a table scale otherwise.
        scale_torque: the matching torque sensor (N m).
        pouring_mocap: whether ``"pouring"`` is a mocap body (``robot=None``).
    """

    spec: mujoco.MjSpec
    model: mujoco.MjModel
    robot: str | None
    pouring: Container
    receiving: Container
    scale_force: str
    scale_torque: str
    pouring_mocap: bool

    def make_data(self) -> mujoco.MjData:
        """Fresh data at the robot's ``home`` keyframe (if any), kinematics computed."""
        data = mujoco.MjData(self.model)
        if self.model.nkey:
            mujoco.mj_resetDataKeyframe(self.model, data, self.model.key("home").id)
        mujoco.mj_forward(self.model, data)
        return data


def _frame(xmat: np.ndarray, xpos: np.ndarray) -> np.ndarray:
    """The 4 x 4 homogeneous transform of a rotation matrix (9 values) and a position."""
    h = np.eye(4)
    h[:3, :3] = xmat.reshape(3, 3)
    h[:3, 3] = xpos
    return h


def _pos_quat(h: np.ndarray) -> tuple[list[float], list[float]]:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, h[:3, :3].ravel())
    return h[:3, 3].tolist(), quat.tolist()


def _grasp_in_body(
    model: mujoco.MjModel, body: str, site: str, container: Container
) -> tuple[list[float], list[float]]:
    """Pose, in ``body``'s frame, that puts the container's mount site on ``site``."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    b, s = model.body(body).id, model.site(site).id
    site_h = _frame(data.site_xmat[s], data.site_xpos[s])
    site_in_body = np.linalg.inv(_frame(data.xmat[b], data.xpos[b])) @ site_h
    mount_pos, mount_quat = container.mount_pose()
    mount_rot = np.zeros(9)
    mujoco.mju_quat2Mat(mount_rot, mount_quat)
    return _pos_quat(site_in_body @ np.linalg.inv(_frame(mount_rot, mount_pos)))


def _add_environment(
    spec: mujoco.MjSpec,
    table_center: tuple[float, float],
    size: tuple[float, float],
    height: float = TABLE_HEIGHT,
) -> None:
    spec.option.timestep = 0.002
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    world = spec.worldbody
    world.add_light(name="sun", pos=[0.5, -0.5, 3.0], dir=[-0.2, 0.2, -1.0])
    world.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[5.0, 5.0, 0.1],
        rgba=[0.82, 0.82, 0.8, 1.0],
        **_STATIC,
    )
    table = world.add_body(name="table", pos=[table_center[0], table_center[1], 0.0])
    table.add_geom(
        name="table_top",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=[0.0, 0.0, height - 0.02],
        size=[size[0], size[1], 0.02],
        rgba=[0.6, 0.45, 0.3, 1.0],
        **_STATIC,
    )
    for sx in (-1, 1):
        for sy in (-1, 1):
            table.add_geom(
                type=mujoco.mjtGeom.mjGEOM_BOX,
                pos=[sx * (size[0] - 0.04), sy * (size[1] - 0.04), (height - 0.04) / 2],
                size=[0.025, 0.025, (height - 0.04) / 2],
                rgba=[0.45, 0.33, 0.22, 1.0],
                **_STATIC,
            )
    world.add_camera(name="overview", pos=[1.9, -1.1, 1.7], xyaxes=[0.5, 0.87, 0, -0.4, 0.23, 0.89])


def _add_scale(spec: mujoco.MjSpec, body: mujoco.MjsBody) -> tuple[str, str]:
    """A force and a torque sensor at a ``scale`` site of ``body``; their names."""
    body.add_site(name="scale", size=[0.01] * 3)
    sensors = {
        "scale_force": mujoco.mjtSensor.mjSENS_FORCE,
        "scale_torque": mujoco.mjtSensor.mjSENS_TORQUE,
    }
    for name, kind in sensors.items():
        spec.add_sensor(name=name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="scale")
    return "scale_force", "scale_torque"


def _robot_at_table(robot: str) -> mujoco.MjSpec:
    """Robot spec plus floor and table: the Movo at a low table, the Panda on a pedestal."""
    spec = robot_spec(robot)
    if robot == "movo":
        _add_environment(spec, (0.78, 0.0), (0.3, 0.5), MOVO_TABLE_HEIGHT)
        return spec
    spec.body("link_0").pos = [0.0, 0.0, _PANDA_PEDESTAL]
    spec.worldbody.add_geom(
        name="pedestal",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=[0.0, 0.0, _PANDA_PEDESTAL / 2],
        size=[0.12, 0.12, _PANDA_PEDESTAL / 2],
        rgba=[0.3, 0.3, 0.32, 1.0],
        **_STATIC,
    )
    _add_environment(spec, (0.65, 0.0), (0.3, 0.5))
    return spec


def build_pour_scene(
    pouring: str = "training",
    receiving: str = "tray",
    robot: str | None = None,
) -> PourScene:
    """Compose a pouring scene: table, the two containers and optionally a robot.

    * ``robot=None``: the pouring container is a mocap body (its pose is the action), upright
      above the receiving container, which stands on the table on a force/torque "scale".
    * ``robot="movo"``: the pouring container is welded in the right gripper (mount site on
      ``right_ee``), the receiving one in the left gripper (on ``left_ee``); the left wrist's
      F/T sensor weighs it, as in the thesis.
    * ``robot="panda"``: the pouring container is welded in the hand (mount on ``tcp``), the
      receiving one stands on the table on a force/torque scale.

    Held containers carry gravity compensation like the robot's links (a controller that knows
    its payload); F/T sensors still measure their weight.

    Args:
        pouring: name of the pouring container (``containers.toml``).
        receiving: name of the receiving container.
        robot: None, "movo" or "panda".

    Raises:
        UnknownNameError: unknown robot or container (a ``ValueError`` listing the known ones).
        InvalidParameterError: a receiving container (the tray) as the pouring one.
    """
    if robot is not None and robot not in ROBOTS:
        raise UnknownNameError("robot", robot, ROBOTS)
    pour, recv = get_container(pouring), get_container(receiving)
    if pour.role == "receiving":
        pours = ", ".join(sorted(container_names("training") + container_names("novel")))
        raise InvalidParameterError(
            f"{pouring!r} is a receiving container and cannot pour; pouring containers: {pours}"
        )
    if robot is None:
        spec = mujoco.MjSpec()
        spec.modelname = f"pour_{pouring}_{receiving}"
        _add_environment(spec, (0.0, 0.0), TABLE_HALF_XY)
        world = spec.worldbody
        rbody = add_container_body(spec, world, recv, name="receiving", pos=(0, 0, TABLE_HEIGHT))
        scale = _add_scale(spec, rbody)
        lift = TABLE_HEIGHT + recv.rim_height + 0.05
        add_container_body(
            spec,
            world,
            pour,
            name="pouring",
            pos=(0.0, -recv.diameter / 4, lift),
            mocap=True,
        )
        return PourScene(spec, spec.compile(), None, pour, recv, *scale, True)

    spec = _robot_at_table(robot)
    spec.modelname = f"{robot}_pour_{pouring}_{receiving}"
    bare = robot_spec(robot).compile()  # grasp offsets are relative to gripper bodies
    if robot == "movo":  # (body name, container, the gripper body holding it, its grasp site)
        held = (
            ("pouring", pour, "right_gripper", "right_ee"),
            ("receiving", recv, "left_gripper", "left_ee"),
        )
        scale = ("left_ft_force", "left_ft_torque")
    else:
        held = (("pouring", pour, "hand", "tcp"),)
        home = mujoco.MjData(bare)
        mujoco.mj_resetDataKeyframe(bare, home, bare.key("home").id)
        mujoco.mj_kinematics(bare, home)
        tcp = home.site_xpos[bare.site("tcp").id] + (0.0, 0.0, _PANDA_PEDESTAL)
        # beside the held container (upright, they never touch), on the pouring side (+y)
        side = tcp[1] + (pour.diameter + recv.diameter) / 2 + 0.02
        spot = (tcp[0] + pour.diameter / 2, side, TABLE_HEIGHT)
        rbody = add_container_body(spec, spec.worldbody, recv, name="receiving", pos=spot)
        scale = _add_scale(spec, rbody)
    for name, c, body, site in held:
        pos, quat = _grasp_in_body(bare, body, site, c)
        b = add_container_body(spec, spec.body(body), c, name=name, pos=pos, quat=quat)
        b.gravcomp = 1.0
    return PourScene(spec, spec.compile(), robot, pour, recv, *scale, False)


def body_clearance(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    body1: str = "pouring",
    body2: str = "receiving",
    cutoff: float = 0.02,
) -> float:
    """Smallest signed distance between the geoms of two bodies, m (< 0: they overlap).

    MuJoCo makes no contacts between bodies that cannot move dynamically (a mocap pouring
    container and a receiving container fixed to the world), so collision checks between
    containers use this instead. Geom pairs whose bounding spheres are further apart than
    ``cutoff`` are skipped; the result is ``cutoff`` when nothing is closer.

    Raises:
        UnknownNameError: a body name is not in the model (or not a string).
        InvalidParameterError: ``body1 == body2``, ``cutoff`` not a finite number > 0, or
            ``data`` not made for ``model``.
    """
    cutoff = check_positive("cutoff", cutoff)
    if data.geom_xpos.shape[0] != model.ngeom or data.qpos.size != model.nq:
        raise InvalidParameterError("data does not belong to model (geom or qpos counts differ)")
    ids = [
        mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) if isinstance(n, str) else -1
        for n in (body1, body2)
    ]
    for n, i in zip((body1, body2), ids, strict=True):
        if i < 0:
            raise UnknownNameError("body", n, [model.body(b).name for b in range(model.nbody)])
    if ids[0] == ids[1]:
        raise InvalidParameterError(f"body1 and body2 are the same body {body1!r}")
    geoms = [np.flatnonzero(model.geom_bodyid == b) for b in ids]
    if len(geoms[0]) == 0 or len(geoms[1]) == 0:
        return cutoff
    gap = cdist(data.geom_xpos[geoms[0]], data.geom_xpos[geoms[1]])  # a tenth of numpy's time
    gap -= model.geom_rbound[geoms[0]][:, None] + model.geom_rbound[geoms[1]][None]
    best = cutoff
    for i, j in zip(*np.nonzero(gap < cutoff), strict=True):
        d = mujoco.mj_geomDistance(model, data, int(geoms[0][i]), int(geoms[1][j]), cutoff, None)
        best = min(best, d)
    return float(best)
