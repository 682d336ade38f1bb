"""Scene composition: pour scenes for every container and robot option."""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import pytest

from pourbench.containers import container_names, get_container
from pourbench.errors import UnknownNameError
from pourbench.scene import body_clearance, build_pour_scene

G = 9.81
NAMES = container_names()
POURING = [n for n in NAMES if get_container(n).role != "receiving"]
GRASP = {"movo": "right_ee", "panda": "tcp"}


def _site_pose(model: mujoco.MjModel, data: mujoco.MjData, name: str) -> np.ndarray:
    h = np.eye(4)
    h[:3, :3] = data.site_xmat[model.site(name).id].reshape(3, 3)
    h[:3, 3] = data.site_xpos[model.site(name).id]
    return h


def _check_scene(pouring: str, receiving: str, robot: str | None) -> None:
    scene = build_pour_scene(pouring, receiving, robot)
    model, data = scene.model, scene.make_data()
    recv = get_container(receiving)
    # containers sit where they should
    if robot is None:
        assert scene.pouring_mocap and model.body_mocapid[model.body("pouring").id] >= 0
        low = data.xpos[model.body("pouring").id][2]
        top = data.site_xpos[model.site("receiving_rim").id][2]
        assert low > top  # the pouring container starts above the receiving rim
    else:
        np.testing.assert_allclose(
            _site_pose(model, data, "pouring_mount"),
            _site_pose(model, data, GRASP[robot]),
            atol=1e-9,
        )
    if robot == "movo":
        np.testing.assert_allclose(
            _site_pose(model, data, "receiving_mount"),
            _site_pose(model, data, "left_ee"),
            atol=1e-9,
        )
    # the scale weighs what hangs on it: the receiving container (plus the gripper on the Movo)
    weight = recv.mass + (1.435 if robot == "movo" else 0.0)
    assert np.linalg.norm(data.sensor(scene.scale_force).data) == pytest.approx(
        weight * G, rel=1e-6
    )
    # 2 s at home: nothing moves, nothing touches
    q0, x0 = data.qpos.copy(), data.xpos.copy()
    contacts = 0
    for _ in range(int(2.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
        contacts = max(contacts, data.ncon)
    assert contacts == 0
    if model.nq:
        assert np.abs(data.qpos - q0).max() < 1e-3
    assert np.linalg.norm(data.xpos - x0, axis=1).max() < 1e-3


@pytest.mark.parametrize("robot", [None, "movo", "panda"])
@pytest.mark.parametrize("pouring", POURING)
def test_pour_scene_every_pouring_container(pouring: str, robot: str | None) -> None:
    _check_scene(pouring, "tray", robot)


@pytest.mark.slow
@pytest.mark.parametrize("robot", [None, "movo", "panda"])
def test_pour_scene_every_container_pair(robot: str | None) -> None:
    for pouring, receiving in itertools.product(POURING, NAMES):
        _check_scene(pouring, receiving, robot)


def test_pouring_container_clearance_to_receiving() -> None:
    scene = build_pour_scene("cup_small", "tray")
    model, data = scene.model, scene.make_data()
    assert body_clearance(model, data, cutoff=0.05) > 0.04  # starts well clear
    tray, cup = get_container("tray"), get_container("cup_small")
    rim = data.site_xpos[model.site("receiving_rim").id]
    # the cup's side wall right above the tray's wall (mid-surfaces aligned)
    dx = tray.shape.points[-1, 0] - cup.shape.points[-1, 0]
    mocap = model.body("pouring").mocapid[0]
    data.mocap_pos[mocap] = rim + np.array([dx, 0.0, 0.02])
    mujoco.mj_forward(model, data)
    expected = 0.02 - tray.wall / 2  # the cup's outer bottom to the tray's rounded rim
    assert body_clearance(model, data, cutoff=0.05) == pytest.approx(expected, abs=5e-4)
    data.mocap_pos[mocap] = rim + np.array([dx, 0.0, -0.01])
    mujoco.mj_forward(model, data)
    assert body_clearance(model, data) < -1e-3  # walls interpenetrate
    assert data.ncon == 0  # MuJoCo itself makes no contacts between two kinematic bodies
    with pytest.raises(UnknownNameError, match=r"'pourng'.*pouring.*receiving"):
        body_clearance(model, data, "pourng")  # a misspelt body: the known ones listed


def test_movo_weighs_liquid_with_the_left_wrist_sensor() -> None:
    scene = build_pour_scene("training", "tray", "movo")
    model, data = scene.model, scene.make_data()
    data.xfrc_applied[model.body("receiving").id, 2] = -0.1 * G  # 100 g of liquid in the tray
    for _ in range(500):  # 1 s to settle on the servos
        mujoco.mj_step(model, data)
    site = model.site("left_ft").id
    world = data.site_xmat[site].reshape(3, 3) @ data.sensor("left_ft_force").data
    # static equilibrium: the sensor carries gripper + tray + liquid; the force on the child
    # points from the child (gripper side) towards the parent (wrist), i.e. up
    np.testing.assert_allclose(world, (0.0, 0.0, (1.435 + 0.2 + 0.1) * G), atol=1e-3)


def test_bad_names_list_the_known_ones() -> None:
    with pytest.raises(UnknownNameError, match=r"movo.*panda"):
        build_pour_scene("training", "tray", "pr2")
    with pytest.raises(ValueError, match="bottle_wine") as info:
        build_pour_scene("kettle", "tray")
    assert "kettle" in str(info.value)
    with pytest.raises(ValueError, match="tray"):
        build_pour_scene("training", "bucket", "panda")
    with pytest.raises(ValueError, match=r"'tray' is a receiving container.*bottle_wine"):
        build_pour_scene("tray", "tray")  # the tray receives only


def test_view_records_every_visible_geom(tmp_path, capsys) -> None:
    from pourbench.cli import main
    from pourbench.view import world_meshes

    scene = build_pour_scene("cup_small", "tray", "panda")
    data = scene.make_data()
    seen = 0
    for _, verts, tris, _ in world_meshes(scene.model, data):
        seen += 1
        assert tris.max() < len(verts)
    visible = np.isin(scene.model.geom_group, (0, 1, 2)).sum()
    assert seen == visible
    for g in range(scene.model.ngeom):  # tessellations stay inside each geom's bounding sphere
        if scene.model.geom_group[g] in (1, 2):
            mesh = next(
                m
                for m in world_meshes(scene.model, data)
                if m[0].endswith(f"/{scene.model.geom(g).name}")
            )
            r = np.linalg.norm(mesh[1] - data.geom_xpos[g], axis=1)
            assert r.max() <= scene.model.geom_rbound[g] + 1e-9
    out = tmp_path / "s.rrd"
    assert (
        main(["view", "scene", "--robot", "panda", "--pouring", "cup_small", "--out", str(out)])
        == 0
    )
    assert out.stat().st_size > 10_000
    assert main(["view", "scene", "--robot", "none", "--pouring", "kettle", "--out", str(out)]) == 2
    assert "known containers" in capsys.readouterr().err


@pytest.fixture(scope="module")
def mocap_scene():
    scene = build_pour_scene("cup_small", "tray")
    return scene.model, scene.make_data()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"body1": None}, r"unknown body None; known bodys: pouring, receiving"),
        ({"body1": 5}, r"unknown body 5"),
        ({"body2": "pourng"}, r"unknown body 'pourng'"),
        ({"body1": "pouring", "body2": "pouring"}, r"same body 'pouring'"),
        ({"cutoff": float("nan")}, r"cutoff must be finite"),
        ({"cutoff": -1.0}, r"cutoff must be > 0"),
        ({"cutoff": 0.0}, r"cutoff must be > 0"),
        ({"cutoff": float("inf")}, r"cutoff must be finite"),
        ({"cutoff": "x"}, r"cutoff must be a number"),
    ],
)
def test_body_clearance_refuses_bad_input(mocap_scene, kwargs: dict, match: str) -> None:
    model, data = mocap_scene
    with pytest.raises(ValueError, match=match):
        body_clearance(model, data, **kwargs)  # None once crashed the process
    other = mujoco.MjData(mujoco.MjModel.from_xml_string("<mujoco/>"))
    with pytest.raises(ValueError, match="data does not belong to model"):
        body_clearance(model, other)
    assert body_clearance(model, data, cutoff=0.05) > 0.04


