"""Implicit viscosity (pourbench.fluids.viscosity): the closed-form wall tensor, the linear
system the conjugate-gradient solve states, and what the viscous terms must keep."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sps
import scipy.sparse.linalg as spla
import warp as wp
from scipy.integrate import quad
from scipy.spatial import cKDTree

from pourbench.errors import InvalidParameterError
from pourbench.fluids import viscosity as V
from pourbench.fluids.config import SolverConfig
from pourbench.fluids.params import liquid_profile
from pourbench.fluids.solver import PBFSolver
from pourbench.fluids.validation import (
    REDUCED_SCORR_SPREAD,
    SETTLING_TOLERANCE,
    SETTLING_VISCOSITIES,
    falling_ball,
    newtonian,
    settling_sphere,
)
from pourbench.geometry.shapes import cup


@wp.kernel
def _eval_wall_tensor(
    d: wp.array(dtype=float),
    kappa: wp.array(dtype=float),
    h: float,
    d_min: float,
    out: wp.array(dtype=wp.vec2),
):
    i = wp.tid()
    out[i] = V.wall_tensor(d[i], kappa[i], h, d_min)


def _wall_tensors(ds: np.ndarray, kappas: np.ndarray, h: float) -> np.ndarray:
    out = wp.zeros(len(ds), dtype=wp.vec2, device="cpu")
    args = [wp.array(ds, dtype=float), wp.array(kappas, dtype=float), h, 0.0]
    wp.launch(_eval_wall_tensor, len(ds), args, [out], device="cpu")
    return out.numpy()


def test_wall_tensor_is_the_mirrored_half_space_integral() -> None:
    """(T_n, T_t) is the Laplacian's kernel integral over the solid beyond a plane wall at
    distance d, each solid point's relative velocity extrapolated linearly from the particle's
    (×(z/d), z the point's distance along the normal): checked against quadrature of that
    definition over the half-space in spherical shells."""
    h = 0.01
    ds = np.array([0.1, 0.25, 0.5, 0.75, 0.95]) * h
    got = _wall_tensors(ds, np.zeros_like(ds), h)
    gcoef = 10.0 * 45.0 / (math.pi * h**6)  # 2(d+2) · the spiky gradient's constant
    for d, (tn, tt) in zip(ds, got, strict=True):

        def shell(r: float, part: str, d: float = d) -> float:
            # ∫ over the cap cos θ > d/r of the sphere of radius r: (z/d) ĉ-weights, dΩ r²
            def integrand(c: float) -> float:
                w = c * c if part == "n" else 0.5 * (1.0 - c * c)  # n̂n̂ or one tangent axis
                return (r * c / d) * w * 2.0 * math.pi

            return quad(integrand, d / r, 1.0)[0] * gcoef * (h - r) ** 2 / r * r * r

        want_n = quad(lambda r: shell(r, "n"), d, h)[0]
        want_t = quad(lambda r: shell(r, "t"), d, h)[0]
        assert tn == pytest.approx(want_n, rel=2e-4)
        assert tt == pytest.approx(want_t, rel=2e-4)


@pytest.mark.parametrize("radius", [0.015, 0.006, -0.03])
def test_curved_wall_tensor_is_the_integral_over_the_sphere(radius: float) -> None:
    """Beside a sphere of radius R (a convex solid, or a spherical cavity for R < 0) the wall
    tensor is the same kernel integral over the solid the sphere holds, each solid point's
    relative velocity extrapolated by its depth δ below the surface (×(d + δ)/d): checked
    against a midpoint sum over a grid of h/120 cells in the particle's frame. A plane's
    tensor is the limit of a huge sphere's."""
    h = 0.01
    ds = np.array([0.15, 0.5, 0.85]) * h
    got = _wall_tensors(ds, np.full(len(ds), 1.0 / radius), h)
    cell = h / 120.0
    ax = (np.arange(240) - 119.5) * cell
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    r = np.sqrt(x * x + y * y + z * z)
    gcoef = 10.0 * 45.0 / (math.pi * h**6)
    for d, (tn, tt) in zip(ds, got, strict=True):
        rho = np.sqrt(x * x + y * y + (z - (d + radius)) ** 2)  # z: the wall normal
        depth = abs(radius) - rho if radius > 0 else rho - abs(radius)
        inside = (r < h) & (depth > 0.0)
        w = gcoef * (h - r[inside]) ** 2 / r[inside] * (d + depth[inside]) / d * cell**3
        r2 = r[inside] ** 2
        assert tn == pytest.approx(np.sum(w * z[inside] ** 2 / r2), rel=5e-3)
        assert tt == pytest.approx(np.sum(w * x[inside] ** 2 / r2), rel=5e-3)
    huge = _wall_tensors(ds, np.full(len(ds), 1e-4), h)
    plane = _wall_tensors(ds, np.zeros(len(ds)), h)
    np.testing.assert_allclose(huge, plane, rtol=1e-3)


def _settled_cup(mu: float, omega: float = 2.0, device: str = "cpu") -> tuple[PBFSolver, object]:
    """Water-like liquid of viscosity ``mu`` settled 0.5 s in a 3 cm cup, then set spinning
    about the cup's axis at ``omega`` rad/s."""
    s = PBFSolver(1, SolverConfig(xsph_viscosity=0.0, device=device))
    shape = cup(0.03, 0.075, wall=0.006)
    c = s.add_container(0, shape)
    s.set_liquid(0, newtonian(mu))
    s.fill(0, c, 1000.0 * math.pi * 0.03**2 * 0.045 * 1e3, newtonian(mu))
    s.step(120)
    x = s.positions()
    spin = np.stack([-omega * x[:, 1], omega * x[:, 0], 0.0 * x[:, 0]], axis=1)
    s.clear_world(0)
    s.add_particles(0, x, spin)
    return s, shape


def _system(s: PBFSolver) -> sps.csr_matrix:
    """The system matrix A = I + c (K + T) the solve states (module docstring), assembled
    from the particles' end-of-step positions and their wall records."""
    visc = s.viscosity
    x = s.buf.x.numpy().astype(float)
    n, h = len(x), s.config.h
    pairs = cKDTree(x).query_pairs(h, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    r = x[i] - x[j]
    d = np.linalg.norm(r, axis=1)
    g = visc.coef * (h - d) ** 2 * d / (d * d + 0.01 * h * h)
    rh = r / d[:, None]
    block = g[:, None, None] * rh[:, :, None] * rh[:, None, :]
    wall_n = s.buf.wall.numpy()[:, :3].astype(float)
    wt = visc.wall_t.numpy().astype(float)
    t_block = wt[:, 1, None, None] * np.eye(3) + (wt[:, 0] - wt[:, 1])[:, None, None] * (
        wall_n[:, :, None] * wall_n[:, None, :]
    )
    rows, cols, vals = [], [], []
    for a, b, m in ((i, i, block), (j, j, block), (i, j, -block), (j, i, -block)):
        for p in range(3):
            for q in range(3):
                rows.append(3 * a + p)
                cols.append(3 * b + q)
                vals.append(m[:, p, q])
    k = sps.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n)
    )
    c = float(visc.c_w.numpy()[0])
    return sps.identity(3 * n) + c * (k + sps.block_diag(list(t_block)))


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.gpu, id="cuda")])
def test_the_solve_is_the_linear_system_it_states(device: str) -> None:
    """After a step of a spinning viscous liquid (0.5 Pa·s) in a cup, the velocities the
    conjugate-gradient solve returns solve A v' = v + c T v_wall (the cup is still: v_wall =
    0) to its tolerance: within 0.1 % of a sparse direct solve. On CUDA too."""
    s, _ = _settled_cup(0.5, device=device)
    s.step()
    visc = s.viscosity
    assert np.abs(visc.v_wall.numpy()).max() < 1e-4  # the cup does not move
    direct = spla.spsolve(_system(s).tocsc(), visc.rhs.numpy().astype(float).ravel())
    got = visc.sol.numpy().astype(float).ravel()
    assert np.linalg.norm(got - direct) <= 1e-3 * np.linalg.norm(direct)
    assert 1 <= visc.iterations.numpy()[0] < s.config.viscosity_max_iterations


