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
