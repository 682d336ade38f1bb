"""Two-way coupling between a :class:`PBFSolver` and MuJoCo (one ``MjData`` per world).

Each step: MuJoCo advances its bodies (using the liquid's wrench of the previous step in
``xfrc_applied``), the colliders take the bodies' new poses, the fluid advances with swept
collisions from the old poses to the new ones, and the liquid's reaction on every coupled
body (summed in the collision kernels) is written to ``xfrc_applied`` for the next step. So
a MuJoCo force sensor under a container reads the liquid's weight and the stream's impacts.

That explicit exchange is unstable for a light body in a thick liquid: a drag b on a body of
mass m, applied a step late, overshoots once b dt / m > 2 (7.5 for a glass sphere of 1 cm
radius in 50 Pa·s). So :meth:`MujocoCoupling.step` integrates the viscous part of the drag
implicitly: with the solver's drag matrix B of each body (:meth:`PBFSolver.body_drag`, about
its CoM) and the body Jacobian J, MuJoCo's velocity change Δ over the step becomes the
solution of (M + dt Jᵀ B J) Δ' = M Δ (M the joint-space inertia), and the positions follow
the changed velocities. Where the liquid's reaction already balances the body's other forces
(Δ = 0: at rest, at terminal speed) nothing changes; a change of speed is spread over the
liquid the body drags along.
Hand-written: MuJoCo integrates its own damping implicitly, but not a wrench applied from
outside.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import warp as wp

from pourbench.errors import InvalidParameterError, check_array, check_index, check_int
from pourbench.fluids import kernels as K
from pourbench.fluids.colliders import shape_kind
from pourbench.fluids.meshes import convex_hull
from pourbench.fluids.solver import PBFSolver
from pourbench.geometry.rotation import quat_right_matrix
from pourbench.geometry.shapes import ContainerShape

_GEOM_KIND = {
    mujoco.mjtGeom.mjGEOM_PLANE: "plane",
    mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
    mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule",
    mujoco.mjtGeom.mjGEOM_CYLINDER: "cylinder",
    mujoco.mjtGeom.mjGEOM_BOX: "box",
    mujoco.mjtGeom.mjGEOM_MESH: "mesh",
}
_GEOM_SIZES = {"plane": 0, "sphere": 1, "capsule": 2, "cylinder": 2, "box": 3, "mesh": 0}
"""How many of a geom's ``geom_size`` entries its collider takes (none: one ignored 0)."""


@dataclass
class _Binding:
    collider: int
    world: int
    body: int
    local_pos: np.ndarray
    local_quat: np.ndarray  # w, x, y, z


@dataclass
class _Gather:
    """Bindings sorted by world: ``groups`` holds (world, rows, body ids) per world."""

    count: int
    colliders: list[int]
    groups: list[tuple[int, slice, np.ndarray]]
    local_pos: np.ndarray  # (count, 3)
    right_mul: np.ndarray  # (count, 4, 4): quat_right_matrix of each binding's local_quat


