"""Solver API: collider SDFs against their references, MuJoCo geoms as colliders, and bad
input (each raises a ValueError naming the value)."""

from __future__ import annotations

import dataclasses
import math
import warnings

import mujoco
import numpy as np
import pytest

from pourbench.errors import CapacityError, InvalidParameterError, UnknownNameError
from pourbench.fluids import liquid_metrics, liquid_profile
from pourbench.fluids.config import SolverConfig
from pourbench.fluids.coupling import MujocoCoupling
from pourbench.fluids.meshes import check_closed_mesh, convex_hull
from pourbench.fluids.solver import PBFSolver, cuda_available
from pourbench.geometry.rotation import inverse_transform_points
from pourbench.geometry.shapes import BoxShell, RevolvedShell, bottle, bowl, cup

DT = SolverConfig().dt


@pytest.mark.parametrize(
    "shape",
    [
        cup(0.04, 0.08),
        bowl(0.07, 0.05),
        bottle(0.04, 0.1, 0.012, 0.04),
        BoxShell(0.05, 0.03, 0.04, 0.004),
        BoxShell(0.05, 0.03, 0.04, 0.004, closed=True),
    ],
    ids=["cup", "bowl", "bottle", "tray", "closed_box"],
)
def test_kernel_sdf_matches_shape_sdf(shape) -> None:
    s = PBFSolver(1)
    c = s.add_container(0, shape)
    pts = np.random.default_rng(0).uniform(-0.09, 0.16, (4000, 3))
    got = s.collider_sdf(c, pts)
    np.testing.assert_allclose(got[:, 0], shape.sdf(pts), atol=2e-6)
    # normals point toward increasing distance (finite difference of the reference SDF)
    far = np.abs(got[:, 0]) > 2e-3
    eps = 1e-5
    fd = np.stack(
        [(shape.sdf(pts + eps * e) - shape.sdf(pts - eps * e)) / (2 * eps) for e in np.eye(3)], 1
    )
    cos = np.sum(fd[far] * got[far, 1:], axis=1) / np.linalg.norm(fd[far], axis=1)
    assert np.quantile(cos, 0.01) > 0.99


GEOMS = {
    "box": '<geom name="g" type="box" size="0.03 0.03 0.02" pos="0 0 0.02" euler="0 0 30"/>',
    "sphere": '<geom name="g" type="sphere" size="0.03" pos="0 0 0.03"/>',
    "capsule": '<geom name="g" type="capsule" size="0.02 0.03" pos="0 0 0.02" euler="0 90 0"/>',
    "cylinder": '<geom name="g" type="cylinder" size="0.03 0.02" pos="0 0 0.02"/>',
    "mesh": '<geom name="g" type="mesh" mesh="m" pos="0 0 0.02"/>',
}
MESH_ASSET = (
    '<asset><mesh name="m" vertex="-.03 -.03 -.02  .03 -.03 -.02  .03 .03 -.02  -.03 .03 -.02'
    '  -.03 -.03 .02  .03 -.03 .02  .03 .03 .02  -.03 .03 .02"/></asset>'
)


def _block_over_geoms(
    asset: str, geom: str
) -> tuple[mujoco.MjModel, mujoco.MjData, PBFSolver, MujocoCoupling]:
    """A floor and ``geom`` in MuJoCo, coupled to a 6 × 6 × 4 block of water above them."""
    xml = f"""<mujoco><option timestep="{DT!r}"/>{asset}
      <worldbody><geom name="floor" type="plane" size="1 1 0.1"/>{geom}</worldbody>
      </mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    solver = PBFSolver(1)
    coupling = MujocoCoupling(solver, model, [data])
    coupling.add_geoms()
    d = solver.config.spacing
    g = (np.arange(6) - 2.5) * d
    X, Y, Z = np.meshgrid(g, g, 0.07 + np.arange(4) * d, indexing="ij")
    solver.add_particles(0, np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1))
    return model, data, solver, coupling


def test_colliders_take_the_geoms_poses_mujoco_computes() -> None:
    """Every collider bound to a geom has the pose MuJoCo gives that geom (position and
    rotation), in each world, for bodies turned differently per world and geoms offset and
    rotated within them, and again after the bodies moved."""
    xml = f"""<mujoco><option timestep="{DT}"/><worldbody>
      <geom name="floor" type="plane" size="1 1 0.1"/>
      <body name="arm" pos="0.1 -0.2 0.3" quat="0.9 0.1 0.3 -0.2">
        <joint type="ball"/>
        <geom type="box" size="0.02 0.03 0.04" pos="0.05 0.01 -0.02" quat="0.5 0.5 -0.5 0.1"/>
        <geom type="capsule" size="0.01 0.03" pos="-0.02 0.04 0.0" euler="0.3 -0.7 1.1"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    datas = [mujoco.MjData(model) for _ in range(2)]
    rng = np.random.default_rng(5)
    coupling = MujocoCoupling(PBFSolver(2), model, datas)
    coupling.add_geoms()
    for _ in range(2):
        for d in datas:
            q = rng.normal(size=4)
            d.qpos[:4] = q / np.linalg.norm(q)
            mujoco.mj_kinematics(model, d)
        coupling.sync()
        for k, b in enumerate(coupling.bindings):  # geom by geom, each in world 0 then 1
            gid, d = k // 2, datas[b.world]
            pose = coupling.solver.colliders[b.collider].pose
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, pose[3:])
            np.testing.assert_allclose(pose[:3], d.geom_xpos[gid], atol=1e-12)
            np.testing.assert_allclose(rot, d.geom_xmat[gid], atol=1e-12)


@pytest.mark.parametrize("kind", sorted(GEOMS))
def test_mujoco_geoms_hold_liquid_up(kind: str) -> None:
    """A block of water dropped on a MuJoCo geom ends up outside it, resting on it."""
    model, data, solver, coupling = _block_over_geoms(
        MESH_ASSET if kind == "mesh" else "", GEOMS[kind]
    )
    coupling.step(round(0.4 / DT))
    x = solver.positions()
    gid = model.geom("g").id
    local = (x - data.geom_xpos[gid]) @ data.geom_xmat[gid].reshape(3, 3)
    geom_collider = [b.collider for b in coupling.bindings if b.body == 0][-1]
    dist = solver.collider_sdf(geom_collider, local)[:, 0]
    assert dist.min() > 0.5 * solver.config.radius  # nothing inside the geom
    assert x[:, 2].min() > 0.0  # nor through the floor
    # an independent inside test in the XML's frame (MuJoCo re-orients meshes internally)
    unrotated = x - data.geom_xpos[gid]
    inside = {
        "box": np.all(np.abs(local) < [0.03, 0.03, 0.02], axis=1),
        "mesh": np.all(np.abs(unrotated) < [0.03, 0.03, 0.02], axis=1),
        "sphere": np.linalg.norm(local, axis=1) < 0.03,
        "cylinder": (np.hypot(local[:, 0], local[:, 1]) < 0.03) & (np.abs(local[:, 2]) < 0.02),
        "capsule": np.hypot(local[:, 0], local[:, 1]) ** 2
        + np.maximum(np.abs(local[:, 2]) - 0.03, 0) ** 2
        < 0.02**2,
    }[kind]
    assert not inside.any()


# an open-top tray, 6 × 6 × 3 cm: floor and four walls, no lid (its faces have no inside)
TRAY_VERTS = np.array(
    [[x, y, z] for z in (0.0, 0.03) for x, y in ((-1, -1), (1, -1), (1, 1), (-1, 1))], float
) * [0.03, 0.03, 1.0]
TRAY_FACES = np.array(
    [[0, 2, 1], [0, 3, 2], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
     [3, 0, 4], [3, 4, 7]]
)  # fmt: skip