def test_view_refuses_bad_indices_and_foreign_data(mocap_scene, tmp_path) -> None:
    from pourbench.view import geom_mesh, record, world_meshes

    model, data = mocap_scene
    for g in (-1, model.ngeom, 1.5):
        with pytest.raises(ValueError, match="geom index g"):
            geom_mesh(model, g)
    assert geom_mesh(model, model.ngeom - 1) is not None
    with pytest.raises(ValueError, match="groups must be"):
        list(world_meshes(model, data, 5))
    old = tmp_path / "old.rrd"
    old.write_text("OLD")
    other = mujoco.MjData(mujoco.MjModel.from_xml_string("<mujoco><worldbody/></mujoco>"))
    with pytest.raises(ValueError, match="data does not belong to model"):
        record(model, other, old)
    bad = mujoco.MjData(model)
    bad.mocap_pos[:] = np.nan
    mujoco.mj_kinematics(model, bad)
    with pytest.raises(ValueError, match="non-finite geom poses"):
        record(model, bad, old)
    assert old.read_text() == "OLD" and list(tmp_path.iterdir()) == [old]


def test_realistic_inputs_the_checks_still_take() -> None:
    """What users pass and the bad-input checks must not refuse: a non-unit quaternion
    (MuJoCo normalises it), view groups as a set."""
    from pourbench.containers import add_container_body
    from pourbench.view import world_meshes

    spec = mujoco.MjSpec()
    add_container_body(spec, spec.worldbody, "training", name="c", quat=(0.0, 0.0, 0.0, 3.0))
    m = spec.compile()
    np.testing.assert_allclose(m.body("c").quat, [0.0, 0.0, 0.0, 1.0])
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    meshes = list(world_meshes(m, data))
    assert meshes and len(list(world_meshes(m, data, {0, 1, 2}))) == len(meshes)


def test_drawing_a_scene_loads_no_warp() -> None:
    """The import layering (DESIGN.md): scenes and containers stand on pure geometry, so a
    fresh interpreter that builds a scene has loaded neither Warp nor the liquid solver."""
    import subprocess
    import sys

    code = (
        "import sys, pourbench.scene, pourbench.containers, pourbench.geometry.shapes; "
        "print(sorted(m for m in ('warp', 'pourbench.fluids') if m in sys.modules))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "[]"
    code = "import sys, pourbench.fluids.params; print('warp' in sys.modules)"  # the profiles
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "False"