def test_viscosity_keeps_momentum_and_spares_rigid_motion() -> None:
    """A free blob in zero gravity, its particles 1.2 spacings apart and no tensile term (no
    position correction, so the solve starts from the given field), solved to 1e-6: the solve
    keeps the liquid's momentum and angular momentum, leaves a translation as it is, takes
    less than 1 % of a rotation's kinetic energy (the pairs turn by ω dt over the step), and
    over 40 % of a random field's."""
    cfg = SolverConfig(
        gravity=(0.0, 0.0, 0.0), scorr_k=0.0, viscosity_tolerance=1e-6, xsph_viscosity=0.0
    )
    g = np.arange(8) * 1.2 * cfg.spacing
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    centre = x.mean(axis=0)
    fields = {  # the field at given positions
        "translation": lambda p: np.broadcast_to([0.02, -0.01, 0.03], p.shape),
        "rotation": lambda p: np.cross([0.5, -1.0, 2.0], p - centre),
        "random": lambda p: np.random.default_rng(3).normal(0.0, 0.05, p.shape),
    }
    kept = {}
    for name, field in fields.items():
        s = PBFSolver(1, cfg)
        s.set_liquid(0, newtonian(2.0))
        s.add_particles(0, x, field(x))
        s.step()
        visc = s.viscosity
        xe = s.buf.x.numpy().astype(float)
        before, after = visc.rhs.numpy().astype(float), visc.sol.numpy().astype(float)
        if name != "random":  # no correction moved them (particles are reordered: x_prev)
            np.testing.assert_allclose(before, field(s.buf.x_prev.numpy()), atol=1e-6)
        scale = np.abs(before).sum()
        assert np.abs(after.sum(0) - before.sum(0)).max() < 1e-5 * scale
        arm = xe - xe.mean(0)
        turn = np.cross(arm, after).sum(0) - np.cross(arm, before).sum(0)
        assert np.abs(turn).max() < 1e-5 * scale * np.ptp(xe)
        kept[name] = (after**2).sum() / (before**2).sum()
    assert kept["translation"] == pytest.approx(1.0, abs=1e-6)
    assert 0.99 < kept["rotation"] <= 1.0
    assert kept["random"] < 0.6


