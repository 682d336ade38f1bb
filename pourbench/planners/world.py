"""MuJoCo-side planning world: a robot with its obstacles as geoms, for distance queries.

NMPC-MP uses the analytic distances of :mod:`pourbench.planners.distance`; everything else —
mink's collision-avoidance limit, the OMPL validity checker and the benchmark's clearance and
collision measurements — asks MuJoCo (``mj_geomDistance``) on this model. Obstacles live on
mocap bodies so moving ones are updated without recompiling.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from pourbench.errors import InvalidParameterError, UnknownNameError, check_array, check_positive
from pourbench.geometry.rotation import quat_z_to
from pourbench.planners.distance import Box, Capsule, Obstacle, Sphere, check_obstacles
from pourbench.planners.kinematics import check_vector

COLLISION_BIT = 1 << 4
"""contype/conaffinity bit given to planner geoms in the world copy (for mink's pair filter;
the world model is only used for kinematics and distance queries, never stepped)."""


def _geom(ob: Obstacle) -> tuple[mujoco.mjtGeom, list[float]]:
    """MuJoCo geom type and size of an obstacle (a capsule with a == b is a sphere).

    Raises:
        InvalidParameterError: a sphere or capsule of radius 0 (MuJoCo has no such geom;
            the distance functions of :mod:`~pourbench.planners.distance` take them).
    """
    if isinstance(ob, Sphere | Capsule) and ob.radius <= 0.0:
        raise InvalidParameterError(
            f"a PlanningWorld obstacle needs a radius > 0 (a MuJoCo geom), got {ob!r}"
        )
    if isinstance(ob, Sphere):
        return mujoco.mjtGeom.mjGEOM_SPHERE, [ob.radius, 0.0, 0.0]
    if isinstance(ob, Box):
        return mujoco.mjtGeom.mjGEOM_BOX, [float(h) for h in ob.half_extents]
    half = 0.5 * float(np.linalg.norm(ob.b - ob.a))
    if half == 0.0:  # MuJoCo needs a positive half-length
        return mujoco.mjtGeom.mjGEOM_SPHERE, [ob.radius, 0.0, 0.0]
    return mujoco.mjtGeom.mjGEOM_CAPSULE, [ob.radius, half, 0.0]


def _pose(ob: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(ob, Sphere):
        return ob.center, np.array([1.0, 0, 0, 0])
    if isinstance(ob, Box):
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, ob.rotation.reshape(-1))
        return ob.center, q
    return 0.5 * (ob.a + ob.b), quat_z_to(ob.b - ob.a)


class PlanningWorld:
    """A robot model plus obstacle geoms.

    Args:
        spec: a fresh MjSpec of the robot (it is modified).
        robot_geoms: the planned arm's collision geoms.
        obstacles: obstacle primitives, added as geoms on mocap bodies ``obstacle_<i>``.
        static_geoms: more geoms of the robot that count as obstacles (body boxes, the other
            arm's capsules).
        base_qpos: full configuration for joints not being changed (default: keyframe
            ``home`` or ``qpos0``).

    A capsule obstacle with ``a == b`` is a sphere and is added as a sphere geom.

    Raises:
        UnknownNameError: a geom name is missing from the robot.
        InvalidParameterError: an obstacle is not a Sphere, Box or Capsule, or ``base_qpos``
            is not ``nq`` finite numbers.
    """

    def __init__(
        self,
        spec: mujoco.MjSpec,
        robot_geoms: Sequence[str],
        obstacles: Sequence[Obstacle] = (),
        static_geoms: Sequence[str] = (),
        base_qpos: np.ndarray | None = None,
    ) -> None:
        obstacles = check_obstacles(obstacles)
        names = {g.name for g in spec.geoms}
        for g in (*robot_geoms, *static_geoms):
            if g not in names:
                raise UnknownNameError("geom", g, sorted(n for n in names if n))
        for g in spec.geoms:
            if g.name in robot_geoms or g.name in static_geoms:
                g.contype = COLLISION_BIT
                g.conaffinity = COLLISION_BIT
        self._kinds = []
        for i, ob in enumerate(obstacles):
            pos, quat = _pose(ob)
            body = spec.worldbody.add_body(name=f"obstacle_{i}", mocap=True, pos=pos, quat=quat)
            gtype, size = _geom(ob)
            body.add_geom(
                name=f"obstacle_{i}",
                type=gtype,
                size=size,
                contype=COLLISION_BIT,
                conaffinity=COLLISION_BIT,
                group=3,
                rgba=[0.9, 0.3, 0.2, 0.6],
            )
            self._kinds.append(type(ob))
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        gid = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)  # noqa: E731
        self.robot_geom_ids = [gid(g) for g in robot_geoms]
        self.obstacle_geom_ids = [gid(f"obstacle_{i}") for i in range(len(obstacles))]
        self.static_geom_ids = [gid(g) for g in static_geoms]
        self._sizes = [tuple(float(v) for v in m.geom_size[g]) for g in self.obstacle_geom_ids]
        self.mocap_ids = [
            m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"obstacle_{i}")]
            for i in range(len(obstacles))
        ]
        if base_qpos is None:
            key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
            base_qpos = m.key_qpos[key] if key >= 0 else m.qpos0
        self.data.qpos[:] = check_array("base_qpos", base_qpos, (m.nq,))
        self._place(obstacles)
        self._fromto = np.zeros(6)

    @property
    def obstacle_geoms(self) -> list[int]:
        """Geom ids that count as obstacles (added primitives and static robot geoms)."""
        return self.obstacle_geom_ids + self.static_geom_ids

    def set_obstacles(self, obstacles: Sequence[Obstacle]) -> None:
        """Move the obstacle bodies to the poses of ``obstacles`` (same count and kinds).

        Raises:
            InvalidParameterError: the count, a kind or a size differs from construction (no
                obstacle is moved then).
        """
        obstacles = check_obstacles(obstacles)
        if len(obstacles) != len(self.mocap_ids):
            raise InvalidParameterError(
                f"world has {len(self.mocap_ids)} obstacles, got {len(obstacles)}"
            )
        for i, ob in enumerate(obstacles):
            if not isinstance(ob, self._kinds[i]):
                raise InvalidParameterError(
                    f"obstacles[{i}] must stay a {self._kinds[i].__name__}, got {ob!r}"
                )
            size = self._sizes[i]  # plain floats: this runs every control step
            if max(abs(a - b) for a, b in zip(_geom(ob)[1], size, strict=True)) > 1e-9:
                raise InvalidParameterError(
                    f"obstacles[{i}] must keep its size (MuJoCo geom size {list(size)}); "
                    f"got {ob!r}: build a new PlanningWorld for other sizes"
                )
        self._place(obstacles)

    def _place(self, obstacles: Sequence[Obstacle]) -> None:
        for i, ob in enumerate(obstacles):
            pos, quat = _pose(ob)
            self.data.mocap_pos[self.mocap_ids[i]] = pos
            self.data.mocap_quat[self.mocap_ids[i]] = quat

    def set_qpos(self, qpos: np.ndarray) -> None:
        """Set the full configuration and update kinematics.

        Raises:
            InvalidParameterError: ``qpos`` is not ``nq`` finite numbers (nothing changes).
        """
        self.data.qpos[:] = check_array("qpos", qpos, (self.model.nq,))
        mujoco.mj_kinematics(self.model, self.data)

    def clearance(self, qpos: np.ndarray | None = None, distmax: float = 1.0) -> float:
        """Smallest signed distance (m) between the arm's geoms and every obstacle geom,
        by ``mj_geomDistance``; ``distmax`` when nothing is closer, ``inf`` with no obstacle.

        Raises:
            InvalidParameterError: ``qpos`` is not ``nq`` finite numbers, or ``distmax`` is
                not finite and > 0 (nothing changes).
        """
        if qpos is not None:
            qpos = check_vector("qpos", qpos, self.model.nq)
        if distmax != 1.0:  # the default needs no check (this runs in OMPL's inner loop)
            check_positive("distmax", distmax)
        if not self.obstacle_geoms or not self.robot_geom_ids:
            return float("inf")
        if qpos is not None:
            self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        best = distmax
        for a in self.robot_geom_ids:
            for b in self.obstacle_geoms:
                d = mujoco.mj_geomDistance(self.model, self.data, a, b, distmax, self._fromto)
                best = min(best, d)
        return float(best)