def test_open_mesh_geom_collides_as_its_convex_hull() -> None:
    """MuJoCo collides a mesh geom as its convex hull, and the fluid does too: water dropped
    on an open tray mesh lands on the hull's top and runs off its sides to the floor, never
    inside it and never faster than its fall (the open faces' own signed distance has no
    inside: particles near the rim were thrown metres away at 11 m/s)."""
    verts = " ".join(f"{v:g}" for v in TRAY_VERTS.ravel())
    faces = " ".join(str(i) for i in TRAY_FACES.ravel())
    model, _, solver, coupling = _block_over_geoms(
        f'<asset><mesh name="m" vertex="{verts}" face="{faces}"/></asset>',
        '<geom name="g" type="mesh" mesh="m" pos="0 0 0.01"/>',
    )
    assert model.mesh_facenum[0] == len(TRAY_FACES)  # MuJoCo keeps the open faces
    fall = math.sqrt(2 * 9.81 * 0.09)  # from the block's top to the floor
    for _ in range(round(0.4 / DT)):
        coupling.step(1)
        x = solver.positions()
        assert np.linalg.norm(solver.velocities(), axis=1).max() < 1.2 * fall
        in_hull = np.all(np.abs(x[:, :2]) < 0.03 - 1e-3, axis=1) & (x[:, 2] < 0.04 - 1e-3)
        assert not (in_hull & (x[:, 2] > 0.01 + 1e-3)).any()
    assert np.abs(x[:, :2]).max() < 0.3  # spread over the floor, nothing thrown away


def test_mesh_collider_must_be_closed_and_wound_outward() -> None:
    s = PBFSolver(1)
    with pytest.raises(InvalidParameterError, match="not closed"):
        s.add_collider(0, "mesh", [], mesh=(TRAY_VERTS, TRAY_FACES))
    hull_v, hull_t = convex_hull(TRAY_VERTS)
    check_closed_mesh(hull_v, hull_t)  # the hull is a closed, outward box
    with pytest.raises(InvalidParameterError, match="wound inward"):
        s.add_collider(0, "mesh", [], mesh=(hull_v, hull_t[:, ::-1]))
    with pytest.raises(InvalidParameterError, match="index vertices"):
        s.add_collider(0, "mesh", [], mesh=(hull_v, hull_t + 100))
    with pytest.raises(InvalidParameterError, match="no convex hull"):
        convex_hull(TRAY_VERTS * [1.0, 1.0, 0.0])  # flat
    s.add_collider(0, "mesh", [], mesh=(hull_v, hull_t))
    x = np.array([[0.0, 0.0, 0.015], [0.0, 0.0, 0.05], [0.029, 0.029, 0.029]])
    sdf = s.collider_sdf(0, x)[:, 0]
    assert sdf[0] == pytest.approx(-0.015, abs=1e-6) and sdf[1] == pytest.approx(0.02, abs=1e-6)
    assert sdf[2] == pytest.approx(-0.001, abs=1e-6)  # inside, next to an edge and a corner
    # the sign is the winding number's: the nearest face's normal misjudged 2 of these points
    q = np.random.default_rng(0).uniform([-0.05, -0.05, -0.02], [0.05, 0.05, 0.05], (200_000, 3))
    inside = np.all(np.abs(q[:, :2]) < 0.03, axis=1) & (q[:, 2] > 0.0) & (q[:, 2] < 0.03)
    assert np.array_equal(s.collider_sdf(0, q)[:, 0] < 0.0, inside)


def test_fill_rejects_more_than_the_container_holds() -> None:
    s = PBFSolver(1)
    c = s.add_container(0, cup(0.02, 0.03))  # about 37 ml
    with pytest.raises(CapacityError, match="mass_g=500"):
        s.fill(0, c, 500.0, "water")
    assert s.num_particles == 0  # nothing half-added


@pytest.mark.parametrize(
    "shape",
    [cup(0.04, 0.08), cup(0.025, 0.06), cup(0.0612, 0.05), BoxShell(0.0512, 0.03, 0.04, 0.004)],
    ids=["cup-4cm", "cup-2.5cm", "cup-6.1cm", "box"],
)
def test_fill_covers_the_cavity_at_the_liquids_number_density(shape) -> None:
    """Each filled layer holds the cavity's volume in particles (one per spacing³), so a fill's
    level is the level its volume reaches: 1 % at most missing below any full layer's top."""
    spacing = 0.005
    s = PBFSolver(1, SolverConfig(spacing=spacing))
    c = s.add_container(0, shape)
    n = s.fill(0, c, 0.9 * shape.interior_volume * 1e6, "water")  # 1 g/ml
    z = s.positions()[:, 2]
    layers = np.unique(np.round(z, 9))
    assert np.allclose(np.diff(layers), spacing)
    assert np.all(shape.sdf(s.positions()) >= 0.5 * spacing - 1e-6)  # clear of the wall
    for top in layers[:-1]:  # the last layer may be partial
        held = np.count_nonzero(z <= top + 1e-9) * spacing**3
        assert held == pytest.approx(shape.volume_below(top + 0.5 * spacing), rel=0.01)
    assert n == round(0.9 * shape.interior_volume / spacing**3)


@pytest.mark.parametrize("bad", [float("nan"), -5.0, "lots"])
def test_fill_rejects_bad_mass(bad) -> None:
    s = PBFSolver(1)
    c = s.add_container(0, cup(0.04, 0.08))
    with pytest.raises(InvalidParameterError, match="mass_g"):
        s.fill(0, c, bad, "water")


def test_unknown_liquid_and_bad_profile_values() -> None:
    s = PBFSolver(1)
    with pytest.raises(UnknownNameError, match=r"known liquids: .*Water"):
        s.set_liquid(0, "lava")
    from pourbench.fluids import liquid_profile

    with pytest.raises(InvalidParameterError, match="adhesion"):
        s.set_liquid(0, liquid_profile("water").replace(adhesion=-1.0))


@pytest.mark.parametrize(
    "kwargs,name",
    [
        ({"spacing": float("nan")}, "spacing"),
        ({"dt": -1.0}, "dt"),
        ({"iterations": 0}, "iterations"),
        ({"sleep_threshold": -0.01}, "sleep_threshold"),
        ({"sleep_threshold": float("nan")}, "sleep_threshold"),
        ({"iterations": 2.5}, "iterations"),
        ({"max_neighbours": 3.5}, "max_neighbours"),
        ({"reorder_every": -1}, "reorder_every"),
        ({"sor": float("nan")}, "sor"),
        ({"sor": 0.0}, "sor"),
        ({"gravity": (0.0, 0.0, float("nan"))}, "gravity z"),
        ({"gravity": (0.0, -9.81)}, "gravity"),
        ({"graph": "yes"}, "graph"),
        ({"device": "tpu"}, "device"),
    ],
)
def test_config_rejects_bad_values(kwargs, name) -> None:
    with pytest.raises(InvalidParameterError, match=name):
        SolverConfig(**kwargs)


def test_a_missing_cuda_device_is_named() -> None:
    import warp as wp

    count = wp.get_cuda_device_count() if cuda_available() else 0
    with pytest.raises(InvalidParameterError, match=f"'cuda:{count}': Warp sees {count} CUDA"):
        PBFSolver(1, SolverConfig(device=f"cuda:{count}"))


_NO_ROTATION = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]


def _two_worlds() -> tuple[PBFSolver, int]:
    """Two worlds, a cup in world 0 (the collider returned)."""
    s = PBFSolver(2)
    return s, s.add_container(0, cup(0.02, 0.04))


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda s, c: s.add_collider(0, "sphere", [-0.05]), "'sphere' sizes must be > 0"),
        (lambda s, c: s.add_collider(0, "sphere", [0.1, 0.2]), "'sphere' collider takes 1"),
        (lambda s, c: s.add_collider(0, "capsule", [0.1]), "'capsule' collider takes 2"),
        (lambda s, c: s.add_collider(0, "revolved", [0.004, 0, 0]), "add_container"),
        (lambda s, c: s.add_collider(0, "sphere", [0.01], body=3), "body slot 3 not in"),
        (lambda s, c: s.add_collider(0, "sphere", [0.01], body=-5), "body slot -5"),
        (lambda s, c: s.add_collider(0, "sphere", [0.01], pose=[0, 0, 0]), r"pose .*\(7,\)"),
        (lambda s, c: s.add_collider(0, "sphere", [0.01], pose=[0] * 7), "norm 0, not 1"),
        (lambda s, c: s.add_collider(1.5, "sphere", [0.01]), "world must be an integer"),
        (lambda s, c: s.add_particles(0, np.zeros((2, 6))), r"positions .*\(n, 3\)"),
        (lambda s, c: s.add_particles(0, np.zeros((3, 3)), np.zeros((1, 3))), "velocities"),
        (lambda s, c: s.fill(1, c, 10.0), "collider 0 is in world 0, not in world 1"),
        (lambda s, c: s.fill(0, -1, 10.0), "collider -1 not in"),
        (lambda s, c: s.fill(0, 4, 10.0), "collider 4 not in"),
        (lambda s, c: s.set_collider_poses([-1], [_NO_ROTATION]), "collider -1 not in"),
        (lambda s, c: s.set_collider_poses([c], [_NO_ROTATION[:6]]), r"\(1, 7\)"),
        (lambda s, c: s.set_collider_poses([c], [[0, 0, 0, 3.0, 0, 0, 0]]), "norm 3"),
        (lambda s, c: s.set_collider_poses([c], [_NO_ROTATION], com=[[math.nan] * 3]), "com"),
        (lambda s, c: s.set_container_shape(3, cup(0.02, 0.04)), "collider 3 not in"),
        (lambda s, c: s.collider_sdf(7, [[0.0, 0.0, 0.0]]), "collider 7 not in"),
        (lambda s, c: s.step(-3), "steps must be >= 0"),
        (lambda s, c: s.step(2.9), "steps must be an integer"),
        (lambda s, c: s.world_slice(7), "world 7 not in"),
        (lambda s, c: s.particle_mass(-1), "world -1 not in"),
        (lambda s, c: liquid_metrics(s, 1, [c]), "not a container of world 1"),
        (lambda s, c: liquid_metrics(s, 0, [9]), "collider 9 not in"),
    ],
)
def test_bad_calls_name_the_value_and_change_nothing(call, match) -> None:
    """Each bad call raises a pourbench error naming what is wrong, and the scene it was made
    on still fills and steps as before (nothing half-added)."""
    s, c = _two_worlds()
    before = len(s.colliders), s.num_body_slots, s.num_particles
    with pytest.raises(InvalidParameterError, match=match):
        call(s, c)
    assert (len(s.colliders), s.num_body_slots, s.num_particles) == before
    s.fill(0, c, 10.0)
    s.step(2)
    assert np.isfinite(s.positions()).all()