@pytest.mark.parametrize(
    "change, match",
    [
        ({"viscosity_pa_s": -1.0}, "viscosity_pa_s must be positive, got -1.0"),
        ({"viscosity_pa_s": float("nan")}, "viscosity_pa_s must be finite, got nan"),
        ({"viscosity_cp": 1.0, "viscosity_pa_s": 0.5}, "viscosity_cp 1.0 .* viscosity_pa_s 0.5"),
    ],
)
def test_a_bad_viscosity_is_refused(change: dict, match: str) -> None:
    with pytest.raises(InvalidParameterError, match=match):
        liquid_profile("water").replace(**change)


def test_centipoise_alone_sets_the_viscosity_in_pa_s() -> None:
    water = liquid_profile("water").replace(viscosity_pa_s=None, viscosity_cp=3.0)
    assert water.viscosity_pa_s == pytest.approx(0.003)


LIGHT_SPHERE_MUS = (10.0, 50.0)


@pytest.fixture(scope="module")
def light_sphere() -> tuple[np.ndarray, np.ndarray]:
    """A 1 cm glass sphere (35 g) on a slide joint, released on the axis of a 3 cm cup of
    liquid of each of :data:`LIGHT_SPHERE_MUS`: its sinking speed over 0.4 s (steps, worlds)
    and the closed form's (Stokes with the cylinder's Haberman–Sayre factor)."""
    import mujoco

    from pourbench.fluids.coupling import MujocoCoupling
    from pourbench.fluids.falling_ball import terminal_speed

    radius, bore, depth = 0.01, 0.03, 0.06
    cfg = SolverConfig(xsph_viscosity=0.0)
    shape = cup(bore, depth + 4 * radius, wall=0.01)
    z0 = shape.bottom_z + depth - radius - 0.005
    mass = 2500.0 * 4.0 / 3.0 * math.pi * radius**3
    model = mujoco.MjModel.from_xml_string(
        f"""<mujoco><option timestep="{cfg.dt!r}"/><worldbody>
        <body pos="0 0 {z0!r}"><joint type="slide" axis="0 0 1"/>
        <geom name="ball" type="sphere" size="{radius!r}" mass="{mass!r}"/></body>
        </worldbody></mujoco>"""
    )
    datas = [mujoco.MjData(model) for _ in LIGHT_SPHERE_MUS]
    s = PBFSolver(len(LIGHT_SPHERE_MUS), cfg)
    coupling = MujocoCoupling(s, model, datas)
    coupling.add_geoms(["ball"])
    for w, mu in enumerate(LIGHT_SPHERE_MUS):
        s.set_liquid(w, newtonian(mu))
        liquid_g = 1000.0 * (math.pi * bore**2 * depth - 4.0 / 3.0 * math.pi * radius**3) * 1e3
        s.fill(w, s.add_container(w, shape), liquid_g)
    for _ in range(120):  # settle 0.5 s, MuJoCo standing still: the sphere is held
        coupling.sync()
        s.step()
        coupling.apply()
    sink = []
    for _ in range(96):  # 0.4 s released
        coupling.step()
        sink.append([-d.qvel[0] for d in datas])
    closed = [terminal_speed(mu, 1000.0, radius, 2500.0, bore)[0] for mu in LIGHT_SPHERE_MUS]
    return np.array(sink), np.array(closed)


