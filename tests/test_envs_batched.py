"""Pour-v0's batched step: the scale reading from the solver's reaction, the collision check
over all worlds, the per-world noise, the memory check before allocation and the solver's
pose table."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import pourbench  # noqa: F401  (registers the ids)
from pourbench.envs.core import PourBatch, estimate_memory
from pourbench.envs.observation import counter_normals
from pourbench.envs.pour_v0 import PourEnv
from pourbench.envs.vector import PourVectorEnv
from pourbench.errors import CapacityError
from pourbench.geometry.rotation import warp_transforms
from pourbench.scene import body_clearance


def test_scale_reading_is_the_mujoco_force_sensor_of_the_same_scene() -> None:
    """Liquid settled in the receiving tray: the env's noise-free reading (the solver's
    reaction on the tray) equals what MuJoCo's scale sensor reads when that reaction is
    applied to the tray, within 0.1 g, and both weigh the grams in the tray within 1 %."""
    env = PourEnv(liquid="water")
    env.reset(seed=0)
    batch = env.unwrapped.batch
    batch.solver.fill(0, batch.recv_col[0], 80.0)
    batch.flush()
    for _ in range(15):  # 1.5 s upright: the tray's liquid settles
        _, _, _, _, info = env.step(np.zeros(2))
    model = batch.model
    data = batch.world_data(0)
    body = model.body("receiving").id
    adr = int(model.sensor("scale_force").adr[0])
    tare = data.sensordata[adr + 2]
    force, torque = batch.solver.body_wrenches()
    slot = batch.recv_slot[0]
    data.xfrc_applied[body, :3], data.xfrc_applied[body, 3:] = force[slot], torque[slot]
    mujoco.mj_forward(model, data)
    sensor_g = (data.sensordata[adr + 2] - tare) / 9.81 * 1e3
    assert batch.weight_g_true(0) == pytest.approx(sensor_g, abs=0.1)
    assert info["poured_g"] > 75.0
    assert batch.weight_g_true(0) == pytest.approx(info["poured_g"], rel=0.01)


def test_collision_flags_equal_mujoco_clearance_per_world() -> None:
    """The batched overlap check (bounding spheres over all worlds, exact distances where
    they overlap) gives body_clearance's verdict in each world, near and far from the tray."""
    venv = PourVectorEnv(24, container_set="training", workers=1)
    venv.reset(seed=5)
    batch = venv.batch
    rng = np.random.default_rng(1)
    for _ in range(3):
        batch.base[:] = (
            batch.target_pos
            + np.c_[
                rng.uniform(-0.2, 0.05, 24),
                rng.uniform(-0.05, 0.05, 24),
                rng.uniform(-0.02, 0.1, 24),
            ]
        )
        batch.tilt[:] = rng.uniform(0.0, 2.0, 24)
        got = batch.collided()
        want = [
            body_clearance(
                batch.model,
                batch.world_data(w),
                batch.body_names[batch.worlds[w].container],
                "receiving",
            )
            < 0.0
            for w in range(24)
        ]
        np.testing.assert_array_equal(got, want)
    assert 0 < sum(want) < 24  # both verdicts were checked


def test_counter_normals_are_standard_and_reproducible() -> None:
    key = np.full(200_000, 12345, np.uint64)
    count = np.arange(200_000, dtype=np.uint64)
    z = counter_normals(key, count)
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1.0) < 0.01
    assert abs(np.mean(z[1:] * z[:-1])) < 0.01  # consecutive draws uncorrelated
    np.testing.assert_array_equal(z[::7], counter_normals(key[::7], count[::7]))
    other = counter_normals(key + np.uint64(1), count)
    assert abs(np.corrcoef(z, other)[0, 1]) < 0.01


def test_a_num_envs_too_large_is_refused_before_anything_is_allocated() -> None:
    host, device = estimate_memory(10**9)
    assert host + device > 2**50  # a petabyte: no machine has it free
    with pytest.raises(CapacityError, match=r"num_envs=1000000000 does not fit: about .* GiB"):
        gym.make_vec("pourbench/Pour-v0", num_envs=10**9, vectorization_mode="vector_entry_point")
    with pytest.raises(CapacityError, match="GiB"):
        PourBatch(10**9)


def test_sb3_env_checker() -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env

    check_env(PourEnv(max_steps=10), warn=True)


def test_collider_poses_are_rows_of_one_table_written_by_index() -> None:
    """``set_collider_poses`` writes rows of the solver's pose table (an index array or a
    list), each collider's ``pose``/``com`` reads its row (also after the table grew), the
    device gets the rows in its collider order, and a bad index changes nothing."""
    from pourbench.errors import InvalidParameterError
    from pourbench.fluids.solver import PBFSolver
    from pourbench.geometry.shapes import BoxShell

    s = PBFSolver(3)
    for w in (2, 0, 1):  # added out of world order: the device groups them by world
        for _ in range(3):  # 9 colliders: the table grows twice
            s.add_container(w, BoxShell(0.02, 0.02, 0.05, 0.005))
    s.fill(0, 3, 5.0)
    poses = np.tile([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], (9, 1))
    poses[:, 0] = np.arange(9) * 0.01
    s.set_collider_poses(np.arange(9)[::-1], poses[::-1], com=poses[::-1, :3])
    s.set_collider_poses([4], poses[[4]] + [0, 0, 0.5, 0, 0, 0, 0])
    expected = poses.copy()
    expected[4, 2] = 0.5
    for i, c in enumerate(s.colliders):
        np.testing.assert_array_equal(c.pose, expected[i])
        np.testing.assert_array_equal(c.com, poses[i, :3])
    with pytest.raises(InvalidParameterError, match=r"collider 9 not in \[0, 9\)"):
        s.set_collider_poses(np.array([0, 9]), poses[:2] + 1.0)
    np.testing.assert_array_equal([c.pose for c in s.colliders], expected)
    s.step()
    device = s.buf.cols.pose.numpy()
    order = [3, 4, 5, 6, 7, 8, 0, 1, 2]  # worlds 0, 1, 2
    np.testing.assert_array_equal(device, warp_transforms(expected[order]))
