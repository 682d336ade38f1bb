"""Containers: one TOML description -> fluid SDF collider and MuJoCo body that agree."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from scipy.spatial import ConvexHull

from pourbench.containers import (
    DEFAULT_MAX_ERROR,
    Container,
    add_container_body,
    container_names,
    get_container,
    load_containers,
)
from pourbench.errors import ProfileFileError, UnknownNameError

NAMES = container_names()


def _cavity_volume(c: Container, dz: float = 2e-4, dr: float = 1e-4) -> float:
    """Integrate the cavity from the SDF alone, m^3.

    In the (rho, z) half-plane, a cell at height z <= rim belongs to the cavity if it is outside
    the wall and lies between the axis and the first wall cell met going outward from the axis.
    """
    shape = c.shape
    z = np.arange(dz / 2, shape.rim_height, dz)
    rho = np.arange(dr / 2, shape.outer_radius + 2 * dr, dr)
    total = 0.0
    for rows in np.array_split(z, max(1, len(z) // 200)):
        zz, rr = np.meshgrid(rows, rho, indexing="ij")
        pts = np.stack([rr, np.zeros_like(rr), zz], axis=-1)
        wall = shape.sdf(pts) < 0
        first = np.where(wall.any(axis=1), wall.argmax(axis=1), 0)
        cavity = np.arange(len(rho))[None, :] < first[:, None]
        total += float((cavity * (2 * math.pi * rr * dr * dz)).sum())
    return total


def test_family_covers_the_thesis_containers() -> None:
    assert len(NAMES) >= 13
    roles = [get_container(n).role for n in NAMES]
    assert roles.count("training") == 1
    assert roles.count("novel") >= 10
    tray = get_container("tray")
    assert tray.role == "receiving"
    assert tray.shape.inner_radius(tray.rim_height - 1e-3) == pytest.approx(0.10, abs=1e-9)
    for kind in ("cup_small", "cup_wide", "cup_tall", "beaker_spout", "mug", "wine_glass"):
        assert kind in NAMES
    for kind in ("bowl", "bottle_wine", "bottle_water", "measuring_cylinder", "pitcher", "spoon"):
        assert kind in NAMES
    # the bottles' narrow necks: mouth much narrower than the body
    for b in ("bottle_wine", "bottle_water"):
        c = get_container(b)
        assert c.mouth_diameter < 0.4 * c.diameter


@pytest.mark.parametrize("name", NAMES)
def test_interior_volume_matches_integrated_sdf(name: str) -> None:
    c = get_container(name)
    numeric = _cavity_volume(c)
    assert numeric == pytest.approx(c.interior_volume, rel=0.02)
    assert c.depth > 0 and c.diameter > 2 * c.shape.mouth_radius - 1e-12


def _mujoco_inside(model: mujoco.MjModel, data: mujoco.MjData, pts: np.ndarray) -> np.ndarray:
    """Points inside any of the model's mesh geoms, from MuJoCo's compiled vertices."""
    inside = np.zeros(len(pts), dtype=bool)
    for g in range(model.ngeom):
        mid = model.geom_dataid[g]
        adr, num = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
        local = model.mesh_vert[adr : adr + num].astype(float)
        verts = data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        cand = np.flatnonzero(np.all((pts >= lo) & (pts <= hi), axis=1) & ~inside)
        if len(cand) == 0:
            continue
        eq = ConvexHull(verts).equations
        ok = np.all(pts[cand] @ eq[:, :3].T + eq[:, 3] <= 1e-12, axis=1)
        inside[cand[ok]] = True
    return inside


def _sample(c: Container, rng: np.random.Generator, n: int) -> np.ndarray:
    """Half uniform in the bounding box, half within 1.5 wall thicknesses of the mid-surface."""
    s = c.shape
    r, top = s.outer_radius + 0.005, s.rim_height + 0.005
    box = rng.uniform((-r, -r, -0.005), (r, r, top), size=(n // 2, 3))
    pts = s.points
    seg = rng.integers(0, len(pts) - 1, n - n // 2)
    a, b = pts[seg], pts[seg + 1]
    t = b - a
    normal = np.stack([-t[:, 1], t[:, 0]], axis=1) / np.linalg.norm(t, axis=1)[:, None]
    q = a + rng.uniform(0, 1, (len(seg), 1)) * t
    q += rng.uniform(-1.5, 1.5, (len(seg), 1)) * s.wall * normal
    phi = rng.uniform(0, 2 * math.pi, len(seg))
    near = np.stack([np.abs(q[:, 0]) * np.cos(phi), np.abs(q[:, 0]) * np.sin(phi), q[:, 1]], 1)
    return np.concatenate([box, near])


@pytest.mark.parametrize("name", NAMES)
def test_mujoco_body_agrees_with_sdf(name: str) -> None:
    c = get_container(name)
    spec = mujoco.MjSpec()
    add_container_body(spec, spec.worldbody, c)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.body_mass[1] == pytest.approx(c.mass, rel=1e-9)
    pts = _sample(c, np.random.default_rng(7), 6000)
    sdf = c.shape.sdf(pts)
    clear = np.abs(sdf) > DEFAULT_MAX_ERROR  # outside the thin band where the meshes may err
    inside = _mujoco_inside(model, data, pts[clear])
    wrong = inside != (sdf[clear] < 0)
    assert clear.sum() > 5000
    assert (sdf[clear] < 0).sum() > 500  # plenty of points inside the wall were tested
    assert not wrong.any(), f"{wrong.sum()} disagreeing points, e.g. {pts[clear][wrong][:3]}"
    # the mount site sits on the outside of the wall, approaching towards the axis
    mpos, mquat = c.mount_pose()
    assert -c.wall / 2 <= float(c.shape.sdf(mpos[None])[0]) <= 1e-9
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, mquat)
    np.testing.assert_allclose(rot.reshape(3, 3)[:, 2], (-1, 0, 0), atol=1e-12)
    np.testing.assert_allclose(rot.reshape(3, 3)[:, 0], (0, 0, 1), atol=1e-12)
    site = model.site(f"{name}_mount")
    np.testing.assert_allclose(data.site_xpos[site.id], mpos, atol=1e-12)


def test_unknown_container_lists_known_ones() -> None:
    with pytest.raises(ValueError, match="teapot") as info:
        get_container("teapot")
    assert isinstance(info.value, UnknownNameError)
    for n in NAMES:
        assert n in str(info.value)


def test_malformed_file_names_the_key(tmp_path) -> None:
    f = tmp_path / "c.toml"
    f.write_text(
        '[container.x]\nrole = "novel"\nkind = "cup"\nradius = 0.03\ndepth = 0.05\n'
        'wall = 0.003\nmass = -1.0\ngrasp_height = 0.02\nrgba = [1, 1, 1, 1]\ndescription = ""\n'
    )
    with pytest.raises(ProfileFileError, match=r"container\.x\.mass"):
        load_containers(f)
    f.write_text(f.read_text().replace('kind = "cup"', 'kind = "vase"').replace("-1.0", "1.0"))
    with pytest.raises(ProfileFileError, match="vase"):
        load_containers(f)


_GOOD = (
    '[container.x]\nrole = "novel"\nkind = "cup"\nradius = 0.03\ndepth = 0.05\nwall = 0.003\n'
    'mass = 1.0\ngrasp_height = 0.02\nrgba = [1, 1, 1, 1]\ndescription = ""\n'
)
_PROFILE = 'kind = "profile"\npoints = [[0, 0], [0.03, 0], [0.03, 0.05]]\n'


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("rgba = [1, 1, 1, 1]", "rgba = [nan, 1, 1, 1]", r"container\.x\.rgba"),
        ("rgba = [1, 1, 1, 1]", "rgba = [2, -1, 1, 1]", r"container\.x\.rgba.*\[0, 1\]"),
        ("rgba = [1, 1, 1, 1]", "rgba = 1", r"container\.x\.rgba"),
        ("rgba = [1, 1, 1, 1]", 'rgba = ["a", 1, 1, 1]', r"container\.x\.rgba"),
        ("rgba = [1, 1, 1, 1]", "rgba = [1, 1, 1]", r"container\.x\.rgba"),
        ("mass = 1.0", "mass = true", r"container\.x\.mass.*True"),
        ("mass = 1.0", 'mass = "abc"', r"container\.x\.mass.*'abc'"),
        ("mass = 1.0", "mass = inf", r"container\.x\.mass"),
        ("radius = 0.03", "radius = true", r"container\.x\.radius.*True"),
        ("radius = 0.03", "radius = nan", r"container\.x\.radius"),
        ("radius = 0.03", "radius = 1e300", r"container\.x'.*<= 2\.0 m"),
        ("radius = 0.03", "radius = 1e4", r"container\.x'.*<= 2\.0 m"),
        ("wall = 0.003", "wall = 1e-300", r"container\.x\.wall.*>= 0\.0001"),
        ("grasp_height = 0.02", 'grasp_height = "a"', r"container\.x\.grasp_height"),
        ("grasp_height = 0.02", "grasp_height = nan", r"container\.x\.grasp_height"),
        ('description = ""', "description = [1]", r"container\.x\.description"),
        ('kind = "cup"', 'kind = ["cup"]', r"container\.x\.kind"),
        ('role = "novel"', 'role = ["novel"]', r"container\.x\.role"),
        ("[container.x]", '[container.""]', r"non-empty name"),
        (_GOOD, "[container]\nx = 3\n", r"container\.x'.*must be a table"),
        (_GOOD, "container = 3\n", r"'container'"),
        (_GOOD, "[container.x\nrole =", r"c\.toml.*invalid TOML"),
        (
            'kind = "cup"\nradius = 0.03\ndepth = 0.05\n',
            _PROFILE.replace("0.05]", "true]"),
            "points",
        ),
        ('kind = "cup"\nradius = 0.03\ndepth = 0.05\n', 'kind = "profile"\npoints = 3\n', "points"),
    ],
)
def test_malformed_entry_names_file_and_key(tmp_path, old: str, new: str, match: str) -> None:
    f = tmp_path / "c.toml"
    assert old in _GOOD
    f.write_text(_GOOD.replace(old, new))
    with pytest.raises(ProfileFileError, match=match) as info:
        load_containers(f)
    assert str(f) in str(info.value)


def test_good_custom_file_still_loads(tmp_path) -> None:
    f = tmp_path / "c.toml"
    f.write_text(
        _GOOD
        + _GOOD.replace("[container.x]", "[container.y]").replace(
            'kind = "cup"\nradius = 0.03\ndepth = 0.05\n', _PROFILE
        )
    )
    got = load_containers(f)
    assert got["x"].rgba == (1.0, 1.0, 1.0, 1.0) and got["x"].mass == 1.0
    assert got["y"].rim_height == pytest.approx(0.05)


def test_unreadable_file_is_a_profile_error(tmp_path) -> None:
    for path in (tmp_path / "missing.toml", tmp_path):
        with pytest.raises(ProfileFileError, match="cannot read") as info:
            load_containers(path)
        assert str(path) in str(info.value)


_NAN = float("nan")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"max_error": 0}, r"max_error must be >= 1e-05"),
        ({"max_error": -1e-3}, r"max_error must be >= 1e-05"),
        ({"max_error": 1e-9}, r"max_error must be >= 1e-05"),
        ({"max_error": _NAN}, r"max_error must be finite"),
        ({"max_error": float("inf")}, r"max_error must be finite"),
        ({"max_error": "0.001"}, r"max_error must be a number"),
        ({"max_error": True}, r"max_error must be a number"),
        ({"pos": (_NAN, 0, 0)}, r"pos must be finite"),
        ({"pos": (0, 0)}, r"pos must have shape \(3,\)"),
        ({"pos": None}, r"pos must have shape"),
        ({"quat": (0, 0, 0, 0)}, r"quat must not be zero"),
        ({"quat": (_NAN, 0, 0, 0)}, r"quat must be finite"),
        ({"container": 5}, r"container must be a Container or a container name"),
        ({"container": None}, r"container must be a Container or a container name"),
        ({"container": "teapot"}, r"unknown container 'teapot'"),
        ({"name": 5}, r"name must be a string"),
        ({"mocap": True, "parent": "body"}, r"mocap body 'a': parent must be spec\.worldbody"),
        ({"name": "taken"}, r"'taken' is already in the spec"),
    ],
)
def test_refused_add_container_body_leaves_spec_unchanged(kwargs: dict, match: str) -> None:
    spec = mujoco.MjSpec()
    other = spec.worldbody.add_body(name="taken")
    args = {"container": "cup_small", "name": "a", "parent": spec.worldbody} | kwargs
    if args["parent"] == "body":
        args["parent"] = other
    container, parent = args.pop("container"), args.pop("parent")
    with pytest.raises(ValueError, match=match):
        add_container_body(spec, parent, container, **args)
    assert spec.body("a") is None and spec.mesh("a_wall_0") is None
    add_container_body(spec, spec.worldbody, "cup_small", name="a")  # the name is still free
    model = spec.compile()
    assert model.nbody == 3 and model.body("a").mass[0] == pytest.approx(0.08)


def test_mesh_size_is_capped_before_building() -> None:
    import dataclasses

    from pourbench.geometry.shapes import cup

    huge = dataclasses.replace(get_container("cup_small"), name="huge", shape=cup(1e4, 0.05))
    with pytest.raises(ValueError, match=r"container 'huge' at max_error=0\.0002 needs \d+ wall"):
        huge.wall_pieces()
    spec = mujoco.MjSpec()
    with pytest.raises(ValueError, match=r"'huge'.*limit 2048"):
        add_container_body(spec, spec.worldbody, huge)
    assert spec.body("huge") is None
    thick = dataclasses.replace(huge, name="thick", shape=cup(1.0, 0.5, 1.0))
    with pytest.raises(ValueError, match=r"'thick' at max_error=1e-05 needs \d+ chords"):
        thick.wall_pieces(1e-5)
    with pytest.raises(ValueError, match="max_error must be >= 1e-05"):
        get_container("bowl").wall_pieces(1e-6)
    assert len(get_container("bowl").wall_pieces(2e-4)) == 387  # the default mesh as before