def test_a_light_sphere_in_a_thick_liquid_sinks_steadily(light_sphere) -> None:
    """Its viscous drag b, applied a step late, would overshoot (b dt / m about 1.5 and 7.5
    at 10 and 50 Pa·s); integrated implicitly (MujocoCoupling), the sphere sinks and never
    rises, and never faster than Stokes' speed in an unbounded liquid."""
    sink, _ = light_sphere
    assert sink.min() > 0.0, sink.min(axis=0)
    unbounded = 2.0 / 9.0 * 1500.0 * 9.81 * 0.01**2 / np.array(LIGHT_SPHERE_MUS)
    assert np.all(sink.max(axis=0) < unbounded), (sink.max(axis=0), unbounded)


@pytest.mark.xfail(
    strict=True,
    reason="in 10 Pa·s it sinks at 0.63 of the closed form over the last 0.1 s: the settled "
    "packing's resistance around a moving body (docs/viscosity.md)",
)
def test_a_light_sphere_in_a_thick_liquid_sinks_at_the_closed_form(light_sphere) -> None:
    """In 10 Pa·s at the closed form's speed within 25 % over the last 0.1 s."""
    sink, closed = light_sphere
    assert sink[-24:, 0].mean() == pytest.approx(closed[0], rel=0.25)


def test_a_column_too_short_to_reach_the_terminal_speed_is_refused() -> None:
    """In 0.1 Pa·s the sphere needs 11 cm of fall to reach 98 % of its terminal speed
    (``falling_ball.startup_fall``): a 14 cm column leaves no stretch after it to time, and
    ``falling_ball`` says so before it runs."""
    with pytest.raises(InvalidParameterError, match="too short"):
        falling_ball([newtonian(0.1)], depth=0.14, startup=0.98)


PLAIN_SETTLING_MUS = (0.1, 0.5, 5.0)
"""Pa·s: the settling runs of the density solve as shipped; 50 Pa·s, a run of 14.5 s of its
own, is left to ``pourbench bench fluids``."""


@pytest.fixture(scope="module")
def settling_plain() -> list:
    """The settling sphere (``validation.settling_sphere``) in a Newtonian liquid of each of
    :data:`PLAIN_SETTLING_MUS`, FleX terms and XSPH off, the density solve as shipped."""
    return settling_sphere(PLAIN_SETTLING_MUS, config=SolverConfig(xsph_viscosity=0.0))


