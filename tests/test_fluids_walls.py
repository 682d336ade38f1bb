"""The density constraint's wall term (``kernels.wall_sum``) against quadrature of the kernel
over a solid sphere, a spherical cavity and a half-space, and the wall curvature that
``kernels.predict`` reads from a collider's SDF against the shapes' known curvatures."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from pourbench.fluids import kernels as K
from pourbench.fluids.config import SolverConfig
from pourbench.fluids.solver import PBFSolver
from pourbench.geometry.shapes import BoxShell, RevolvedShell

H = 0.01


@wp.kernel
def _wall_sums(
    d: wp.array(dtype=float), kappa: wp.array(dtype=float), h: float, out: wp.array(dtype=wp.vec2)
):
    i = wp.tid()
    out[i] = K.wall_sum(d[i], kappa[i], h, 1.0)


def wall_sums(d: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """``wall_sum`` (coef 1) at distances ``d`` (m) and curvatures ``kappa`` (1/m)."""
    out = wp.zeros(len(d), dtype=wp.vec2, device="cpu")
    wp.launch(
        _wall_sums,
        len(d),
        [wp.array(d, dtype=float, device="cpu"), wp.array(kappa, dtype=float), H],
        [out],
        device="cpu",
    )
    return out.numpy().astype(float)


def quadrature(d: float, radius: float) -> float:
    """(h − r)³ integrated over a solid sphere of ``radius`` (m; negative: a spherical cavity
    of that radius, the solid outside it; inf: a half-space) whose surface is ``d`` below a
    point, over 2π: each shell of radius r about the point holds the spherical cap the
    solid cuts from it."""
    r = np.linspace(d, H, 400001)
    if math.isinf(radius):
        cos = d / r
    else:
        centre = radius + d  # the solid's (or cavity's) centre, along the normal
        cos = (centre**2 + r**2 - radius**2) / (2 * centre * r)
    area = r * r * (1 - np.clip(cos, -1.0, 1.0))  # shell area inside the solid / 2π
    return float(np.trapezoid((H - r) ** 3 * area, r))


@pytest.mark.parametrize("radius", [math.inf, 0.05, 0.015, 0.006, -0.05, -0.02])
def test_wall_sum_is_the_kernel_over_a_sphere_of_the_walls_curvature(radius: float) -> None:
    """Exact for a sphere of curvature κ ≤ 2/h and a cavity of curvature ≥ −1/(2h); κ = 0 is
    the half-space, and the returned derivative is the sum's slope in d."""
    d = np.array([0.0005, 0.0025, 0.005, 0.0075, 0.0095])
    kappa = np.full(len(d), 0.0 if math.isinf(radius) else 1.0 / radius)
    got = wall_sums(d, kappa)
    want = [quadrature(x, radius) for x in d]
    np.testing.assert_allclose(got[:, 0], want, rtol=1e-3)
    step = 1e-5
    slope = (wall_sums(d + step, kappa)[:, 0] - wall_sums(d - step, kappa)[:, 0]) / (2 * step)
    np.testing.assert_allclose(got[:, 1], slope, rtol=2e-3, atol=1e-3 * abs(got[0, 1]))


def wall_curvatures(solver: PBFSolver, points: np.ndarray) -> np.ndarray:
    """The wall curvature ``predict`` records for particles at ``points`` (one step without
    gravity, so that the particles stay where they were put)."""
    solver.add_particles(0, points)
    solver.step()
    return solver.buf.wall.numpy()[:, 4].astype(float)


def test_the_wall_curvature_of_a_sphere_and_a_plane() -> None:
    """Around a sphere of radius R every particle within h of it reads 1/R, over a box's
    flat faces 0."""
    cfg = SolverConfig(gravity=(0.0, 0.0, 0.0), reorder_every=0)
    s = PBFSolver(1, cfg)
    radius = 0.02
    s.add_collider(0, "sphere", [radius])
    s.add_collider(0, "box", [0.03, 0.03, 0.01], pose=[0.0, 0.0, -0.2, 1.0, 0.0, 0.0, 0.0])
    rng = np.random.default_rng(0)
    u = rng.normal(size=(64, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    near_sphere = u * (radius + rng.uniform(0.002, 0.009, size=(64, 1)))
    over_box = np.column_stack(
        [rng.uniform(-0.02, 0.02, 16), rng.uniform(-0.02, 0.02, 16), np.full(16, -0.185)]
    )
    kappa = wall_curvatures(s, np.vstack([near_sphere, over_box]))
    np.testing.assert_allclose(kappa[:64], 1.0 / radius, rtol=0.005)
    np.testing.assert_allclose(kappa[64:], 0.0, atol=1e-6)


def test_the_wall_curvature_beside_a_capsule() -> None:
    """Beside a capsule's cylinder (radius R), d from it, the SDF's Laplacian is 1/(R + d),
    read as the sphere of the same Laplacian, κ = L/(2 − L d): within κd of the mean
    curvature 1/(2R) of a surface curved one way only."""
    cfg = SolverConfig(gravity=(0.0, 0.0, 0.0), reorder_every=0)
    s = PBFSolver(1, cfg)
    radius, d = 0.015, 0.004
    s.add_collider(0, "capsule", [radius, 0.05])
    angle = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    out = radius + d
    points = np.column_stack(
        [out * np.cos(angle), out * np.sin(angle), np.linspace(-0.04, 0.04, 24)]
    )
    lap = 1.0 / out
    np.testing.assert_allclose(wall_curvatures(s, points), lap / (2 - lap * d), rtol=0.005)


def test_shapes_with_edges_keep_the_plane() -> None:
    """Boxes, box shells and revolved containers read no curvature, even where their faces
    meet (a box's edge, a tank's corner, a cup's wall): their term is the half-space's."""
    cfg = SolverConfig(gravity=(0.0, 0.0, 0.0), reorder_every=0)
    s = PBFSolver(1, cfg)
    s.add_container(0, BoxShell(0.05, 0.05, 0.1, 0.01))
    s.add_collider(0, "box", [0.01, 0.01, 0.01], pose=[0.0, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0])
    rim = 0.04
    cup_pose = [0.3, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    s.add_container(0, RevolvedShell(((0.0, 0.0), (rim, 0.0), (rim, 0.12)), 0.004), pose=cup_pose)
    points = np.array(
        [
            [0.0, 0.045, 0.03],  # the tank's wall
            [0.046, 0.046, 0.03],  # its vertical corner
            [0.0, 0.0, 0.004],  # its floor
            [0.013, 0.013, 0.05],  # the box's vertical edge
            [0.0, 0.0, 0.064],  # its top face
            [0.3 + rim - 0.006, 0.0, 0.06],  # the cup's side wall
            [0.3 + rim - 0.006, 0.0, 0.006],  # its bottom corner
        ]
    )
    np.testing.assert_allclose(wall_curvatures(s, points), 0.0, atol=0.0)