class MujocoCoupling:
    """Binds solver colliders to MuJoCo bodies, one ``MjData`` per solver world.

    Args:
        solver: the fluid solver; its ``config.dt`` must equal ``model.opt.timestep``.
        model: the MuJoCo model shared by every world.
        datas: one ``MjData`` per solver world.
    """

    def __init__(self, solver: PBFSolver, model: mujoco.MjModel, datas: Sequence[mujoco.MjData]):
        if not isinstance(solver, PBFSolver):
            raise InvalidParameterError(f"solver must be a PBFSolver, got {solver!r}")
        if not isinstance(model, mujoco.MjModel):
            raise InvalidParameterError(f"model must be a mujoco.MjModel, got {model!r}")
        datas = list(datas)
        bad = [d for d in datas if not isinstance(d, mujoco.MjData)]
        if bad:
            raise InvalidParameterError(f"datas must be mujoco.MjData, got {bad[0]!r}")
        if len(datas) != solver.num_worlds:
            raise InvalidParameterError(
                f"need one MjData per world: {solver.num_worlds} worlds, {len(datas)} datas"
            )
        if abs(model.opt.timestep - solver.config.dt) > 1e-12:
            raise InvalidParameterError(
                f"model.opt.timestep={model.opt.timestep} must equal the fluid dt="
                f"{solver.config.dt}"
            )
        self.solver, self.model, self.datas = solver, model, list(datas)
        self.bindings: list[_Binding] = []
        self._gathered: _Gather | None = None
        self.slots: dict[tuple[int, int], int] = {}
        for d in self.datas:
            mujoco.mj_kinematics(model, d)

    def _body_id(self, body: int | str) -> int:
        if isinstance(body, str):
            bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, body)
            if bid < 0:
                names = [self.model.body(i).name for i in range(self.model.nbody)]
                raise InvalidParameterError(f"unknown body {body!r}; bodies: {names}")
            return bid
        return check_index("body", body, self.model.nbody)

    def _slot(self, world: int, body: int) -> int:
        if body == 0:  # the world body never moves and takes no wrench
            return -1
        key = (world, body)
        if key not in self.slots:
            self.slots[key] = self.solver.new_body_slot()
        return self.slots[key]

    def _worlds(self, world: int | None) -> range:
        if world is None:
            return range(self.solver.num_worlds)
        world = check_index("world", world, self.solver.num_worlds)
        return range(world, world + 1)

    def add_geoms(self, geoms: Iterable[int | str] | None = None, world: int | None = None) -> None:
        """Turn MuJoCo geoms (all collidable ones by default) into colliders.

        Supported: plane, sphere, capsule, cylinder, box, mesh. Other types raise.
        """
        m = self.model
        worlds = self._worlds(world)
        if geoms is None:
            ids = [g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]]
        else:
            if isinstance(geoms, str | int):
                raise InvalidParameterError(
                    f"geoms must be a list of geom names or ids, got {geoms!r}"
                )
            ids = []
            for g in geoms:
                gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g) if isinstance(g, str) else g
                if isinstance(g, str) and gid < 0:
                    names = [m.geom(i).name for i in range(m.ngeom) if m.geom(i).name]
                    raise InvalidParameterError(f"unknown geom {g!r}; named geoms: {names}")
                ids.append(check_index("geom", gid, m.ngeom))
        for g in ids:  # every geom checked before any collider is added
            gtype = int(m.geom_type[g])
            if gtype not in _GEOM_KIND:
                raise InvalidParameterError(
                    f"geom {m.geom(g).name or g}: type {mujoco.mjtGeom(gtype).name} has no "
                    f"fluid collider; supported: {sorted(_GEOM_KIND.values())}"
                )
        for g in ids:
            kind = _GEOM_KIND[int(m.geom_type[g])]
            params = list(m.geom_size[g][: _GEOM_SIZES[kind]]) or [0.0]
            mesh = None
            if kind == "mesh":  # MuJoCo collides a mesh geom as its convex hull; so does the fluid
                mid = m.geom_dataid[g]
                va, vn = m.mesh_vertadr[mid], m.mesh_vertnum[mid]
                mesh = convex_hull(m.mesh_vert[va : va + vn])
            body = int(m.geom_bodyid[g])
            for w in worlds:
                c = self.solver.add_collider(w, kind, params, body=self._slot(w, body), mesh=mesh)
                self.bindings.append(
                    _Binding(c, w, body, m.geom_pos[g].copy(), m.geom_quat[g].copy())
                )
        self.sync()

    def add_container(
        self,
        body: int | str,
        shape: ContainerShape,
        local_pos: Sequence[float] = (0.0, 0.0, 0.0),
        local_quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
        world: int | None = None,
    ) -> list[int]:
        """Attach a container shell to ``body`` (frame offset in (w, x, y, z) quaternion).

        Returns:
            The collider index in each world, in world order.
        """
        shape_kind(shape)  # a container shape, checked before any state changes
        bid = self._body_id(body)
        worlds = self._worlds(world)
        pos = check_array("local_pos", local_pos, (3,))
        quat = check_array("local_quat", local_quat, (4,))
        if abs(np.linalg.norm(quat) - 1.0) > 1e-3:
            raise InvalidParameterError(f"local_quat must be a unit quaternion, got {local_quat}")
        out = []
        for w in worlds:
            c = self.solver.add_container(w, shape, body=self._slot(w, bid))
            self.bindings.append(_Binding(c, w, bid, pos.copy(), quat.copy()))
            out.append(c)
        self.sync()
        return out

    def _gather(self) -> _Gather:
        """The bindings as arrays, grouped by world (rebuilt when bindings are added)."""
        if self._gathered is None or self._gathered.count != len(self.bindings):
            b = self.bindings
            order = sorted(range(len(b)), key=lambda k: b[k].world)
            worlds = np.array([b[k].world for k in order])
            cuts = np.flatnonzero(np.diff(worlds)) + 1
            bodies = np.array([b[k].body for k in order])
            self._gathered = _Gather(
                count=len(b),
                colliders=[b[k].collider for k in order],
                groups=[
                    (int(w[0]), slice(int(r[0]), int(r[-1]) + 1), bodies[r])
                    for w, r in zip(
                        np.split(worlds, cuts), np.split(np.arange(len(b)), cuts), strict=True
                    )
                ],
                local_pos=np.array([b[k].local_pos for k in order], float),
                right_mul=np.array([quat_right_matrix(b[k].local_quat) for k in order]),
            )
        return self._gathered

    def sync(self) -> None:
        """Copy every bound body's current pose (from ``MjData``) to its collider: one read of
        each world's body poses, then the frame offsets of all bindings at once."""
        if not self.bindings:
            return
        g = self._gather()
        n = g.count
        xq, xm, xp, com = np.empty((n, 4)), np.empty((n, 9)), np.empty((n, 3)), np.empty((n, 3))
        for w, rows, bodies in g.groups:
            d = self.datas[w]
            xq[rows], xm[rows] = d.xquat[bodies], d.xmat[bodies]
            xp[rows], com[rows] = d.xpos[bodies], d.xipos[bodies]
        poses = np.empty((n, 7))
        poses[:, :3] = xp + (xm.reshape(n, 3, 3) @ g.local_pos[:, :, None])[:, :, 0]
        poses[:, 3:] = (g.right_mul @ xq[:, :, None])[:, :, 0]  # body quaternion ⊗ local one
        self.solver.set_collider_poses(g.colliders, poses, com)

    def apply(self) -> None:
        """Write the liquid's last reaction wrench on each coupled body to ``xfrc_applied``."""
        force, torque = self.solver.body_wrenches()
        for (w, body), slot in self.slots.items():
            self.datas[w].xfrc_applied[body, :3] = force[slot]
            self.datas[w].xfrc_applied[body, 3:] = torque[slot]

    def step(self, n: int = 1) -> None:
        """Advance MuJoCo and the liquid together by ``n`` steps."""
        for _ in range(check_int("steps", n, minimum=0)):
            drag = self._joint_drag()
            for w, d in enumerate(self.datas):
                if drag[w] is None:
                    mujoco.mj_step(self.model, d)
                else:
                    qvel = d.qvel.copy()
                    mujoco.mj_step(self.model, d)
                    self._implicit_drag(d, drag[w], qvel)
                mujoco.mj_kinematics(self.model, d)
            self.sync()
            self.solver.step()
            self.apply()

    def _joint_drag(self) -> list[np.ndarray | None]:
        """Per world, Σ Jᵀ B J over its bodies (nv × nv) from the solver's last step, at the
        bodies' current poses; None where no body feels a viscous drag."""
        out: list[np.ndarray | None] = [None] * len(self.datas)
        if not self.slots:
            return out
        drag = self.solver.body_drag()
        nv = self.model.nv
        jac = np.empty((6, nv))
        for (w, body), slot in self.slots.items():
            b = drag[slot]
            if not b.any():
                continue
            d = self.datas[w]
            if out[w] is None:
                mujoco.mj_comPos(self.model, d)  # the Jacobian's motion axes, at these poses
            mujoco.mj_jacBodyCom(self.model, d, jac[:3], jac[3:], body)
            out[w] = (0.0 if out[w] is None else out[w]) + jac.T @ b @ jac
        return out

    def _implicit_drag(self, d: mujoco.MjData, joint_drag: np.ndarray, qvel: np.ndarray) -> None:
        """Replace ``d``'s step's velocity change Δ (from ``qvel``) by the solution of
        (M + dt Jᵀ B J) Δ' = M Δ, and move its positions by dt (Δ' − Δ) (module docstring).
        ``d``'s inertia is the one MuJoCo stepped with."""
        nv, dt = self.model.nv, self.model.opt.timestep
        inertia = np.empty((nv, nv))
        mujoco.mj_fullM(self.model, d, inertia)
        change = d.qvel - qvel
        new = np.linalg.solve(inertia + dt * joint_drag, inertia @ change)
        fix = new - change
        d.qvel += fix
        mujoco.mj_integratePos(self.model, d.qpos, fix, dt)