@pytest.mark.slow
def test_a_settling_sphere_falls_slower_the_thicker_the_liquid(settling_plain) -> None:
    """From 0.1 to 5 Pa·s the sphere reaches a terminal speed, and a lower one in each
    thicker liquid."""
    terminal = [r.terminal for r in settling_plain]
    assert np.all(np.isfinite(terminal)) and np.all(np.diff(terminal) < 0), terminal


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="without the corrected pressure the sphere falls at 0.50 / 0.70 / 0.50 of the "
    "closed form at 0.1 / 0.5 / 5 Pa·s and slows as it goes deeper: the settled packing "
    "resists a moving body with a stress that grows with the pressure (docs/viscosity.md, "
    "'Settling sphere')",
)
def test_a_settling_sphere_meets_the_closed_form_without_the_correction(settling_plain) -> None:
    """Its terminal speed is Stokes' law with the cylinder's Haberman–Sayre factor and the
    Schiller–Naumann term within :data:`SETTLING_TOLERANCE` at each viscosity."""
    ratios = {
        mu: r.terminal / r.closed_form
        for mu, r in zip(PLAIN_SETTLING_MUS, settling_plain, strict=True)
    }
    assert all(abs(r - 1.0) <= SETTLING_TOLERANCE for r in ratios.values()), ratios


SHIPPED_SPACING, FINER_SPACING = 0.005, 0.004
"""m: the liquid's spacing as shipped, and the finer one the settling sphere is checked at."""


@pytest.fixture(scope="module")
def settling_corrected() -> dict[float, dict[float, float]]:
    """The settling sphere in a Newtonian liquid of each of :data:`SETTLING_VISCOSITIES`
    with ``corrected_pressure``, at the shipped spacing and a finer one: {spacing: {μ:
    terminal speed over the closed form}}."""
    out = {}
    for spacing in (SHIPPED_SPACING, FINER_SPACING):
        config = SolverConfig(xsph_viscosity=0.0, corrected_pressure=True, spacing=spacing)
        results = settling_sphere(SETTLING_VISCOSITIES, config=config)
        out[spacing] = {
            mu: r.terminal / r.closed_form
            for mu, r in zip(SETTLING_VISCOSITIES, results, strict=True)
        }
    return out


@pytest.mark.slow
def test_with_the_corrected_pressure_the_sphere_settles_at_the_closed_form(
    settling_corrected,
) -> None:
    """``corrected_pressure`` takes the settled packing's pressure-set resistance off the
    sphere: at the finer spacing its terminal speed is the closed form's within
    :data:`SETTLING_TOLERANCE` over four decades of viscosity, and at the shipped spacing
    from 0.1 to 5 Pa·s (docs/viscosity.md, "Settling sphere")."""
    finer, shipped = settling_corrected[FINER_SPACING], settling_corrected[SHIPPED_SPACING]
    assert all(abs(r - 1.0) <= SETTLING_TOLERANCE for r in finer.values()), finer
    thinner = {mu: r for mu, r in shipped.items() if mu <= 5.0}
    assert all(abs(r - 1.0) <= SETTLING_TOLERANCE for r in thinner.values()), shipped


@pytest.mark.slow
def test_in_the_stokes_regime_the_corrected_sphere_nears_the_closed_form_as_the_spacing_shrinks(
    settling_corrected,
) -> None:
    """At 5 and 50 Pa·s (Re < 1, where the closed form is sharp) the sphere's shortfall
    shrinks with the spacing: smaller at 4 mm than at 5 mm."""
    for mu in (5.0, 50.0):
        finer = abs(settling_corrected[FINER_SPACING][mu] - 1.0)
        shipped = abs(settling_corrected[SHIPPED_SPACING][mu] - 1.0)
        assert finer < shipped, (mu, settling_corrected)


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="at 50 Pa·s and the shipped 5 mm the sphere falls at 0.70 of the closed form and "
    "slows as it goes deeper: part of the packing's pressure-set resistance is left, and a "
    "shortfall that shrinks with the spacing (docs/viscosity.md, 'Settling sphere')",
)
def test_at_the_shipped_spacing_the_sphere_settles_at_the_closed_form_in_50_pa_s(
    settling_corrected,
) -> None:
    """The shipped spacing's terminal speed at 50 Pa·s within :data:`SETTLING_TOLERANCE`."""
    ratio = settling_corrected[SHIPPED_SPACING][50.0]
    assert abs(ratio - 1.0) <= SETTLING_TOLERANCE, ratio


