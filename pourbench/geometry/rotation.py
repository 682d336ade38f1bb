"""Rotations of points by unit quaternions and rigid poses, in numpy."""

from __future__ import annotations

import numpy as np


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternion ``q`` = (x, y, z, w): one (4,) for
    every vector, or one per vector (..., 4)."""
    q = np.asarray(q, float)
    u, w = q[..., :3], q[..., 3:]
    v = np.asarray(v, float)
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def transform_points(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a (x, y, z, qx, qy, qz, qw) pose (or one per point, (..., 7)) to local points."""
    pose = np.asarray(pose, float)
    return quat_rotate(pose[..., 3:], pts) + pose[..., :3]


def inverse_transform_points(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """World points into the local frame of a (x, y, z, qx, qy, qz, qw) pose (or of one pose
    per point, (..., 7))."""
    pose = np.asarray(pose, float)
    qc = np.concatenate([-pose[..., 3:6], pose[..., 6:]], axis=-1)
    return quat_rotate(qc, np.asarray(pts, float) - pose[..., :3])
