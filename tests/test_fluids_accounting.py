"""The device-side liquid accounting (``fluids.accounting.LiquidCounter``) against the float64
cavity tests of the container shapes."""

from __future__ import annotations

import numpy as np

from pourbench.containers import container_names, get_container
from pourbench.fluids.accounting import LiquidCounter
from pourbench.fluids.solver import PBFSolver
from pourbench.geometry.rotation import inverse_transform_points
from pourbench.geometry.shapes import BoxShell


def _tilted(z: float, angle: float, x: float = 0.0) -> np.ndarray:
    """Pose at (x, 0, z) turned by ``angle`` (rad) about the y axis."""
    return np.array([x, 0.0, z, np.cos(angle / 2), 0.0, np.sin(angle / 2), 0.0])


def _expected(x, poses, shapes, margin):
    """Float64 counts: first container holding the particle, else spilled below the lowest
    rim, else in flight."""
    free = np.ones(len(x), bool)
    inside = []
    for pose, shape in zip(poses, shapes, strict=True):
        held = shape.contains(inverse_transform_points(pose, x), margin=margin) & free
        inside.append(int(held.sum()))
        free &= ~held
    level = min(p[2] + s.rim_height for p, s in zip(poses, shapes, strict=True))
    spilled = int((free & (x[:, 2] < level)).sum())
    return inside, spilled, int(free.sum()) - spilled


def test_counts_equal_the_shapes_own_cavity_tests_for_every_shipped_container() -> None:
    """Every shipped container (revolved profiles of several segments, tilted) and a closed
    and an open box, each with a receiving tray below it, in its own world: particles spread
    through and around both cavities count as the float64 ``contains`` tests count them,
    before the first step (host state) and after one (the device's own arrays)."""
    rng = np.random.default_rng(3)
    margin = 0.005
    tray = get_container("tray").shape if "tray" in container_names() else None
    tray = tray or BoxShell(0.1, 0.1, 0.03, 0.004)
    shapes = [get_container(n).shape for n in container_names()]
    shapes += [BoxShell(0.03, 0.02, 0.05, 0.003), BoxShell(0.03, 0.02, 0.05, 0.003, closed=True)]
    s = PBFSolver(len(shapes))
    counter = LiquidCounter(s, [*shapes, tray], margin)
    poses = np.zeros((len(shapes), 2, 7))
    clouds = []
    for w, shape in enumerate(shapes):
        poses[w, 0] = _tilted(0.12, rng.uniform(0.0, 2.0), x=rng.uniform(-0.02, 0.02))
        poses[w, 1] = _tilted(0.0, 0.0)
        s.add_container(w, shape, pose=poses[w, 0])
        s.add_container(w, tray, pose=poses[w, 1])
        # a cloud over both containers and around them, as in a pour
        lo, hi = np.array([-0.15, -0.15, -0.02]), np.array([0.15, 0.15, 0.35])
        x = rng.uniform(lo, hi, (4000, 3)).astype(np.float32)
        s.add_particles(w, x)
        clouds.append(x.astype(float))
    index = np.stack([np.arange(len(shapes)), np.full(len(shapes), len(shapes))], 1)
    for stepped in (False, True):
        if stepped:  # the step moves the particles: read them back for the float64 tests
            s.step()
            x_all = s.positions().astype(float)
            clouds = [x_all[s.world_slice(w)] for w in range(len(shapes))]
        inside, spilled, flight = counter.count(np.arange(len(shapes)), poses, index)
        for w, shape in enumerate(shapes):
            want = _expected(clouds[w], poses[w], [shape, tray], margin)
            assert (list(inside[w]), spilled[w], flight[w]) == (want[0], want[1], want[2]), w
            assert inside[w].sum() + spilled[w] + flight[w] == len(clouds[w])
        assert inside[:, 0].min() > 0 and inside[:, 1].min() > 0 and spilled.min() > 0


def test_worlds_not_asked_for_are_not_counted_and_rows_follow_the_order_given() -> None:
    """Counting worlds (2, 0) of three: row 0 is world 2's, row 1 world 0's; world 1's
    particles count nowhere."""
    shape = get_container(container_names()[0]).shape
    s = PBFSolver(3)
    pose = _tilted(0.0, 0.0)
    for w, n in enumerate((5, 7, 11)):
        s.add_container(w, shape, pose=pose)
        s.add_particles(w, np.tile([0.0, 0.0, shape.bottom_z + 0.01], (n, 1)))
    counter = LiquidCounter(s, [shape], 0.0)
    inside, spilled, flight = counter.count(np.array([2, 0]), np.tile(pose, (2, 1, 1)), [[0], [0]])
    assert inside.tolist() == [[11], [5]]
    assert spilled.tolist() == [0, 0] and flight.tolist() == [0, 0]


def test_liquid_beside_the_containers_below_the_lowest_rim_is_spilled_however_deep() -> None:
    """A puddle on the table beside a tray (layers from the table up to just under the tray's
    rim) is spilled: it can no longer fall into a container; a drop above the rim, beside
    it, is in flight. The lowest rim is the tray's, not the raised cup's."""
    tray, cup = BoxShell(0.1, 0.1, 0.03, 0.004), BoxShell(0.03, 0.02, 0.05, 0.003)
    s = PBFSolver(1)
    poses = np.array([_tilted(0.2, 0.0), _tilted(0.0, 0.0)])
    s.add_container(0, cup, pose=poses[0])
    s.add_container(0, tray, pose=poses[1])
    d = s.config.spacing
    layers = np.arange(0.5 * d, tray.rim_height, d)  # resting on the table at z = 0
    puddle = np.stack([np.full(len(layers), 0.15), np.zeros(len(layers)), layers], 1)
    s.add_particles(0, [*puddle, [0.15, 0.0, tray.rim_height + d]])
    inside, spilled, flight = LiquidCounter(s, [cup, tray], 0.0).count([0], poses[None], [[0, 1]])
    assert len(layers) >= 4 and inside.sum() == 0
    assert (spilled[0], flight[0]) == (len(layers), 1)


def test_a_nan_particle_counts_in_flight() -> None:
    """A particle with a NaN position is in no cavity and not below the spill level: in
    flight, so the world's counts still add up to its particles."""
    shape = get_container(container_names()[0]).shape
    s = PBFSolver(1)
    pose = _tilted(0.0, 0.0)
    s.add_container(0, shape, pose=pose)
    s.add_particles(0, [[0.0, 0.0, shape.bottom_z + 0.01], [0.0, 0.0, 0.3], [0.5, 0, -1]])
    s.step()
    x = s.buf.x.numpy()  # the CPU array's own memory
    x[np.argmax(x[:, 2])] = np.nan  # the highest particle diverges
    inside, spilled, flight = LiquidCounter(s, [shape], 0.0).count([0], pose[None, None], [[0]])
    assert (inside[0, 0], spilled[0], flight[0]) == (1, 1, 1)


def test_the_env_measures_with_the_counter() -> None:
    """Pour-v0's accounting adds up to the liquid it was filled with, all of it in the pouring
    container at reset."""
    from pourbench.envs.core import PourBatch, PourConfig

    b = PourBatch(2, PourConfig(liquid="water"))
    for w in range(2):
        b.reset_world(w, seed=w)
    b.flush()
    m = b.measure()
    total = m["remaining_g"] + m["poured_g"] + m["spilled_g"] + m["in_flight_g"]
    np.testing.assert_allclose(total, m["initial_g"], atol=b.particle_g.max())
    assert np.all(m["remaining_g"] > 0.95 * m["initial_g"])