@pytest.mark.slow
def test_with_less_tensile_spread_the_stokes_sphere_nears_its_closed_form() -> None:
    """At 5 Pa·s and the shipped spacing (Re < 1), with ``corrected_pressure`` and
    ``bulk_scorr_spread`` at :data:`REDUCED_SCORR_SPREAD`, the sphere's terminal speed is
    within half of :data:`SETTLING_TOLERANCE` of the closed form (docs/viscosity.md, "The
    bulk's tensile term", has the term as shipped beside it)."""
    config = SolverConfig(
        xsph_viscosity=0.0, corrected_pressure=True, bulk_scorr_spread=REDUCED_SCORR_SPREAD
    )
    (ball,) = settling_sphere([5.0], config=config)
    ratio = ball.terminal / ball.closed_form
    assert abs(ratio - 1.0) <= SETTLING_TOLERANCE / 2, ratio


@pytest.mark.slow
def test_with_less_tensile_spread_the_shipped_spacing_settles_at_the_closed_form() -> None:
    """The settling sphere of ``bench fluids`` with ``corrected_pressure`` and
    ``bulk_scorr_spread`` at :data:`REDUCED_SCORR_SPREAD`, at the shipped spacing: its terminal
    speed is the closed form's within :data:`SETTLING_TOLERANCE` at each of
    :data:`SETTLING_VISCOSITIES`, 50 Pa·s included, where the correction alone falls short
    (docs/viscosity.md, "The bulk's tensile term", gives its numbers and its cost)."""
    config = SolverConfig(
        xsph_viscosity=0.0, corrected_pressure=True, bulk_scorr_spread=REDUCED_SCORR_SPREAD
    )
    results = settling_sphere(SETTLING_VISCOSITIES, config=config)
    ratios = {
        mu: r.terminal / r.closed_form for mu, r in zip(SETTLING_VISCOSITIES, results, strict=True)
    }
    assert all(abs(r - 1.0) <= SETTLING_TOLERANCE for r in ratios.values()), ratios


def _swirled(liquids: list[str], threshold: float) -> np.ndarray:
    """Each world's cup of 150 g of ``liquids[w]``, swirled for 20 steps at Pour-v0's
    resolution with ``min_viscous_diffusion`` = ``threshold``: world 0's velocities."""
    cfg = SolverConfig(spacing=0.008, dt=1.0 / 120.0, iterations=3, min_viscous_diffusion=threshold)
    s = PBFSolver(len(liquids), cfg)
    for w, liquid in enumerate(liquids):
        s.fill(w, s.add_container(w, cup(0.04, 0.1)), 150.0, liquid)
    x = s.positions()[s.world_slice(0)]
    s.clear_world(0)
    swirl = np.zeros_like(x)
    swirl[:, :2] = np.stack([-x[:, 1], x[:, 0]], 1) * 20.0  # a rigid swirl of 20 rad/s
    s.add_particles(0, x, swirl)
    s.step(20)
    return s.velocities()[s.world_slice(0)]


def test_a_liquid_below_the_diffusion_threshold_takes_no_viscosity_solve() -> None:
    """ν dt / h² per world is its closed form, and 0 below ``min_viscous_diffusion``. A
    skipped world moves otherwise than when it is solved (oil at thresholds 1e-2 and 0), the
    same alone or beside a solved liquid. Water at Pour-v0's resolution is under the
    threshold Pour-v0 sets, and its solve moves no particle by a bit: skipping it loses
    nothing."""
    cfg = SolverConfig(spacing=0.008, dt=1.0 / 120.0, min_viscous_diffusion=1e-3)
    s = PBFSolver(3, cfg)
    for w, liquid in enumerate(("water", "oil", "honey")):
        s.set_liquid(w, liquid)
    expected = [
        liquid_profile(n).viscosity_pa_s / liquid_profile(n).density * cfg.dt / cfg.h**2
        for n in ("water", "oil", "honey")
    ]
    assert expected[0] < 1e-4 and expected[1] > 1e-3  # water under Pour-v0's threshold
    assert s.viscous_diffusion() == pytest.approx([0.0, expected[1], expected[2]])
    skipped = _swirled(["oil"], 1e-2)
    assert np.array_equal(skipped, _swirled(["oil", "honey"], 1e-2))
    assert not np.allclose(skipped, _swirled(["oil"], 0.0), atol=1e-4)
    assert np.array_equal(_swirled(["water"], 1e-3), _swirled(["water"], 0.0))
