"""Signed distances of pourbench.planners.distance against brute force and against MuJoCo."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pourbench.errors import InvalidParameterError
from pourbench.planners.distance import (
    Box,
    Capsule,
    Sphere,
    capsule_obstacle_distances,
    obstacle_from_mujoco_geom,
    point_box_signed_distance,
)


def _dense_capsule_distance(a, b, r, ob, n=2001):
    """Brute force: sample the capsule axis densely, exact distance to the obstacle."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = a + t * (b - a)
    if isinstance(ob, Sphere):
        d = np.linalg.norm(pts - ob.center, axis=1) - ob.radius
    elif isinstance(ob, Box):
        d = point_box_signed_distance(pts, ob.center, ob.half_extents, ob.rotation)[0]
    else:
        ab = ob.b - ob.a
        s = np.clip((pts - ob.a) @ ab / (ab @ ab), 0.0, 1.0)[:, None]  # exact per sample
        d = np.linalg.norm(pts - (ob.a + s * ab), axis=1) - ob.radius
    return d.min() - r


def test_capsule_distances_match_brute_force():
    rng = np.random.default_rng(3)
    worst = 0.0
    for k in range(40):
        a, b = rng.normal(0, 0.3, (2, 3))
        r = rng.uniform(0.02, 0.08)
        obs = [
            Sphere(rng.normal(0, 0.3, 3), rng.uniform(0.02, 0.2)),
            Box(
                rng.normal(0, 0.3, 3),
                rng.uniform(0.05, 0.3, 3),
                Rotation.random(random_state=k).as_matrix(),
            ),
            Capsule(*rng.normal(0, 0.3, (2, 3)), rng.uniform(0.02, 0.1)),
        ]
        res = capsule_obstacle_distances(a[None], b[None], np.array([r]), obs)
        for j, ob in enumerate(obs):
            brute = _dense_capsule_distance(a, b, r, ob)
            sd = res.sd[0, j]
            # Our value is the exact minimum: never above the sampled one, and close to it.
            assert sd <= brute + 1e-9
            worst = max(worst, brute - sd)
            # The reported points realise the distance.
            gap = np.linalg.norm(res.point_robot[0, j] - res.point_obstacle[0, j])
            assert abs(abs(sd + r) - gap) < 1e-9
    assert worst < 2e-3  # sampling step of the brute force (0.5 mm on ≤ 1 m axes) bounds it


def _mujoco_pair(kind: str, params: dict) -> tuple[mujoco.MjModel, mujoco.MjData]:
    cap = params["capsule"]
    fromto = " ".join(map(str, [*cap[0], *cap[1]]))
    xml = f"""<mujoco><worldbody>
      <geom name="robot" type="capsule" fromto="{fromto}" size="{cap[2]}"/>
      {params["other"]}
    </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    return m, d


@pytest.mark.parametrize("seed", range(6))
def test_capsule_distances_agree_with_mujoco(seed):
    """Our analytic distances equal MuJoCo's mj_geomDistance (separated shapes)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(0, 0.1, 3)
    b = a + rng.normal(0, 0.2, 3)
    r = 0.04
    c = rng.normal(0, 0.1, 3) + np.array([0.5, 0.0, 0.0])
    h = rng.uniform(0.05, 0.15, 3)
    quat = Rotation.random(random_state=seed).as_quat(scalar_first=True)
    other = (
        f'<geom name="ob" type="box" pos="{" ".join(map(str, c))}" '
        f'quat="{" ".join(map(str, quat))}" size="{" ".join(map(str, h))}"/>'
    )
    m, d = _mujoco_pair("box", {"capsule": (a, b, r), "other": other})
    fromto = np.zeros(6)
    ref = mujoco.mj_geomDistance(m, d, 0, 1, 10.0, fromto)
    box = Box(c, h, d.geom_xmat[1].reshape(3, 3))
    ours = capsule_obstacle_distances(a[None], b[None], np.array([r]), [box]).sd[0, 0]
    assert ref > 0
    assert ours == pytest.approx(ref, abs=1e-5)
    other = f'<geom name="ob" type="sphere" pos="{" ".join(map(str, c))}" size="0.07"/>'
    m, d = _mujoco_pair("sphere", {"capsule": (a, b, r), "other": other})
    ref = mujoco.mj_geomDistance(m, d, 0, 1, 10.0, fromto)
    ours = capsule_obstacle_distances(a[None], b[None], np.array([r]), [Sphere(c, 0.07)]).sd[0, 0]
    assert ours == pytest.approx(ref, abs=1e-6)


def test_penetration_is_negative():
    box = Box([0, 0, 0], [0.1, 0.1, 0.1])
    res = capsule_obstacle_distances(
        np.array([[-0.3, 0.0, 0.05]]), np.array([[0.3, 0.0, 0.05]]), np.array([0.02]), [box]
    )
    # Axis runs 5 cm inside the box; deepest point is 5 cm from the top face.
    assert res.sd[0, 0] == pytest.approx(-0.05 - 0.02, abs=1e-9)
    np.testing.assert_allclose(res.normal[0, 0], [0, 0, 1], atol=1e-12)