class ReactionLog:
    """The liquid's reaction force on every body slot after each of ``steps`` solver steps,
    kept on the solver's device and read back in one copy.

    Call :meth:`record` (k) right after the solver's k-th step of a batch of ``steps``, then
    :meth:`read` once. Recording is a copy of the solver's reaction table on its device (on
    CUDA a device-to-device copy, no synchronisation; on the CPU a numpy copy between views).
    """

    def __init__(self, solver: PBFSolver, steps: int) -> None:
        self.solver = solver
        self.steps = check_int("steps", steps, minimum=1)
        self.slots = max(solver.num_body_slots, 1)
        self._log = wp.zeros(self.steps * self.slots * 3, dtype=wp.int64, device=solver.device)
        # on the CPU the log and the table are written through numpy views (no launch)
        self._host_log = self._log.numpy().reshape(self.steps, -1) if solver.device.is_cpu else None
        self._table: wp.array | None = None
        self._source: wp.array | np.ndarray | None = None

    def record(self, k: int) -> None:
        """Keep the reaction table of the solver's last step as entry ``k`` (0-based)."""
        table = self.solver.buf.cols.force  # (slots, 3) in K.WRENCH_UNIT, rebuilt on upload
        if table is not self._table:
            self._table = table
            cpu = self._host_log is not None
            self._source = table.numpy().reshape(-1) if cpu else table.flatten()
        if self._host_log is not None:
            self._host_log[k] = self._source
        else:
            m = self.slots * 3
            wp.copy(self._log, self._source, dest_offset=k * m, count=m)

    def read(self) -> np.ndarray:
        """(steps, slots, 3) reaction forces on the bodies, N (one device read)."""
        log = self._log.numpy().reshape(self.steps, self.slots, 3)
        return log * float(K.WRENCH_UNIT)