def test_a_failed_coupling_call_leaves_the_coupling_working() -> None:
    """Bad worlds, offsets or geoms are refused before any slot or binding is made, so the
    coupling steps on afterwards with its earlier bindings."""
    xml = f"""<mujoco><option timestep="{DT!r}"/><worldbody>
      <geom name="floor" type="plane" size="1 1 0.1"/>
      <body name="cupbody" pos="0 0 0.1"><freejoint/><geom type="box" size=".01 .01 .01"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    coupling = MujocoCoupling(PBFSolver(1), model, [mujoco.MjData(model)])
    coupling.add_container("cupbody", cup(0.02, 0.04))
    state = len(coupling.bindings), dict(coupling.slots), len(coupling.solver.colliders)
    bad = [
        (lambda: coupling.add_container("cupbody", cup(0.02, 0.04), world=5), "world 5"),
        (lambda: coupling.add_container("cupbody", cup(0.02, 0.04), world=-1), "world -1"),
        (lambda: coupling.add_container("cupbody", cup(0.02, 0.04), local_pos=(0, 0, math.nan)),
         "local_pos"),
        (lambda: coupling.add_container("cupbody", cup(0.02, 0.04), local_quat=(0, 0, 0, 0)),
         "local_quat"),
        (lambda: coupling.add_container(99, cup(0.02, 0.04)), "body 99 not in"),
        (lambda: coupling.add_container("cupbody", "cup"), "unsupported container shape"),
        (lambda: coupling.add_geoms(["floor", "nope"]), "unknown geom 'nope'"),
        (lambda: coupling.add_geoms("floor"), "list of geom names"),
        (lambda: coupling.add_geoms([0], world=7), "world 7"),
        (lambda: coupling.step(-2), "steps must be >= 0"),
    ]  # fmt: skip
    for call, match in bad:
        with pytest.raises(InvalidParameterError, match=match):
            call()
        assert (len(coupling.bindings), dict(coupling.slots), len(coupling.solver.colliders)) == (
            state
        )
    coupling.solver.fill(0, coupling.bindings[0].collider, 20.0)
    coupling.step(3)
    assert np.isfinite(coupling.solver.positions()).all()


def test_shapes_refuse_bad_sizes_and_keep_lists_hashable() -> None:
    with pytest.raises(InvalidParameterError, match="radius must be a number"):
        cup("a", 0.04)
    with pytest.raises(InvalidParameterError, match="segments must be an integer"):
        bowl(0.05, 0.02, segments=2.5)
    with pytest.raises(InvalidParameterError, match="closed must be True or False"):
        BoxShell(0.1, 0.1, 0.1, 0.004, closed="no")
    as_lists = RevolvedShell([[0.0, 0.002], [0.022, 0.002], [0.022, 0.044]], 0.004)
    assert as_lists == cup(0.02, 0.04) and hash(as_lists) == hash(cup(0.02, 0.04))
    s = PBFSolver(1)
    assert s.fill(0, s.add_container(0, as_lists), 20.0) > 0


def test_profile_values_and_names() -> None:
    water = liquid_profile("water")
    assert water.replace(density=np.float32(998.0)).density == pytest.approx(998.0)
    with pytest.raises(InvalidParameterError, match="unknown liquid parameter 'foo'"):
        water.replace(foo=1.0)
    with pytest.raises(InvalidParameterError, match="density must be a number"):
        water.replace(density=True)
    with pytest.raises(InvalidParameterError, match="name must be a string"):
        water.replace(name=None)


def test_collider_input_errors() -> None:
    s = PBFSolver(2)
    with pytest.raises(InvalidParameterError, match="kind"):
        s.add_collider(0, "torus", [0.1])
    with pytest.raises(InvalidParameterError, match="world"):
        s.add_collider(5, "plane", [0.0])
    c = s.add_collider(0, "plane", [0.0])
    with pytest.raises(InvalidParameterError, match="finite"):
        s.set_collider_poses([c], np.array([[math.nan, 0, 0, 1, 0, 0, 0]]))


def test_runaway_world_is_flagged_not_raised() -> None:
    s = PBFSolver(2)
    for w in range(2):
        s.add_collider(w, "plane", [0.0])
    s.add_particles(0, [[0.0, 0.0, 0.05]])
    s.add_particles(1, [[0.0, 0.0, 0.05]], velocities=[[0.0, 0.0, 500.0]])
    s.step(2)
    assert s.diverged().tolist() == [False, True]


def test_edits_mid_run_continue_from_the_current_state() -> None:
    """Changing a liquid or adding a collider mid-run must not rewind the particles."""

    def run(edit: bool) -> np.ndarray:
        s = PBFSolver(1)
        s.add_collider(0, "plane", [0.0])
        c = s.add_container(0, cup(0.03, 0.06))
        s.fill(0, c, 40.0, "water")
        s.step(30)
        if edit:
            before = s.positions()
            s.set_liquid(0, "water")  # same liquid: the run must be unchanged
            s.add_collider(0, "sphere", [0.01], pose=[1.0, 1.0, 1.0, 1, 0, 0, 0])  # far away
            np.testing.assert_array_equal(s.positions(), before)
        s.step(30)
        return s.positions()

    np.testing.assert_array_equal(run(True), run(False))


def test_half_neighbour_lists_hold_every_pair_once() -> None:
    """Each pair within h is listed exactly once (brute force by a k-d tree), and the total
    neighbour counts include both sides of every pair."""
    from scipy.spatial import cKDTree

    s = PBFSolver(2)
    for w in range(2):
        s.add_collider(w, "plane", [0.0])
        c = s.add_container(w, cup(0.04, 0.08))
        s.fill(w, c, 60.0 + 40.0 * w, "water")
    s.step(5)
    s.launches.build_neighbours()  # lists of the current positions (the step builds them on p)
    p = s.buf.p.numpy()
    listed = [(min(i, j), max(i, j)) for i, js in enumerate(s.neighbour_lists()) for j in js]
    assert len(listed) == len(set(listed))  # no pair twice
    world = s.worlds()
    h = s.config.h
    truth = {(i, j) for i, j in cKDTree(p).query_pairs(h) if world[i] == world[j]}
    # a filled lattice puts many pairs at exactly h, where float rounding decides (W = 0 there)
    differ = np.array(sorted(set(listed) ^ truth), dtype=int).reshape(-1, 2)
    gap = np.linalg.norm(p[differ[:, 0]] - p[differ[:, 1]], axis=1)
    assert np.all(np.abs(gap - h) < 1e-6 * h), gap
    assert len(truth) > 10_000
    total = np.bincount(np.array(listed).ravel(), minlength=len(p))
    np.testing.assert_array_equal(s.neighbour_counts(), total)


def test_full_neighbour_lists_hold_every_neighbour() -> None:
    """Full lists (interleaved, the CUDA layout) list every neighbour of every particle, once,
    in both directions (checked on the CPU, where the same kernels run)."""
    from scipy.spatial import cKDTree

    s = PBFSolver(2, SolverConfig(pair_lists="full"))
    for w in range(2):
        s.add_collider(w, "plane", [0.0])
        s.fill(w, s.add_container(w, cup(0.04, 0.08)), 50.0 + 30.0 * w, "water")
    s.step(5)
    s.launches.build_neighbours()
    p, lists = s.buf.p.numpy(), s.neighbour_lists()
    assert all(len(js) == len(set(js.tolist())) and i not in js for i, js in enumerate(lists))
    listed = {(i, int(j)) for i, js in enumerate(lists) for j in js}
    assert listed == {(j, i) for i, j in listed}  # symmetric
    world = s.worlds()
    truth = {(i, j) for i, j in cKDTree(p).query_pairs(s.config.h) if world[i] == world[j]}
    truth |= {(j, i) for i, j in truth}
    differ = np.array(sorted(listed ^ truth), dtype=int).reshape(-1, 2)
    gap = np.linalg.norm(p[differ[:, 0]] - p[differ[:, 1]], axis=1)
    assert np.all(np.abs(gap - s.config.h) < 1e-6 * s.config.h), gap  # float ties at r = h
    assert len(truth) > 10_000
    np.testing.assert_array_equal(s.neighbour_counts(), [len(js) for js in lists])


def test_morton_buckets_keep_locality_without_aliasing_wide_scenes() -> None:
    """The full lists' bucket of a cell: neighbouring cells get nearby buckets (what a GPU
    warp's shared candidates rely on), and a scene wider than the Morton code's period (a
    1 cm-cell slab 4 m x 1 m, as a spreading dam break of 1M particles) does not fold onto
    itself: the low Morton bits alone put three cells into every bucket here."""
    import warp as wp

    from pourbench.fluids import kernels as K

    @wp.kernel
    def buckets_of(cells: wp.array(dtype=wp.vec3i), mask: int, out: wp.array(dtype=int)):
        i = wp.tid()
        out[i] = K.morton_bucket(0, cells[i], mask)

    def buckets(cells: np.ndarray, mask: int) -> np.ndarray:
        out = wp.zeros(len(cells), dtype=int, device="cpu")
        cells = wp.array(cells, dtype=wp.vec3i, device="cpu")
        wp.launch(buckets_of, len(out), [cells, mask], [out], device="cpu")
        return out.numpy()

    mask = (1 << 21) - 1  # the table of 1M particles (2^21 buckets)
    g = np.stack(np.meshgrid(np.arange(-200, 200), np.arange(-50, 50), np.arange(4)), -1)
    slab = g.reshape(-1, 3).astype(np.int32)
    b = buckets(slab, mask)
    cells_per_bucket = len(slab) / len(np.unique(b))
    # cells dropped at random into 2^21 buckets share one 8 % of the time (160k cells)
    assert cells_per_bucket < 1.1, cells_per_bucket
    block = np.stack(np.meshgrid(*[np.arange(64)] * 3), -1).reshape(-1, 3).astype(np.int32)
    step = np.abs(buckets(block + np.int32([1, 0, 0]), mask) - buckets(block, mask))
    assert np.median(step) <= 8  # x-neighbours inside a block of space: Morton steps


def test_readbacks_are_snapshots() -> None:
    """Arrays returned by the solver do not change when it steps on."""
    s = PBFSolver(1)
    s.add_collider(0, "plane", [0.0])
    c = s.add_container(0, cup(0.04, 0.08))
    s.fill(0, c, 50.0, "water")
    s.step(2)
    x, v = s.positions(), s.velocities()
    x0, v0 = x.copy(), v.copy()
    s.step(5)
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(v, v0)
    assert not np.array_equal(s.positions(), x0)


def test_velocities_are_the_particles_motion() -> None:
    """``velocities()`` reads each particle's displacement over the last step / dt. In a
    cohesive liquid at rest that is not the velocity carried into the next step, which also
    holds the impulses cohesion and surface tension leave for it (balanced there by the
    density constraint). Before the first step it reads the velocities the particles got."""
    s = PBFSolver(1, SolverConfig(reorder_every=0))  # no re-sort: indices stay put
    s.add_collider(0, "plane", [0.0])
    sticky = dataclasses.replace(liquid_profile("water"), cohesion=0.05, surface_tension=0.05)
    s.set_liquid(0, sticky)
    cavity = s.add_container(0, cup(0.03, 0.06))
    s.fill(0, cavity, 40.0)
    given = np.random.default_rng(0).normal(0.0, 0.01, (3, 3)).astype(np.float32)
    s.add_particles(0, [[0.0, 0.0, 0.05], [0.01, 0.0, 0.05], [0.0, 0.01, 0.05]], given)
    np.testing.assert_array_equal(s.velocities()[-3:], given)
    s.step(round(1.5 / s.config.dt))
    x0 = s.positions()
    s.step(1)
    moved = (s.positions() - x0) / s.config.dt
    np.testing.assert_allclose(s.velocities(), moved, atol=1e-5)
    # settled: the median particle moves under 2 mm/s (0.8 measured), while the impulses
    # carried into the next step are 7.5 mm/s at the median
    assert np.median(np.linalg.norm(moved, axis=1)) < 2e-3
    carried = s.buf.v.numpy()
    assert np.median(np.linalg.norm(carried - moved, axis=1)) > 5e-3


def test_kernels_compile_for_cuda(tmp_path) -> None:
    """The solver's kernels build for a CUDA GPU (sm_80) with NVRTC, which ships with Warp
    and needs no GPU: the CUDA path compiles even on machines that cannot run it."""
    import warp as wp

    from pourbench.fluids import kernels

    wp.init()
    archs = getattr(wp._src.context.runtime, "nvrtc_supported_archs", None) or set()
    if 80 not in archs:
        pytest.skip("this Warp build has no NVRTC for sm_80")
    built = wp.compile_aot_module(kernels, arch=80, module_dir=tmp_path)
    assert built and all(p.exists() and p.stat().st_size > 0 for p in built)


def _swirl(spin: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """A ball of particles (radius 3 cm, 5 mm lattice) around (0.1, 0.1, 0.1) with a Gaussian
    vortex about z (angular speed ``spin`` on the axis)."""
    g = np.arange(-6, 7) * 0.005
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    x = x[np.linalg.norm(x, axis=1) < 0.03]
    rate = spin * np.exp(-((np.hypot(x[:, 0], x[:, 1]) / 0.01) ** 2))
    return x + 0.1, (rate[:, None] * np.cross([0.0, 0.0, 1.0], x)).astype(np.float32)


def _lz(s: PBFSolver, core: float = np.inf) -> float:
    """Angular momentum about the swirl's axis (per unit particle mass) of the particles
    within ``core`` (m) of it."""
    r = s.positions() - 0.1
    inside = np.hypot(r[:, 0], r[:, 1]) < core
    return float(np.cross(r[inside], s.velocities()[inside])[:, 2].sum())


_SWIRLY = dataclasses.replace(
    liquid_profile("water"), vorticity_confinement=1.0, surface_tension=0.5, cohesion=0.05
)


@pytest.mark.parametrize("liquid", ["water", "honey", "swirly"])
def test_full_and_half_pair_lists_agree(liquid: str) -> None:
    """The full-list kernels (the CUDA default: no atomics between threads) step the same
    liquid as the half-list kernels (the CPU default) up to float rounding; run here on the
    CPU, this checks the CUDA mode's code path on machines without a GPU. "swirly" (a spinning
    ball with vorticity confinement, surface tension and cohesion) exercises every term."""

    def run(mode: str) -> PBFSolver:
        s = PBFSolver(1, SolverConfig(pair_lists=mode))
        if liquid == "swirly":
            s.set_liquid(0, _SWIRLY)
            s.add_particles(0, *_swirl())
        else:
            s.add_collider(0, "plane", [0.0])
            s.fill(0, s.add_container(0, cup(0.04, 0.08)), 100.0, liquid)
        s.step(3)
        return s

    half, full = run("half"), run("full")
    assert half.half_lists and not full.half_lists
    if liquid == "swirly":
        # vorticity confinement's direction N = ∇|ω| / |∇|ω|| turns on rounding where the
        # gradient nearly vanishes, so a few particles differ by mm/s: compare the bulk
        np.testing.assert_allclose(full.positions(), half.positions(), atol=1e-5)
        dv = np.abs(full.velocities() - half.velocities())
        assert np.median(dv) < 1e-4 and np.quantile(dv, 0.9) < 1e-3  # a sign slip: ~1e-2
        np.testing.assert_allclose(full.densities(), half.densities(), atol=1e-3)
    else:
        np.testing.assert_allclose(full.positions(), half.positions(), atol=1e-6)
        np.testing.assert_allclose(full.velocities(), half.velocities(), atol=1e-4)
        np.testing.assert_allclose(full.densities(), half.densities(), atol=1e-5)
    # a pair within float rounding of h can be listed in one mode and not the other
    diff = np.abs(full.neighbour_counts() - half.neighbour_counts())
    assert diff.max() <= 1 and np.count_nonzero(diff) <= 0.01 * len(diff)
    with pytest.raises(InvalidParameterError, match="pair_lists"):
        SolverConfig(pair_lists="quarter")


@pytest.mark.parametrize("mode", ["half", "full"])
def test_vorticity_confinement_feeds_the_vortex(mode: str) -> None:
    """Weightless spinning ball: without confinement its angular momentum L_z is conserved
    (within 3 %) while the narrow vortex spreads, so the core (particles within 1 cm of the
    axis) keeps about a tenth of its L_z after 20 steps; vorticity confinement (force along
    N × ω, N = ∇|ω| / |∇|ω||) feeds rotation back into the core in the vortex's own sense
    (measured 0.74 of it against 0.12). The ball is a 5 mm cubic lattice, so its rest sum is
    the lattice's (``rest_packing=1``). The core is measured because the whole ball's L_z
    under confinement depends on its free surface, where the curl's one-sided estimate is
    poor (measured 0.88 of the start after 40 steps)."""
    lz, core = {}, {}
    for eps in (0.0, 0.2):
        liquid = dataclasses.replace(
            liquid_profile("water"),
            vorticity_confinement=eps,
            viscosity=0.0,
            viscosity_pa_s=None,
            surface_tension=0.0,
            cohesion=0.0,
        )
        cfg = SolverConfig(gravity=(0.0, 0.0, 0.0), pair_lists=mode, rest_packing=1.0)
        s = PBFSolver(1, cfg)
        s.set_liquid(0, liquid)
        s.add_particles(0, *_swirl())
        lz0, core0 = _lz(s), _lz(s, core=0.01)
        s.step(20)
        lz[eps], core[eps] = _lz(s) / lz0, _lz(s, core=0.01) / core0
    assert lz[0.0] == pytest.approx(1.0, abs=0.03)
    assert core[0.2] > 2.0 * core[0.0] and core[0.2] > 0.5, f"core L_z {core}"


def test_full_neighbour_list_warns() -> None:
    """A list that fills up drops pairs; the solver says so instead of staying silent."""
    s = PBFSolver(1, SolverConfig(max_neighbours=6))
    s.add_collider(0, "plane", [0.0])
    s.fill(0, s.add_container(0, cup(0.04, 0.08)), 50.0, "water")
    with pytest.warns(RuntimeWarning, match="max_neighbours=6"):
        s.step(2)
    roomy = PBFSolver(1)
    roomy.add_collider(0, "plane", [0.0])
    roomy.fill(0, roomy.add_container(0, cup(0.04, 0.08)), 50.0, "water")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        roomy.step(20)
    with pytest.raises(InvalidParameterError, match="max_neighbours"):
        SolverConfig(max_neighbours=0)


def test_bounding_spheres_skip_only_colliders_out_of_reach() -> None:
    """Colliders of every kind sunk in liquid: skipping the SDF of colliders whose bounding
    sphere a particle cannot reach changes nothing, bit for bit (the bounds really hold)."""

    def run(skip: bool) -> np.ndarray:
        s = PBFSolver(1)
        tank = s.add_container(0, BoxShell(0.05, 0.05, 0.08, 0.004))
        for kind, params, x in [
            ("sphere", [0.008], -0.03),
            ("capsule", [0.006, 0.008], -0.01),
            ("cylinder", [0.007, 0.006], 0.01),
            ("box", [0.006, 0.005, 0.007], 0.03),
        ]:
            s.add_collider(0, kind, params, pose=[x, 0.02, 0.02, 1, 0, 0, 0])
        s.add_container(0, cup(0.015, 0.02), pose=[0.0, -0.025, 0.012, 1, 0, 0, 0])
        # a closed box mesh (1.2 × 1 × 0.8 cm), turned 30° about z
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
        faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                 [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]  # fmt: skip
        turn = [math.cos(math.pi / 12), 0.0, 0.0, math.sin(math.pi / 12)]
        s.add_collider(
            0, "mesh", [], pose=[0.025, -0.02, 0.03, *turn],
            mesh=(corners * [0.006, 0.005, 0.004], np.array(faces)),
        )  # fmt: skip
        s.fill(0, tank, 300.0, "water")
        s.step(1)
        if not skip:
            s.buf.cols.bound.fill_(1.0e30)
        s.step(30)
        return s.positions()

    np.testing.assert_array_equal(run(True), run(False))


def test_collider_sdfs_are_one_lipschitz() -> None:
    """The collider passes skip a particle's SDFs while its clearance (least distance to a
    collider at the step's predicted position, less the moves since) stays positive; that is
    exact only if no SDF grows faster than distance: |s(a) − s(b)| ≤ |a − b| for every kind."""
    s = PBFSolver(1)
    ids = [s.add_collider(0, "plane", [0.0])]
    for kind, params in [
        ("box", [0.03, 0.02, 0.01]),
        ("sphere", [0.02]),
        ("capsule", [0.01, 0.02]),
        ("cylinder", [0.02, 0.015]),
    ]:
        ids.append(s.add_collider(0, kind, params))
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]  # fmt: skip
    ids.append(s.add_collider(0, "mesh", [], mesh=(corners * [0.03, 0.02, 0.01], np.array(faces))))
    for shape in (
        cup(0.04, 0.08),
        bowl(0.07, 0.05),
        bottle(0.04, 0.1, 0.012, 0.04),
        BoxShell(0.05, 0.03, 0.04, 0.004),
        BoxShell(0.05, 0.03, 0.04, 0.004, closed=True),
    ):
        ids.append(s.add_container(0, shape))
    rng = np.random.default_rng(1)
    a = rng.uniform(-0.09, 0.12, (20000, 3))
    b = a + rng.normal(0.0, 0.01, a.shape)
    step = np.linalg.norm(b - a, axis=1)
    for c in ids:
        rise = np.abs(s.collider_sdf(c, b)[:, 0] - s.collider_sdf(c, a)[:, 0])
        assert np.all(rise <= step + 1e-6), (s.colliders[c].kind, float((rise - step).max()))


def test_step_fractions_rescale_with_the_step() -> None:
    """XSPH viscosity and particle friction relax velocities by fractions per step, rescaled
    so that two half-length steps relax as much as one; adhesion acts as a force: its pull is
    a spring of one stiffness at every step, its grip scales with dt². At ``calibration_dt``
    all are the calibrated values. (That a pour then keeps its timing at another step is checked by
    ``test_a_sticky_pour_does_not_depend_on_the_step``.) XSPH smooths a liquid with a physical
    viscosity by ``xsph_viscosity``, and one without by its own FleX coefficient."""
    got = {}
    ink, honey = (liquid_profile(n).replace(viscosity_pa_s=None) for n in ("ink", "honey"))
    for dt in (1 / 480, 1 / 240, 1 / 120):
        s = PBFSolver(3, SolverConfig(dt=dt))
        s.set_liquid(0, ink)
        s.set_liquid(1, honey)
        s.set_liquid(2, "honey")
        got[dt] = {k: f[:2] for k, f in s.step_fractions().items()}
        xsph = SolverConfig().xsph_viscosity
        assert s.step_fractions()["viscosity_frac"][2] == pytest.approx(
            1.0 - (1.0 / (1.0 + xsph)) ** (dt / SolverConfig().calibration_dt)
        )
    for k in ("viscosity_frac", "friction_frac"):
        left = {dt: 1.0 - f[k] for dt, f in got.items()}
        np.testing.assert_allclose(left[1 / 480] ** 2, left[1 / 240], rtol=1e-12)
        np.testing.assert_allclose(left[1 / 240] ** 2, left[1 / 120], rtol=1e-12)
    grip = {dt: f["adhesion_grip"] for dt, f in got.items()}
    np.testing.assert_allclose(4.0 * grip[1 / 480], grip[1 / 240], rtol=1e-12)
    np.testing.assert_allclose(grip[1 / 120], 4.0 * grip[1 / 240], rtol=1e-12)
    # the pull is a spring of stiffness k: k dt² / (1 + k dt²) a step, the same k at every dt
    stiffness = {
        dt: f["adhesion_frac"] / (1.0 - f["adhesion_frac"]) / dt**2 for dt, f in got.items()
    }
    np.testing.assert_allclose(stiffness[1 / 480], stiffness[1 / 240], rtol=1e-9)
    np.testing.assert_allclose(stiffness[1 / 120], stiffness[1 / 240], rtol=1e-9)
    adhesion = np.array([ink.adhesion, honey.adhesion])
    cfg = SolverConfig()
    kept = {k: 1.0 - f for k, f in got[1 / 240].items()}  # the share that each fraction leaves
    np.testing.assert_allclose(
        kept["viscosity_frac"], 1.0 / (1.0 + np.array([ink.viscosity, honey.viscosity]))
    )
    np.testing.assert_allclose(
        kept["friction_frac"],
        1.0 - 0.1 * np.array([ink.particle_friction, honey.particle_friction]),
    )
    np.testing.assert_allclose(got[1 / 240]["adhesion_frac"], cfg.adhesion_gain * adhesion)
    np.testing.assert_allclose(got[1 / 240]["adhesion_grip"], adhesion * cfg.adhesion_range)


def test_metrics_of_every_world_from_one_pass() -> None:
    """liquid_metrics_all (one kernel pass on the solver's device) gives each world what
    testing its own particles in each container's frame in float64 gives."""
    from pourbench.fluids.metrics import liquid_metrics, liquid_metrics_all
    from pourbench.fluids.scenarios import two_cup_scene
    from pourbench.geometry.rotation import inverse_transform_points

    scene = two_cup_scene(["water", "honey"], 60.0, num_worlds=2)
    s = scene.solver
    scene.set_tilt(np.array([2.0, 1.2]))  # per world
    scene.step(120)
    x = s.positions()
    cups = {w: [scene.source[w], scene.target[w]] for w in (1, 0)}  # any order of worlds
    got = liquid_metrics_all(s, cups)
    for (w, cs), m in zip(cups.items(), got, strict=True):
        xw = x[s.world_slice(w)]
        free = np.ones(len(xw), bool)
        counts = []
        for c in cs:
            col = s.colliders[c]
            inside = col.shape.contains(inverse_transform_points(col.pose, xw), s.config.spacing)
            counts.append(int((inside & free).sum()))
            free &= ~inside
        m_g = s.particle_mass(w) * 1e3
        assert m.inside_g == pytest.approx([n * m_g for n in counts], abs=1e-9)
        assert m.particles == len(xw) and m.total_g == pytest.approx(60.0, abs=0.6)
        assert m == liquid_metrics(s, w, cs)
    assert got[0].inside_g != got[1].inside_g  # the two pours differ: worlds kept apart
    with pytest.raises(ValueError, match="not a container of world 0"):
        liquid_metrics_all(s, {0: [scene.source[1], scene.target[0]]})


def test_a_runaway_below_the_speed_cap_is_flagged() -> None:
    """A particle thrown out of a cup of settled water at 3 m/s (far below ``max_speed``, but
    faster than any fall in the scene could make it) flags its world, and only its world."""
    s = PBFSolver(2)
    shape = cup(0.03, 0.06)
    for w in range(2):
        s.fill(w, s.add_container(w, shape), 100.0, "water")
    for _ in range(10):
        s.step(6)
        assert not s.diverged().any()
    top = s.positions()[s.world_slice(1)][:, 2].max()
    s.add_particles(1, [[0.0, 0.0, top + 0.004]], velocities=[[0.5, 0.0, 3.0]])
    s.step()
    assert s.diverged().tolist() == [False, True]


def test_divergence_is_judged_on_the_state_waiting_for_upload_too() -> None:
    """Between an edit and the next step (the host state), a particle added too fast or not
    finite flags its world; the others stay unflagged, and a step changes nothing of that."""
    s = PBFSolver(3)
    for w in range(3):
        s.fill(w, s.add_container(w, cup(0.03, 0.06)), 40.0, "water")
    s.step(2)
    s.add_particles(1, [[0.0, 0.0, 0.05]], velocities=[[0.0, 0.0, 2.0 * s.config.max_speed]])
    s.add_particles(2, [[0.0, 0.0, 0.05]])
    s._x[-1] = np.nan  # a host state that diverged (add_particles refuses a NaN itself)
    assert s.diverged().tolist() == [False, True, True]
    s.step()
    assert s.diverged().tolist() == [False, True, True]


def test_fast_liquid_motion_is_not_a_blow_up() -> None:
    """A collapsing 12 cm column (its front near the free-fall speed from its top) and a tray
    of water carried at 1.5 m/s, then stopped dead, are never flagged."""
    dam = PBFSolver(1)
    dam.add_container(0, BoxShell(0.15, 0.025, 0.2, 0.005))
    block = np.stack(np.meshgrid(*(np.arange(k) * 0.005 for k in (12, 10, 24))), -1)
    dam.add_particles(0, block.reshape(-1, 3) + np.array([-0.1475, -0.0225, 0.0075]))
    tray = PBFSolver(1)
    box = BoxShell(0.04, 0.04, 0.03, 0.003)
    c = tray.add_container(0, box)
    tray.fill(0, c, 100.0, "water")
    fastest = 0.0
    for _ in range(48):
        dam.step(4)
        for _ in range(4):  # carried at 1.5 m/s for 0.4 s, then held
            x = min(tray.steps + 1, 96) * tray.config.dt * 1.5
            tray.set_collider_poses([c], np.array([[x, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]]))
            tray.step()
        fastest = max(fastest, float(np.linalg.norm(dam.velocities(), axis=1).max()))
        assert not dam.diverged().any(), f"dam break flagged at {dam.time:.2f} s"
        assert not tray.diverged().any(), f"carried tray flagged at {tray.time:.2f} s"
    assert fastest > 1.0  # the collapse is fast: the bound is not idle


def test_fill_at_least_holds_the_mass_asked_for_with_one_particle_to_spare_at_most() -> None:
    """``at_least`` rounds the particle count up: the least count whose mass reaches the
    grams asked for, where the default takes the nearest count (which may fall short)."""
    s = PBFSolver(2)
    grams = s.particle_mass(0) * 1e3
    cups = [s.add_container(w, cup(0.04, 0.08)) for w in range(2)]
    for mass_g in (100.0, 99.9, 10 * grams, 10.4 * grams, 0.2 * grams):
        s.clear_world(0)
        s.clear_world(1)
        n_up = s.fill(0, cups[0], mass_g, "water", at_least=True)
        n_near = s.fill(1, cups[1], mass_g, "water")
        assert n_up * grams >= mass_g > (n_up - 1) * grams
        assert n_near == round(mass_g / grams)
    # the nearest count can fall short of the mass asked for; rounded up it cannot
    s.clear_world(0)
    assert s.fill(0, cups[0], 10.4 * grams, "water") * grams < 10.4 * grams


def spiky_moment(grad_c: float, h: float, r: np.ndarray) -> np.ndarray:
    """The gradient moments −∇W ⊗ r of the offsets ``r`` (rows) within h: −grad_c (h − d)² / d
    · r ⊗ r, summed."""
    d = np.linalg.norm(r, axis=1)
    keep = (d < h) & (d > 1e-9)
    weight = -grad_c * (h - d[keep]) ** 2 / d[keep]
    return np.einsum("k,ka,kb->ab", weight, r[keep], r[keep])


def lattice_offsets(n: np.ndarray, spacing: float) -> np.ndarray:
    """The 26 lattice offsets p_i − site within h = 2 spacings, turned to the wall normal n
    as the solver turns them."""
    t1 = np.cross(n, [0.0, 1.0, 0.0] if abs(n[0]) > 0.6 else [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    steps = np.array(np.meshgrid(*[[-1, 0, 1]] * 3, indexing="ij")).reshape(3, -1).T
    steps = steps[np.any(steps != 0, axis=1)]
    return steps @ np.array([t1, np.cross(n, t1), n]) * spacing


def lattice_solid_moments(
    p: np.ndarray, plane: np.ndarray, sdf, spacing: float, grad_c: float, h: float
) -> tuple[np.ndarray, int]:
    """What a particle at ``p`` with wall ``plane`` (n, offset, κ) counts of the solid on the
    lattice sites, from the solid's signed distance ``sdf`` (points → m) and each site's
    share clip(1/2 − sd/s): beside a flat or concave wall (κ = 0), where its mirror images
    stand for the half-space behind the plane, the share less the plane's where positive, at
    the site and at its mirror image across the plane; beside a sphere (κ > 0) the share.
    Also the number of sites that count."""
    n, offset, kappa = plane[:3], plane[3], plane[4]
    r = lattice_offsets(n, spacing)
    sites = p - r
    behind = sites @ n - offset  # the sites' signed distance to the plane
    share = np.clip(0.5 - sdf(sites) / spacing, 0, 1)
    if kappa > 0.0:
        extra, mirrored = share, np.zeros((0, 3))
    else:
        extra = np.maximum(share - np.clip(0.5 - behind / spacing, 0, 1), 0.0)
        mirrored = (r + 2.0 * behind[:, None] * n)[extra > 0]
    d = np.linalg.norm(r, axis=1)
    moments = np.einsum("k,ka,kb->ab", -grad_c * (h - d) ** 2 / d * extra, r, r)
    if len(mirrored):
        dm = np.linalg.norm(mirrored, axis=1)
        weight = np.where(dm < h, -grad_c * (h - dm) ** 2 / dm, 0.0) * extra[extra > 0]
        moments += np.einsum("k,ka,kb->ab", weight, mirrored, mirrored)
    return moments, int((extra > 0).sum())


@pytest.mark.parametrize("mode", ["half", "full"])
def test_the_correction_matrices_invert_each_particles_gradient_moments(mode: str) -> None:
    """``corrected_pressure``: each particle's matrix is tr(M)/3 · M⁻¹ for its gradient
    moments M = −Σ_j ∇_i W_ij ⊗ r_ij, summed here over the pairs a k-d tree finds; a particle
    with a container wall within h adds the same moments of the mirror images of itself and
    of its neighbours in front of the wall's plane, and of the solid where it is not that
    half-space (the cup's inner corner), counted on the lattice sites at the spacing from the
    shapes' own signed distances; one beside a sphere (a ball resting in world 2's cup)
    counts the solid on the lattice sites. The identity where M is too one-sided to invert
    (three particles in a row, world 1)."""
    from scipy.spatial import cKDTree

    from pourbench.fluids.colliders import KIND_NAMES
    from pourbench.fluids.config import rest_sums
    from pourbench.fluids.kernels import CORRECTION_MIN_RATIO

    s = PBFSolver(3, SolverConfig(corrected_pressure=True, pair_lists=mode))
    cups = {}
    for w in (0, 2):
        s.add_collider(w, "plane", [0.0])
        cups[w] = s.add_container(w, cup(0.04, 0.08))
    s.add_collider(2, "sphere", [0.012], pose=[0.0, 0.0, 0.016, 1, 0, 0, 0])
    for w, index in cups.items():
        s.fill(w, index, 60.0, "water")
    s.add_particles(1, np.array([[0.3, 0.3, 0.05], [0.304, 0.3, 0.05], [0.308, 0.3, 0.05]]))
    s.step(5)
    s.launches.build_neighbours()
    s.launches.correct_gradients()
    p = s.buf.p.numpy().astype(float)
    got = s.buf.corr.numpy().astype(float)
    h, grad_c, spacing = s.config.h, rest_sums(s.config)[1], s.config.spacing
    world = s.worlds()
    tree = cKDTree(p)
    moments = np.zeros((len(p), 3, 3))
    for i, j in tree.query_pairs(h):
        if world[i] == world[j]:
            moments[[i, j]] += spiky_moment(grad_c, h, (p[i] - p[j])[None])

    def sdf(points: np.ndarray, w: int) -> np.ndarray:
        sd = np.full(len(points), np.inf)
        for c in s.colliders:
            if c.world != w:
                continue
            local = inverse_transform_points(c.pose, points)
            if c.shape is not None:
                sd = np.minimum(sd, c.shape.sdf(local))
            elif c.kind == KIND_NAMES["sphere"]:
                sd = np.minimum(sd, np.linalg.norm(local, axis=1) - c.params[0])
            else:
                assert c.kind == KIND_NAMES["plane"]
                sd = np.minimum(sd, local[:, 2])
        return sd

    wall = s.buf.wall.numpy().astype(float)
    sites = {"container": 0, "sphere": 0}
    for i in np.flatnonzero(s.buf.wall_collider.numpy() >= 0):
        n, offset, kappa = wall[i, :3], wall[i, 3], wall[i, 4]
        if kappa <= 0.0:
            near = [j for j in tree.query_ball_point(p[i], h) if world[j] == world[i]]
            ahead = p[near] @ n - offset
            ghosts = p[near][ahead > 0] - 2.0 * ahead[ahead > 0, None] * n  # itself included
            moments[i] += spiky_moment(grad_c, h, p[i] - ghosts)
        solid, count = lattice_solid_moments(
            p[i], wall[i], lambda q, w=world[i]: sdf(q, w), spacing, grad_c, h
        )
        moments[i] += solid
        sites["sphere" if kappa > 0.0 else "container"] += count
    assert sites["container"] > 0 and sites["sphere"] > 0
    mean = np.trace(moments, axis1=1, axis2=2) / 3.0
    invertible = np.linalg.det(moments) >= CORRECTION_MIN_RATIO * mean**3
    assert invertible.sum() > 0.95 * (world != 1).sum()
    assert not invertible[world == 1].any()
    products = got[invertible] @ moments[invertible]
    expected = mean[invertible, None, None] * np.eye(3)
    np.testing.assert_allclose(products, expected, atol=1e-3 * mean.max())
    np.testing.assert_allclose(got[~invertible], np.broadcast_to(np.eye(3), got[~invertible].shape))


def test_a_layer_half_a_spacing_above_a_floor_sees_its_mirror_layer_below() -> None:
    """A weightless square layer of particles at the spacing s, half a spacing above a floor:
    the middle particle's moments are its own layer's (four neighbours at s, four at √2 s)
    and its mirror layer's a spacing below (one at s, four at √2 s, four at √3 s). In closed
    form, with f(d) = −grad_c (h − d)² / d: M_xx = M_yy = s² [2 f(s) + 4 f(√2 s) + 2 f(√2 s)
    + 4 f(√3 s)] and M_zz = s² [f(s) + 4 f(√2 s) + 4 f(√3 s)], so its correction matrix is
    tr(M)/3 · M⁻¹. A lone particle a spacing and a half up has neither neighbours nor an
    image within h: the identity."""
    from pourbench.fluids.config import rest_sums

    cfg = SolverConfig(corrected_pressure=True, gravity=(0.0, 0.0, 0.0))
    s, h, grad_c = cfg.spacing, cfg.h, rest_sums(cfg)[1]
    f = lambda d: -grad_c * (h - d) ** 2 / d  # noqa: E731
    r2, r3 = np.sqrt(2.0) * s, np.sqrt(3.0) * s
    xx = s**2 * (2 * f(s) + 6 * f(r2) + 4 * f(r3))
    zz = s**2 * (f(s) + 4 * f(r2) + 4 * f(r3))
    expected = (2 * xx + zz) / 3 * np.diag([1 / xx, 1 / xx, 1 / zz])
    grid = (np.arange(5) - 2) * s
    layer = np.stack(np.meshgrid(grid, grid, [0.5 * s], indexing="ij"), -1).reshape(-1, 3)
    shift = np.array([0.01, 0.02, 0.0])
    middle = shift + np.array([0.0, 0.0, 0.5 * s])
    up = np.array([0.0, 0.0, s])
    for points, at, matrix in (
        (layer + shift, middle, expected),
        ((middle + up)[None], middle + up, np.eye(3)),
    ):
        solver = PBFSolver(1, cfg)
        solver.add_collider(0, "plane", [0.0])
        solver.add_particles(0, points)
        solver.step(1)
        solver.launches.build_neighbours()
        solver.launches.correct_gradients()
        p = solver.buf.p.numpy()
        index = np.argmin(np.linalg.norm(p - at, axis=1))
        np.testing.assert_allclose(p[index], at, atol=1e-7)  # the middle stays: symmetric
        np.testing.assert_allclose(solver.buf.corr.numpy()[index], matrix, rtol=3e-4, atol=1e-6)


def test_a_particle_in_a_corner_of_three_colliders_counts_the_solid_of_all_three() -> None:
    """A lone particle in the corner of three planes (a floor and two walls, each its own
    collider): beside its own mirror image across its nearest wall, it counts the other two
    walls on the lattice sites, turned to its nearest wall, weighted by the least of the
    three planes' shares less the nearest plane's, at each site and at its mirror image, so
    more than two colliders near a particle count as one solid."""
    from pourbench.fluids.config import rest_sums

    cfg = SolverConfig(corrected_pressure=True, gravity=(0.0, 0.0, 0.0))
    s, h, grad_c = cfg.spacing, cfg.h, rest_sums(cfg)[1]
    c45 = np.sqrt(0.5)
    solver = PBFSolver(1, cfg)
    solver.add_collider(0, "plane", [0.0])  # z = 0
    solver.add_collider(0, "plane", [0.0], pose=np.array([0, 0, 0, c45, 0, c45, 0]))  # x = 0
    solver.add_collider(0, "plane", [0.0], pose=np.array([0, 0, 0, c45, -c45, 0, 0]))  # y = 0
    x = np.array([0.6, 0.7, 0.8]) * s
    solver.add_particles(0, x[None])
    solver.step(1)
    solver.launches.build_neighbours()
    solver.launches.correct_gradients()
    x = solver.buf.p.numpy()[0].astype(float)  # where the step left it (moved by < 1 µm)
    np.testing.assert_allclose(x, np.array([0.6, 0.7, 0.8]) * s, atol=1e-6)

    plane = np.array([1.0, 0.0, 0.0, 0.0, 0.0])  # the x = 0 wall is nearest
    moments = spiky_moment(grad_c, h, np.array([[2.0 * x[0], 0.0, 0.0]]))  # its image
    solid, count = lattice_solid_moments(x, plane, lambda q: q.min(axis=1), s, grad_c, h)
    assert count > 0  # the other two walls' sites
    moments += solid
    expected = np.trace(moments) / 3.0 * np.linalg.inv(moments)
    np.testing.assert_allclose(solver.buf.corr.numpy()[0], expected, rtol=1e-4, atol=1e-6)


def test_a_lattice_liquid_in_a_closed_box_is_pushed_alike_in_every_direction() -> None:
    """The solid counts as the mirror images of the liquid in front of it, so a liquid on the
    cubic lattice, filling a closed box half a spacing from every wall, has complete, even
    neighbourhoods: the particles beside the walls are pushed toward them as hard as along
    them (``validation.wall_push_anisotropy``: n·C·n and t·C·t both 1)."""
    from pourbench.fluids.validation import wall_push_anisotropy

    cfg = SolverConfig(corrected_pressure=True, gravity=(0.0, 0.0, 0.0))
    d, (nx, ny, nz) = cfg.spacing, (8, 8, 6)
    box = BoxShell(half_x=nx * d / 2, half_y=ny * d / 2, depth=nz * d, wall=0.01, closed=True)
    axes = [(np.arange(k) + 0.5) * d - k * d / 2 for k in (nx, ny)]
    axes.append((np.arange(nz) + 0.5) * d + box.bottom_z)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    s = PBFSolver(1, cfg)
    s.add_container(0, box)
    s.add_particles(0, grid)
    s.step(1)
    normal, tangential, count = wall_push_anisotropy(s)
    assert count == nx * ny * nz - (nx - 2) * (ny - 2) * (nz - 2)  # the outer shell
    assert normal == pytest.approx(1.0, abs=2e-3)
    assert tangential == pytest.approx(1.0, abs=2e-3)


def test_settled_water_beside_its_cup_is_pushed_toward_the_wall_as_along_it() -> None:
    """200 g of water settled for a second in a cup (docs/rest.md) packs beside the wall in
    its own way, not as the lattice; the mirror images of that packing complete the wall
    layer's neighbourhoods, so its particles are pushed toward the wall as hard as along it
    within 3 % (``validation.wall_push_anisotropy``; docs/viscosity.md, "Shear cell")."""
    from pourbench.fluids.validation import wall_push_anisotropy

    s = PBFSolver(1, SolverConfig(corrected_pressure=True))
    s.add_collider(0, "plane", [0.0])
    s.fill(0, s.add_container(0, cup(0.04, 0.08)), 200.0, "water")
    s.step(240)
    normal, tangential, count = wall_push_anisotropy(s)
    assert count > 400
    assert normal == pytest.approx(1.0, abs=0.03)
    assert tangential == pytest.approx(1.0, abs=0.03)


def test_the_corrected_pressure_keeps_momentum() -> None:
    """A weightless blob packed a tenth too tight springs apart under the corrected density
    solve as under the plain one, along other paths (the correction acts), and its momentum
    stays zero: the mean of a pair's two matrices keeps the pair's corrections opposite."""
    g = np.arange(-5, 6) * 0.0045
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    x = x[np.linalg.norm(x, axis=1) < 0.025] + 0.1
    x += np.random.default_rng(0).normal(0.0, 3e-4, x.shape)  # an irregular packing
    spread, moved = {}, {}
    for corrected in (False, True):
        cfg = SolverConfig(gravity=(0.0, 0.0, 0.0), corrected_pressure=corrected)
        s = PBFSolver(1, cfg)
        s.set_liquid(0, liquid_profile("water"))
        s.add_particles(0, x)
        s.step(10)
        v = s.velocities().astype(float)
        assert np.linalg.norm(v.sum(axis=0)) < 1e-4 * np.abs(v).sum()
        moved[corrected] = s.positions().astype(float)
        spread[corrected] = np.linalg.norm(moved[corrected] - 0.1, axis=1).mean()
    start = np.linalg.norm(x - 0.1, axis=1).mean()
    apart = np.linalg.norm(moved[True] - moved[False], axis=1)
    assert np.median(apart) > 1e-5, np.median(apart)  # a hundredth of a millimetre
    assert spread[True] > start and spread[False] > start
    assert spread[True] == pytest.approx(spread[False], rel=0.05)


@pytest.mark.parametrize("mode", ["half", "full"])
def test_the_bulk_scorr_mean_is_the_kernel_weighted_mean_over_a_particles_pairs(mode) -> None:
    """``bulk_scorr_spread`` below 1: a density pass leaves in ``scorr_mean`` each particle's
    Σ_j W_ij s_corr_ij / Σ_j W_ij over its neighbours (W the spiky density kernel, s_corr the
    tensile term −k ((h² − r²)³ / (h² − Δq²)³)ⁿ + k c), as the pairs a k-d tree finds give it,
    with half lists (summed from both ends of a pair) and full lists alike."""
    from scipy.spatial import cKDTree

    # no extra iterations: every world stays active, so the pass below covers them all
    cfg = SolverConfig(bulk_scorr_spread=0.3, pair_lists=mode, max_iterations=4, iterations=4)
    s = PBFSolver(2, cfg)
    for w in range(2):
        s.add_collider(w, "plane", [0.0])
        s.fill(w, s.add_container(w, cup(0.04, 0.08)), 40.0 + 20.0 * w, "water")
    s.step(5)
    s.launches.build_neighbours()
    p = s.buf.p.numpy().astype(float)
    s.launches.density_iteration()
    got = s.buf.scorr_mean.numpy().astype(float)

    h = s.config.h
    k, n, w_dq, offset = s.constants.scorr
    world = s.worlds()
    weighted, total = np.zeros(len(p)), np.zeros(len(p))
    for i, j in cKDTree(p).query_pairs(h):
        if world[i] != world[j]:
            continue
        d = np.linalg.norm(p[i] - p[j])
        w = (h - d) ** 3
        scorr = -k * (((h * h - d * d) ** 3 / w_dq) ** n - offset)
        weighted[[i, j]] += w * scorr
        total[[i, j]] += w
    has = total > 0
    assert has.sum() == len(p) == 800  # 100 g of water at 5 mm, every particle with neighbours
    want = weighted[has] / total[has]
    # float32 sums: a mean near zero (offset and repulsion cancelling) is held to the scale
    np.testing.assert_allclose(got[has], want, rtol=1e-3, atol=1e-4 * np.abs(want).max())


def test_a_bulk_scorr_spread_outside_zero_to_one_is_refused() -> None:
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(InvalidParameterError, match="bulk_scorr_spread"):
            SolverConfig(bulk_scorr_spread=bad)
