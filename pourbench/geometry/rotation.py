"""Rotations and rigid poses, in numpy, in one convention: MuJoCo's.

A quaternion is (w, x, y, z), unit length; a pose is (x, y, z, qw, qx, qy, qz) in metres.
Every pourbench API takes and returns these. Warp's ``wp.transform`` stores the quaternion
scalar last: :func:`warp_transforms` converts at that boundary, the only place that does.

Written by hand, not with scipy's ``Rotation``: every function here is batched over leading
axes and runs each step on (worlds, colliders) or (particles,) arrays, where a ``Rotation``
object would be built per call and store the scalar last.
"""

from __future__ import annotations

import numpy as np

from pourbench.errors import InvalidParameterError


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternion ``q`` (w, x, y, z): one (4,) for
    every vector, or one per vector (..., 4)."""
    q = np.asarray(q, float)
    w, u = q[..., :1], q[..., 1:]
    v = np.asarray(v, float)
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_conj(q: np.ndarray) -> np.ndarray:
    """The conjugate (the inverse of a unit quaternion), (..., 4)."""
    q = np.asarray(q, float)
    return np.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of (..., 4) quaternions: rotate by ``b``, then by ``a``."""
    return np.einsum("...ij,...j->...i", quat_right_matrix(b), np.asarray(a, float))


def quat_right_matrix(b: np.ndarray) -> np.ndarray:
    """The (..., 4, 4) matrices R(b) with a ⊗ b = R(b) a, so that a stack of fixed right
    factors composes with one matrix product."""
    w, x, y, z = np.moveaxis(np.asarray(b, float), -1, 0)
    rows = [[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def axis_angle_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    """The rotation by ``angle`` (rad) about unit ``axis`` (3,)."""
    return np.r_[np.cos(angle / 2), np.sin(angle / 2) * np.asarray(axis, float)]


def quat_z_to(axis: np.ndarray) -> np.ndarray:
    """A unit quaternion rotating +z onto ``axis`` (3,); the identity for a zero axis."""
    norm = np.linalg.norm(axis)
    if norm == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    a = np.asarray(axis, float) / norm
    c = float(a[2])
    if c < -1.0 + 1e-12:
        return np.array([0.0, 1.0, 0.0, 0.0])
    q = np.array([1.0 + c, -a[1], a[0], 0.0])  # (1 + z·a, z × a), normalised
    return q / np.linalg.norm(q)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of (..., 4) unit quaternions."""
    q = np.asarray(q, float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rotation_error(quat: np.ndarray, goal_quat: np.ndarray) -> float:
    """Angle (rad) of the rotation between two unit quaternions (4,).

    Raises:
        InvalidParameterError: a quaternion holds NaN or inf (it would read as no error).
    """
    c = abs(float(np.dot(quat, goal_quat)))
    if not c <= 1e300:  # NaN (or inf): an unknown rotation, never "reached"
        raise InvalidParameterError(
            f"quaternions must be finite, got {np.asarray(quat).tolist()} and "
            f"{np.asarray(goal_quat).tolist()}"
        )
    return 2.0 * float(np.arccos(min(1.0, c)))


def transform_points(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a pose (7,) (or one per point, (..., 7)) to local points (..., 3)."""
    pose = np.asarray(pose, float)
    return quat_rotate(pose[..., 3:], pts) + pose[..., :3]


def inverse_transform_points(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """World points (..., 3) into the local frame of a pose (7,) (or of one per point)."""
    pose = np.asarray(pose, float)
    return quat_rotate(quat_conj(pose[..., 3:]), np.asarray(pts, float) - pose[..., :3])


def warp_transforms(poses: np.ndarray) -> np.ndarray:
    """Poses (..., 7) as float32 in ``wp.transform``'s layout (x, y, z, qx, qy, qz, qw)."""
    poses = np.asarray(poses)
    return np.concatenate([poses[..., :3], poses[..., 4:], poses[..., 3:4]], -1).astype(np.float32)
