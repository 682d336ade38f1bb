"""Robot models: forward kinematics against the thesis' DH tables, limits, gripper, home pose."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from pourbench.errors import UnknownNameError
from pourbench.scene import ROBOTS, load_robot

PI = math.pi

# Thesis Table 4.1 (Jaco2, distal convention): theta offset, d, a, alpha.
JACO_DH = (
    (PI, -0.2755, 0.0, PI / 2),
    (0.0, 0.0, 0.0, PI / 2),
    (0.0, -0.41, 0.0, PI / 2),
    (0.0, -0.0098, 0.0, PI / 2),
    (0.0, -0.3111, 0.0, PI / 2),
    (PI, 0.0, 0.0, -PI / 2),
    (PI / 2, -0.2638, 0.0, PI),
)
# Thesis Table 4.6 (Panda, modified convention): d, a_{i-1}, alpha_{i-1}.
PANDA_MDH = (
    (0.333, 0.0, 0.0),
    (0.0, 0.0, -PI / 2),
    (0.316, 0.0, PI / 2),
    (0.0, 0.0825, PI / 2),
    (0.384, -0.0825, -PI / 2),
    (0.0, 0.0, PI / 2),
    (0.107, 0.088, PI / 2),
)
# Thesis Table 4.7.
PANDA_QMAX = (2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973)
PANDA_QMIN = (-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973)
PANDA_QDMAX = (2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100)
PANDA_QDDMAX = (15, 7.5, 10, 12.5, 15, 20, 20)


def _rot_z(t: float) -> np.ndarray:
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def _trans(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def jaco_fk(q: np.ndarray) -> np.ndarray:
    """Distal DH (Eq. 4.24): H = Rz(theta) Tz(d) Tx(a) Rx(alpha), chained from frame 0."""
    h = np.eye(4)
    for qi, (off, d, a, al) in zip(q, JACO_DH, strict=True):
        h = h @ _rot_z(qi + off) @ _trans(0, 0, d) @ _trans(a, 0, 0) @ _rot_x(al)
    return h


def panda_fk(q: np.ndarray) -> np.ndarray:
    """Modified DH (Eq. 4.25): H = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta) Tz(d)."""
    h = np.eye(4)
    for qi, (d, a, al) in zip(q, PANDA_MDH, strict=True):
        h = h @ _rot_x(al) @ _trans(a, 0, 0) @ _rot_z(qi) @ _trans(0, 0, d)
    return h


def _site_pose(data: mujoco.MjData, model: mujoco.MjModel, name: str) -> np.ndarray:
    sid = model.site(name).id
    h = np.eye(4)
    h[:3, :3] = data.site_xmat[sid].reshape(3, 3)
    h[:3, 3] = data.site_xpos[sid]
    return h


def _pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    dp = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    cos = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1.0) / 2.0
    return dp, float(math.acos(np.clip(cos, -1.0, 1.0)))


@pytest.mark.parametrize(
    ("robot", "prefix", "fk"),
    [("movo", "right_", jaco_fk), ("movo", "left_", jaco_fk), ("panda", "", panda_fk)],
)
def test_forward_kinematics_matches_dh_table(robot: str, prefix: str, fk) -> None:
    model = load_robot(robot)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    rng = np.random.default_rng(0)
    adr = [model.jnt_qposadr[model.joint(f"{prefix}joint_{i}").id] for i in range(1, 8)]
    worst_p = worst_r = 0.0
    for _ in range(100):
        if robot == "panda":
            q = rng.uniform(PANDA_QMIN, PANDA_QMAX)
        else:
            q = rng.uniform(-2 * PI, 2 * PI, size=7)
        data.qpos[adr] = q
        mujoco.mj_kinematics(model, data)
        base = _site_pose(data, model, f"{prefix}arm_base")
        ee = _site_pose(data, model, f"{prefix}ee")
        dp, dr = _pose_error(np.linalg.inv(base) @ ee, fk(q))
        worst_p, worst_r = max(worst_p, dp), max(worst_r, dr)
    assert worst_p < 1e-6, worst_p
    assert worst_r < 1e-6, worst_r


def test_panda_limits_equal_table_4_7() -> None:
    model = load_robot("panda")
    for i in range(7):
        jnt = model.joint(f"joint_{i + 1}")
        assert model.jnt_limited[jnt.id]
        np.testing.assert_allclose(model.jnt_range[jnt.id], (PANDA_QMIN[i], PANDA_QMAX[i]))
        act = model.actuator(f"joint_{i + 1}")
        np.testing.assert_allclose(
            model.actuator_ctrlrange[act.id], (-PANDA_QDMAX[i], PANDA_QDMAX[i])
        )
    np.testing.assert_allclose(model.numeric("accel_limits").data, PANDA_QDDMAX)


def test_jaco_joints_are_continuous_with_kinova_velocity_limits() -> None:
    model = load_robot("movo")
    for side in ("right_", "left_"):
        for i in range(1, 8):
            assert not model.jnt_limited[model.joint(f"{side}joint_{i}").id]
            lim = math.radians(36.0 if i <= 4 else 48.0)  # Kinova K75+ / K58 actuators
            rng = model.actuator_ctrlrange[model.actuator(f"{side}joint_{i}").id]
            np.testing.assert_allclose(rng, (-lim, lim))


@pytest.mark.parametrize("side", ["right", "left"])
def test_movo_gripper_mass_and_com_equal_table_3_2(side: str) -> None:
    model = load_robot("movo")
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    body = model.body(f"{side}_gripper").id
    assert model.body_subtreemass[body] == pytest.approx(1.435, abs=1e-9)
    # subtree centre of mass expressed in the gripper (sensor flange) frame, mm
    com = data.xmat[body].reshape(3, 3).T @ (data.subtree_com[body] - data.xpos[body])
    np.testing.assert_allclose(com * 1e3, (-1.1, 0.8, 78.6), atol=1e-6)
    # the F/T site sits between wrist and gripper: on the gripper body, at its flange
    site = model.site(f"{side}_ft")
    assert model.site_bodyid[site.id] == body
    assert model.body_parentid[body] == model.body(f"{side}_link_7").id
    names = {model.sensor(i).name for i in range(model.nsensor)}
    assert {f"{side}_ft_force", f"{side}_ft_torque"} <= names


@pytest.mark.parametrize("robot", ROBOTS)
def test_home_pose_holds_still_without_self_contact(robot: str) -> None:
    model = load_robot(robot)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    x0 = data.xpos.copy()
    q0 = data.qpos.copy()
    contacts = 0
    for _ in range(int(2.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
        contacts = max(contacts, data.ncon)
    assert contacts == 0
    assert np.max(np.abs(data.qpos - q0)) < 1e-3  # rad or m
    assert np.max(np.linalg.norm(data.xpos - x0, axis=1)) < 1e-3  # every body within 1 mm


def test_planner_primitives_are_unsimulated_capsules() -> None:
    for robot, names in (
        ("movo", [f"{s}_col_{i}" for s in ("right", "left") for i in (1, 2, 3)]),
        ("panda", [f"col_{i}" for i in range(1, 6)]),
    ):
        model = load_robot(robot)
        for n in names:
            g = model.geom(n)
            assert model.geom_type[g.id] in (
                int(mujoco.mjtGeom.mjGEOM_CAPSULE),
                int(mujoco.mjtGeom.mjGEOM_CYLINDER),
            )
            assert (
                model.geom_group[g.id],
                model.geom_contype[g.id],
                model.geom_conaffinity[g.id],
            ) == (3, 0, 0)
    movo = load_robot("movo")
    for i in (1, 2, 3):
        assert movo.geom_type[movo.geom(f"body_col_{i}").id] == int(mujoco.mjtGeom.mjGEOM_BOX)


def test_unknown_robot_lists_known_ones() -> None:
    with pytest.raises(ValueError, match=r"movo.*panda") as info:
        load_robot("ur5")
    assert isinstance(info.value, UnknownNameError)
    assert "ur5" in str(info.value)


@pytest.mark.parametrize(("robot", "prefix"), [("movo", "right_"), ("panda", "")])
def test_velocity_commands_are_tracked_and_clipped(robot: str, prefix: str) -> None:
    model = load_robot(robot)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    joints = [model.joint(f"{prefix}joint_{i}").id for i in range(1, 8)]
    adr = model.jnt_qposadr[joints]
    q0 = data.qpos[adr].copy()
    act = model.actuator(f"{prefix}joint_2").id
    data.ctrl[model.actuator(f"{prefix}joint_1").id] = 0.2  # rad/s, within the limits
    data.ctrl[act] = -100.0  # far beyond the limit: clipped to the velocity limit
    for _ in range(int(0.4 / model.opt.timestep)):  # Panda joint 2 stays inside its range
        mujoco.mj_step(model, data)
    vel = data.qvel[model.jnt_dofadr[joints]]
    assert vel[0] == pytest.approx(0.2, rel=0.02)  # steady state: the joint moves as commanded
    assert vel[1] == pytest.approx(model.actuator_ctrlrange[act, 0], rel=0.02)
    dq = data.qpos[adr] - q0
    assert dq[0] == pytest.approx(0.2 * 0.4, abs=0.03)  # lags the integrated target < 0.15 s
    assert np.abs(dq[2:]).max() < 0.01
