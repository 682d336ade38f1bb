"""Online differential-IK baseline with mink (it stands where the thesis used RelaxedIK),
and mink IK for the joint-space goals of the offline planners.

Uses the real library: a ``FrameTask`` on the end-effector site, a small ``PostureTask``,
``ConfigurationLimit``, ``VelocityLimit`` and ``CollisionAvoidanceLimit`` between the arm's
capsules and every obstacle geom of a :class:`~pourbench.planners.world.PlanningWorld`, and a
``DofFreezingTask`` constraint on every joint that is not the planned arm's.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import mink
import mujoco
import numpy as np

from pourbench.errors import (
    InvalidParameterError,
    UnknownNameError,
    check_array,
    check_finite,
    check_int,
    check_positive,
    check_quat,
)
from pourbench.geometry.rotation import rotation_error
from pourbench.planners.distance import Obstacle
from pourbench.planners.kinematics import joint_speeds
from pourbench.planners.world import PlanningWorld


@dataclass
class MinkResult:
    """One mink control step: ``u`` (n,) rad/s, wall ``solve_time_s`` (s), ``iterations`` (IK
    solves)."""

    u: np.ndarray
    solve_time_s: float
    iterations: int = 1


def _check_names(m: mujoco.MjModel, obj, kind: str, names: Sequence[str], count: int) -> None:
    for name in names:
        if not isinstance(name, str) or mujoco.mj_name2id(m, obj, name) < 0:
            known = [mujoco.mj_id2name(m, obj, i) for i in range(count)]
            raise UnknownNameError(kind, name, [k for k in known if k])


class MinkController:
    """mink differential IK with collision avoidance, configuration and velocity limits.

    Args:
        world: the robot with its obstacles (MuJoCo geoms).
        joints: the planned arm's joints.
        robot_geoms: the arm's collision geoms.
        ts: control period (s).
        safety_distance: minimum distance kept by the collision-avoidance limit (m).
        max_joint_speed: joint-speed bounds (rad/s), one per joint.
        orientation_cost: FrameTask orientation cost relative to position cost 1.
        posture_cost: PostureTask cost (regularises the null space).
        base_qpos: full configuration of the joints that are not planned.
        substeps: IK steps per control period (each ``ts / substeps`` long).

    Raises:
        UnknownNameError: a joint, the site or a robot geom is not in the world's model.
        InvalidParameterError: a NaN, negative or wrongly shaped setting.
    """

    def __init__(
        self,
        world: PlanningWorld,
        joints: Sequence[str],
        ee_site: str,
        robot_geoms: Sequence[str],
        *,
        ts: float,
        safety_distance: float,
        max_joint_speed: np.ndarray,
        orientation_cost: float = 0.5,
        posture_cost: float = 1e-3,
        base_qpos: np.ndarray | None = None,
        substeps: int = 4,
    ) -> None:
        m = world.model
        joints = tuple(joints)
        robot_geoms = tuple(robot_geoms)
        if not joints:
            raise InvalidParameterError("joints must name at least one joint, got none")
        _check_names(m, mujoco.mjtObj.mjOBJ_JOINT, "joint", joints, m.njnt)
        _check_names(m, mujoco.mjtObj.mjOBJ_SITE, "site", (ee_site,), m.nsite)
        _check_names(m, mujoco.mjtObj.mjOBJ_GEOM, "geom", robot_geoms, m.ngeom)
        check_positive("ts", ts)
        substeps = check_int("substeps", substeps, minimum=1)
        check_finite("safety_distance", safety_distance, minimum=0.0)
        check_finite("orientation_cost", orientation_cost, minimum=0.0)
        check_finite("posture_cost", posture_cost, minimum=0.0)
        speeds = joint_speeds(max_joint_speed, len(joints))
        base = world.data.qpos if base_qpos is None else base_qpos
        base = check_array("base_qpos", base, (m.nq,))
        self.world = world
        self.ts = ts
        self.substeps = int(substeps)
        self.safety_distance = safety_distance
        self.config = mink.Configuration(m)
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints]
        self.qadr = np.array([m.jnt_qposadr[j] for j in jids])
        self.dadr = np.array([m.jnt_dofadr[j] for j in jids])
        self.base_qpos = np.array(base, float)
        self.frame = mink.FrameTask(ee_site, "site", position_cost=1.0,
                                    orientation_cost=orientation_cost, lm_damping=1e-3)  # fmt: skip
        self.posture = mink.PostureTask(m, cost=posture_cost)
        self.posture.set_target(self.base_qpos)
        frozen = [d for d in range(m.nv) if d not in set(self.dadr.tolist())]
        self.constraints = [mink.DofFreezingTask(m, dof_indices=frozen)] if frozen else []
        obstacle_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
                          for g in world.obstacle_geoms]  # fmt: skip
        self.limits: list = [
            mink.ConfigurationLimit(m),
            mink.VelocityLimit(m, {j: float(s) for j, s in zip(joints, speeds, strict=True)}),
        ]
        if obstacle_names:
            self.limits.append(
                mink.CollisionAvoidanceLimit(
                    m,
                    [(list(robot_geoms), obstacle_names)],
                    minimum_distance_from_collisions=safety_distance,
                    collision_detection_distance=safety_distance + 0.3,
                )
            )

    def _check_goal(self, q0, goal_pos, goal_quat) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(self.qadr)
        q0 = check_array("q0", q0, (n,))
        goal_pos = check_array("goal_pos", goal_pos, (3,))
        return q0, goal_pos, check_quat("goal_quat", goal_quat)

    def _qpos(self, q: np.ndarray) -> np.ndarray:
        qpos = self.base_qpos.copy()
        qpos[self.qadr] = q
        return qpos

    def _velocity(self, q, goal_pos, goal_quat, dt: float, collisions: bool = True) -> np.ndarray:
        # mink's Configuration owns its MjData: give it the world's obstacle (mocap) poses.
        self.config.data.mocap_pos[:] = self.world.data.mocap_pos
        self.config.data.mocap_quat[:] = self.world.data.mocap_quat
        self.config.update(self._qpos(q))
        target = mink.SE3.from_rotation_and_translation(
            mink.SO3(np.asarray(goal_quat, float) / np.linalg.norm(goal_quat)),
            np.asarray(goal_pos, float),
        )
        self.frame.set_target(target)
        v = mink.solve_ik(
            self.config,
            [self.frame, self.posture],
            dt,
            solver="proxqp",
            damping=1e-3,
            limits=self.limits if collisions else self.limits[:2],
            constraints=self.constraints,
        )
        return v[self.dadr]

    def plan(
        self,
        q0: np.ndarray,
        goal_pos: np.ndarray,
        goal_quat: np.ndarray,
        obstacles: Sequence[Obstacle] = (),
    ) -> MinkResult:
        """One control step: joint velocities (rad/s) to apply for ``ts`` seconds.

        Raises:
            InvalidParameterError: NaN or wrongly shaped ``q0`` or goal, a zero goal
                quaternion, or obstacles that differ from the world's.
        """
        t0 = time.perf_counter()
        q0, goal_pos, goal_quat = self._check_goal(q0, goal_pos, goal_quat)
        self.world.set_obstacles(obstacles)
        # Differential IK is a fast-rate method: integrate ``substeps`` IK steps over the
        # control period and return their mean velocity (so q + u·t_s is where they end).
        q = np.asarray(q0, float).copy()
        dt = self.ts / self.substeps
        for _ in range(self.substeps):
            q = q + self._velocity(q, goal_pos, goal_quat, dt) * dt
        u = (q - np.asarray(q0, float)) / self.ts
        return MinkResult(u=u, solve_time_s=time.perf_counter() - t0, iterations=self.substeps)

    def solve_ik(
        self,
        q0: np.ndarray,
        goal_pos: np.ndarray,
        goal_quat: np.ndarray,
        *,
        max_iters: int = 400,
        dt: float = 0.05,
        pos_tol: float = 1e-3,
        rot_tol: float = 1e-2,
    ) -> tuple[np.ndarray, bool]:
        """Iterated mink IK from ``q0`` to a configuration at the goal pose.

        First without the collision limit (so obstacles between start and goal do not trap
        the iteration); if that configuration is closer than the safety distance to an
        obstacle, it is refined with the collision-avoidance limit on.

        Returns:
            (q, success): the last configuration (rad) and whether it meets the tolerances and
            keeps the safety distance.

        Raises:
            InvalidParameterError: NaN or wrongly shaped ``q0`` or goal, a zero goal
                quaternion, or a bad iteration setting.
        """
        q0, goal_pos, goal_quat = self._check_goal(q0, goal_pos, goal_quat)
        check_int("max_iters", max_iters, minimum=1)
        check_positive("dt", dt)
        check_finite("pos_tol", pos_tol, minimum=0.0)
        check_finite("rot_tol", rot_tol, minimum=0.0)
        site = self.frame.frame_name
        q = np.asarray(q0, float).copy()
        for collisions in (False, True):
            for _ in range(max_iters):
                q = q + self._velocity(q, goal_pos, goal_quat, dt, collisions) * dt
                self.config.update(self._qpos(q))
                pose = self.config.get_transform_frame_to_world(site, "site")
                p, xi = pose.translation(), pose.rotation().wxyz
                if (
                    np.linalg.norm(p - goal_pos) < pos_tol
                    and rotation_error(xi, goal_quat) < rot_tol
                ):
                    break
            else:
                continue
            if self.world.clearance(self._qpos(q)) >= self.safety_distance:
                return q, True
        return q, False