def test_bad_obstacles_raise_value_error():
    with pytest.raises(ValueError):
        Sphere([0, 0, np.nan], 0.1)
    with pytest.raises(InvalidParameterError):
        Box([0, 0, 0], [0.1, -0.1, 0.1])


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: Sphere([0, 0, 0], -0.1), r"sphere radius must be >= 0.0, got -0.1"),
        (lambda: Sphere([0, 0, 0], np.nan), r"sphere radius .* got nan"),
        (lambda: Sphere([0, 0, 0], True), r"sphere radius must be a number, got True"),
        (lambda: Capsule([0, 0, 0], [0, 0, 1], -1e-3), r"capsule radius must be >= 0.0"),
        (lambda: Box([0, 0, 0], [0.1] * 3, np.diag([1.0, 1.0, -1.0])), r"det \+1"),
        (lambda: Box([0, 0, 0], [0.1] * 3, np.eye(2)), r"box rotation must be 3x3"),
        (lambda: Box([0, 0, 0], [0.1] * 3, np.full((3, 3), np.nan)), r"box rotation"),
    ],
)
def test_bad_obstacle_parameters_are_refused(make, match):
    with pytest.raises(InvalidParameterError, match=match):
        make()


def test_zero_radius_obstacles_are_a_point_and_a_segment():
    """Radius 0 is geometry the distances take: a point, a segment (the sphere and capsule
    of radius r are those plus r)."""
    a, b = np.array([[-0.3, 0.0, 0.0]]), np.array([[0.3, 0.0, 0.0]])
    point, seg = Sphere([0.0, 0.2, 0.0], 0.0), Capsule([0, 0.5, -1], [0, 0.5, 1], 0.0)
    sd = capsule_obstacle_distances(a, b, [0.05], [point, seg]).sd
    np.testing.assert_allclose(sd.ravel(), [0.2 - 0.05, 0.5 - 0.05], atol=1e-12)


def test_degenerate_capsule_is_a_sphere():
    """A capsule with a == b is allowed: it is the sphere of its radius."""
    a = np.array([[-0.3, 0.0, 0.0]])
    b = np.array([[0.3, 0.0, 0.0]])
    cap = Capsule([0.1, 0.2, 0.0], [0.1, 0.2, 0.0], 0.05)
    sph = Sphere([0.1, 0.2, 0.0], 0.05)
    sd = capsule_obstacle_distances(a, b, [0.02], [cap, sph]).sd
    assert sd[0, 0] == pytest.approx(sd[0, 1], abs=1e-12)
    assert sd[0, 0] == pytest.approx(0.2 - 0.07, abs=1e-12)


@pytest.mark.parametrize("bad", [None, "x", 3.0, np.zeros(3)])
def test_non_obstacle_entries_are_refused(bad):
    """No uninitialised memory for entries that are not obstacles: a clear error instead."""
    obs = [Sphere([0, 0, 2], 0.1), bad]
    with pytest.raises(InvalidParameterError, match=r"obstacles\[1\] must be a Sphere, Box or"):
        capsule_obstacle_distances(np.zeros((1, 3)), np.ones((1, 3)), [0.05], obs)


def test_obstacles_copy_the_callers_arrays():
    """A frozen obstacle does not move with the array it was built from (MjData's geom_xpos,
    a caller's buffer), and editing that array cannot undo the construction checks."""
    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body pos="0 0 1"><freejoint/>'
        '<geom type="box" size=".1 .1 .1"/></body></worldbody></mujoco>'
    )
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    box = obstacle_from_mujoco_geom(int(m.geom_type[0]), d.geom_xpos[0], d.geom_xmat[0],
                                    m.geom_size[0])  # fmt: skip
    for _ in range(50):
        mujoco.mj_step(m, d)  # the body falls
    assert d.geom_xpos[0, 2] < 0.99
    np.testing.assert_array_equal(box.center, [0.0, 0.0, 1.0])

    h, R, c, v = np.full(3, 0.1), np.eye(3), np.zeros(3), np.zeros(3)
    b = Box(c, h, R, v)
    s = Sphere(c, 0.1, velocity=v)
    cap = Capsule(c, c + 1.0, 0.1, velocity=v)
    h[0], R[0, 0], c[:], v[:] = -1.0, 5.0, 7.0, 9.0
    np.testing.assert_array_equal(b.half_extents, [0.1, 0.1, 0.1])
    np.testing.assert_array_equal(b.rotation, np.eye(3))
    for vec in (b.center, b.velocity, s.center, s.velocity, cap.a, cap.velocity):
        np.testing.assert_array_equal(vec, [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(cap.b, [1.0, 1.0, 1.0])
