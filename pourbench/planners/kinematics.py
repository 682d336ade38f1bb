"""MuJoCo kinematics of one arm for the planners.

Everything here comes from MuJoCo itself (``mj_kinematics``, ``mj_comPos``, ``mj_jacSite``,
``mj_jacBody``); no forward kinematics is re-derived by hand. An :class:`ArmKinematics` picks
the arm's joints, its end-effector site and its collision capsules out of any ``MjModel`` and
evaluates them at one configuration or at a batch of configurations (a predicted horizon).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from pourbench.errors import InvalidParameterError, PourbenchError, UnknownNameError, check_array

_CAPSULE_TYPES = (int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_CYLINDER))
_JOINT_TYPES = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


@dataclass(frozen=True)
class ArmState:
    """Kinematic quantities of an arm at ``T`` configurations (leading axis ``T``).

    Attributes:
        q: joint positions, (T, n) in rad.
        ee_pos: end-effector site position, (T, 3) in m (world frame).
        ee_quat: end-effector orientation quaternion (w, x, y, z), (T, 4).
        jac_pos: translational Jacobian of the site, (T, 3, n) in m/rad.
        jac_rot: rotational Jacobian (world-frame angular velocity), (T, 3, n) in 1/rad·rad.
        seg_a: first end point of each collision capsule's axis, (T, K, 3) in m.
        seg_b: second end point, (T, K, 3) in m.
        radius: capsule radii, (K,) in m.
        body_pos: origin of the body each capsule is fixed to, (T, K, 3) in m.
        body_jacp: translational Jacobian at that origin, (T, K, 3, n).
        body_jacr: rotational Jacobian of that body, (T, K, 3, n).
    """

    q: np.ndarray
    ee_pos: np.ndarray
    ee_quat: np.ndarray
    jac_pos: np.ndarray
    jac_rot: np.ndarray
    seg_a: np.ndarray
    seg_b: np.ndarray
    radius: np.ndarray
    body_pos: np.ndarray
    body_jacp: np.ndarray
    body_jacr: np.ndarray


_F64 = np.dtype(np.float64)


def check_vector(name: str, value: object, n: int) -> np.ndarray:
    """``value`` as ``n`` finite floats, like :func:`~pourbench.errors.check_array` but with a
    fast path for a float64 array of the right shape (OMPL's validity checker calls this for
    every state it samples)."""
    if (
        type(value) is np.ndarray
        and value.dtype is _F64
        and value.shape == (n,)
        and math.isfinite(sum(value.tolist()))  # cheaper than numpy's sum for a few values
    ):
        return value
    return check_array(name, value, (n,))


def joint_speeds(value: object, n: int | None = None) -> np.ndarray:
    """``max_joint_speed`` (rad/s) as finite numbers > 0: one number or one per joint; with
    ``n`` (the arm's joints) broadcast to ``n`` values.

    Raises:
        InvalidParameterError: not numbers, not one value or one per joint, not finite or
            not > 0.
    """
    try:
        s = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"max_joint_speed must be numbers, got {value!r}") from exc
    if s.ndim > 1 or s.size == 0 or (n is not None and s.size not in (1, n)):
        want = "a number or one per joint" if n is None else f"one number or {n} (one per joint)"
        raise InvalidParameterError(f"max_joint_speed must be {want}, got {value!r}")
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise InvalidParameterError(f"max_joint_speed must be finite and > 0, got {value!r}")
    return s if n is None else np.broadcast_to(s.reshape(-1), (n,)).copy()


def point_jacobian(
    body_pos: np.ndarray, body_jacp: np.ndarray, body_jacr: np.ndarray, point: np.ndarray
) -> np.ndarray:
    """Translational Jacobian of a point rigidly attached to a body.

    Uses v_p = v_o + ω × (p − o). Shapes broadcast over leading axes.

    Args:
        body_pos: body origin o, (..., 3) in m.
        body_jacp: Jacobian of o, (..., 3, n).
        body_jacr: rotational Jacobian, (..., 3, n).
        point: the point p, (..., 3) in m.

    Returns:
        (..., 3, n) Jacobian of p in m/rad.
    """
    r = point - body_pos
    # (ω × r) = −(r × ω); column-wise cross product of r with each column of jacr.
    cross = np.cross(r[..., None, :], np.swapaxes(body_jacr, -1, -2))  # (..., n, 3)
    return body_jacp - np.swapaxes(cross, -1, -2)


class ArmKinematics:
    """One arm of a MuJoCo model: joints, end-effector site and collision capsules.

    Joints that are not part of the arm stay at ``base_qpos`` (the ``home`` keyframe when the
    model has one, else ``qpos0``).

    Args:
        joint_names: the arm's hinge or slide joints, in planning order.
        ee_site: name of the end-effector site.
        collision_geoms: names of capsule or cylinder geoms that represent the arm for
            collision checking (cylinders are treated as capsules, a conservative cover).
        base_qpos: full ``qpos`` used for every joint that is not planned.

    Raises:
        UnknownNameError: a joint, site or geom name is not in the model.
        PourbenchError: a joint is not 1-DoF or a geom is not a capsule or cylinder.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        joint_names: Sequence[str],
        ee_site: str,
        collision_geoms: Sequence[str] = (),
        base_qpos: np.ndarray | None = None,
    ) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.joint_names = tuple(joint_names)
        jids = [self._id(mujoco.mjtObj.mjOBJ_JOINT, "joint", j) for j in self.joint_names]
        for name, jid in zip(self.joint_names, jids, strict=True):
            if int(model.jnt_type[jid]) not in _JOINT_TYPES:
                raise PourbenchError(f"joint {name!r} is not a hinge or slide joint")
        self.qadr = np.array([model.jnt_qposadr[j] for j in jids], dtype=int)
        self.dadr = np.array([model.jnt_dofadr[j] for j in jids], dtype=int)
        limited = np.array([bool(model.jnt_limited[j]) for j in jids])
        rng = np.array([model.jnt_range[j] for j in jids], dtype=float)
        self.lower = np.where(limited, rng[:, 0], -np.inf)
        self.upper = np.where(limited, rng[:, 1], np.inf)
        self.ee_site = ee_site
        self.site_id = self._id(mujoco.mjtObj.mjOBJ_SITE, "site", ee_site)
        self.collision_geoms = tuple(collision_geoms)
        self.geom_ids = np.array(
            [self._id(mujoco.mjtObj.mjOBJ_GEOM, "geom", g) for g in self.collision_geoms],
            dtype=int,
        )
        for name, gid in zip(self.collision_geoms, self.geom_ids, strict=True):
            if int(model.geom_type[gid]) not in _CAPSULE_TYPES:
                raise PourbenchError(f"collision geom {name!r} must be a capsule or cylinder")
        self.geom_body = np.asarray(model.geom_bodyid[self.geom_ids], dtype=int)
        self.radius = model.geom_size[self.geom_ids, 0].copy()
        self.half_length = model.geom_size[self.geom_ids, 1].copy()
        if base_qpos is None:
            key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
            base_qpos = model.key_qpos[key] if key >= 0 else model.qpos0
        self.base_qpos = check_array("base_qpos", base_qpos, (model.nq,)).copy()
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))

    def _id(self, obj: mujoco.mjtObj, kind: str, name: str) -> int:
        i = mujoco.mj_name2id(self.model, obj, name)
        if i < 0:
            count = {"joint": self.model.njnt, "site": self.model.nsite, "geom": self.model.ngeom}
            known = [mujoco.mj_id2name(self.model, obj, k) for k in range(count[kind])]
            raise UnknownNameError(kind, name, [k for k in known if k])
        return i

    @property
    def n(self) -> int:
        """Number of planned joints."""
        return len(self.qadr)

    @property
    def num_capsules(self) -> int:
        """Number of collision capsules K."""
        return len(self.geom_ids)

    def home(self) -> np.ndarray:
        """The arm's joint positions in ``base_qpos`` (rad)."""
        return self.base_qpos[self.qadr].copy()

    def set_base_qpos(self, qpos: np.ndarray) -> None:
        """Replace the configuration of the joints that are not planned (full ``qpos``).

        Raises:
            InvalidParameterError: ``qpos`` is not ``nq`` finite numbers (nothing changes).
        """
        self.base_qpos = check_array("base_qpos", qpos, (self.model.nq,)).copy()

    def full_qpos(self, q: np.ndarray) -> np.ndarray:
        """Full model ``qpos`` with the arm at ``q`` and everything else at ``base_qpos``.

        Raises:
            InvalidParameterError: ``q`` is not ``n`` finite numbers.
        """
        q = check_vector("q", q, self.n)
        qpos = self.base_qpos.copy()
        qpos[self.qadr] = q
        return qpos

    def forward(self, q: np.ndarray) -> ArmState:
        """Kinematics at one configuration ``q`` (n,); arrays keep a leading axis of 1.

        Raises:
            InvalidParameterError: ``q`` is not ``n`` finite numbers.
        """
        return self.forward_many(check_array("q", q, (self.n,))[None, :])

    def forward_many(self, qs: np.ndarray, jacobians: bool = True) -> ArmState:
        """Kinematics at ``T`` configurations ``qs`` (T, n).

        With ``jacobians=False`` the Jacobian arrays are left zero (faster; poses only).

        Raises:
            InvalidParameterError: ``qs`` has the wrong shape or is not finite.
        """
        qs = check_array("configurations", qs, (None, self.n))
        m, d = self.model, self.data
        T, n, K = qs.shape[0], self.n, self.num_capsules
        ee_pos = np.empty((T, 3))
        ee_quat = np.empty((T, 4))
        jac_pos = np.zeros((T, 3, n))
        jac_rot = np.zeros((T, 3, n))
        body_pos = np.empty((T, K, 3))
        body_jacp = np.zeros((T, K, 3, n))
        body_jacr = np.zeros((T, K, 3, n))
        d.qpos[:] = self.base_qpos
        gids, bids = self.geom_ids, self.geom_body
        gpos = np.empty((T, K, 3))
        gaxis = np.empty((T, K, 3))
        jacp, jacr, dadr = self._jacp, self._jacr, self.dadr
        for t in range(T):
            d.qpos[self.qadr] = qs[t]
            mujoco.mj_kinematics(m, d)
            ee_pos[t] = d.site_xpos[self.site_id]
            mujoco.mju_mat2Quat(ee_quat[t], d.site_xmat[self.site_id])
            if K:
                gpos[t] = d.geom_xpos[gids]
                gaxis[t] = d.geom_xmat[gids][:, 2::3]  # z axis: third column of row-major xmat
                body_pos[t] = d.xpos[bids]
            if jacobians:
                mujoco.mj_comPos(m, d)
                mujoco.mj_jacSite(m, d, jacp, jacr, self.site_id)
                jac_pos[t] = jacp[:, dadr]
                jac_rot[t] = jacr[:, dadr]
                for k in range(K):
                    mujoco.mj_jacBody(m, d, jacp, jacr, bids[k])
                    body_jacp[t, k] = jacp[:, dadr]
                    body_jacr[t, k] = jacr[:, dadr]
        half = self.half_length[None, :, None]
        seg_a = gpos - half * gaxis
        seg_b = gpos + half * gaxis
        return ArmState(
            q=qs.copy(),
            ee_pos=ee_pos,
            ee_quat=ee_quat,
            jac_pos=jac_pos,
            jac_rot=jac_rot,
            seg_a=seg_a,
            seg_b=seg_b,
            radius=self.radius,
            body_pos=body_pos,
            body_jacp=body_jacp,
            body_jacr=body_jacr,
        )

    def ee_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End-effector position (m) and quaternion (w, x, y, z) at ``q``."""
        s = self.forward(q)
        return s.ee_pos[0].copy(), s.ee_quat[0].copy()
