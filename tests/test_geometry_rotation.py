"""The rotation module against MuJoCo's quaternion routines and Warp's transforms."""

from __future__ import annotations

import mujoco
import numpy as np
import warp as wp

from pourbench.geometry.rotation import (
    axis_angle_quat,
    inverse_transform_points,
    quat_conj,
    quat_mul,
    quat_rotate,
    quat_to_matrix,
    quat_z_to,
    rotation_error,
    transform_points,
    warp_transforms,
)


def _unit_quats(n: int, seed: int) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_products_matrices_and_rotations_agree_with_mujoco() -> None:
    a, b = _unit_quats(20, 0), _unit_quats(20, 1)
    v = np.random.default_rng(2).normal(size=(20, 3))
    for k in range(20):
        ab, mat, rv = np.zeros(4), np.zeros(9), np.zeros(3)
        mujoco.mju_mulQuat(ab, a[k], b[k])
        mujoco.mju_quat2Mat(mat, a[k])
        mujoco.mju_rotVecQuat(rv, v[k], a[k])
        np.testing.assert_allclose(quat_mul(a[k], b[k]), ab, atol=1e-15)
        np.testing.assert_allclose(quat_to_matrix(a[k]), mat.reshape(3, 3), atol=1e-15)
        np.testing.assert_allclose(quat_rotate(a[k], v[k]), rv, atol=1e-14)
    np.testing.assert_allclose(quat_mul(a, b)[3], quat_mul(a[3], b[3]), atol=0)  # batched
    identity = np.tile([1.0, 0, 0, 0], (20, 1))
    np.testing.assert_allclose(quat_mul(a, quat_conj(a)), identity, atol=1e-15)


def test_axis_angles_and_alignments() -> None:
    q = axis_angle_quat(np.array([0.0, 1.0, 0.0]), np.pi / 2)
    np.testing.assert_allclose(quat_rotate(q, [1.0, 0.0, 0.0]), [0.0, 0.0, -1.0], atol=1e-15)
    assert np.isclose(rotation_error(q, [1.0, 0.0, 0.0, 0.0]), np.pi / 2, atol=1e-12)
    for axis in ([1.0, 2.0, -0.5], [0.0, 0.0, -3.0], [0.0, 0.0, 2.0]):
        unit = np.asarray(axis) / np.linalg.norm(axis)
        np.testing.assert_allclose(quat_rotate(quat_z_to(axis), [0, 0, 1.0]), unit, atol=1e-15)


def test_poses_round_trip_and_match_warp_transforms() -> None:
    """A pose (x, y, z, qw, qx, qy, qz) moves points as the Warp transform it converts to."""
    poses = np.concatenate([np.random.default_rng(3).normal(size=(5, 3)), _unit_quats(5, 4)], 1)
    pts = np.random.default_rng(5).normal(size=(5, 3))
    world = transform_points(poses, pts)
    np.testing.assert_allclose(inverse_transform_points(poses, world), pts, atol=1e-14)
    tf = warp_transforms(poses)
    for k in range(5):
        tf_k = wp.transform(wp.vec3(*tf[k, :3]), wp.quat(*tf[k, 3:]))
        moved = wp.transform_point(tf_k, wp.vec3(*pts[k]))
        np.testing.assert_allclose(np.array(moved), world[k], atol=1e-5)
