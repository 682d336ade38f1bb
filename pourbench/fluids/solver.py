"""Batched position-based-fluids solver (Warp), with FleX's parameters per world.

One :class:`PBFSolver` holds ``num_worlds`` independent worlds. Particles of different
worlds never interact; each world has its own liquid, colliders and collider poses; one
kernel launch per stage advances every world. A step is Macklin & Müller's PBF loop:

predict (gravity, damping) → neighbour lists (spatial hash of (world, cell), radix-sorted;
half lists on the CPU, each pair once and its terms added to both particles, full lists on
CUDA, see ``SolverConfig.pair_lists``) → ``iterations`` Jacobi density iterations (λ with
constraint-force mixing and a wall term for the liquid the nearest collider replaces, Δp with
the s_corr tensile term, projection out of colliders) → swept collision with friction and
adhesion (reaction summed per body) → velocity update (dissipation) → vorticity confinement,
XSPH viscosity, cohesion, surface tension and particle friction.

FleX's dimensionless coefficients become rates the same way for every liquid: XSPH viscosity,
particle friction and adhesion per step of ``SolverConfig.calibration_dt``, rescaled to any
step (:meth:`PBFSolver.step_fractions`); cohesion and surface tension are accelerations
(``SolverConfig.cohesion_accel``, Akinci et al. 2013 forms); damping is a drag rate (1/s);
dissipation damps velocity per shape contact (1/s per contact: FleX damps "based on how many
particle contacts it has", and were every liquid neighbour a contact, Table 3.5's dish soap,
5, could not pour). FleX's ``buoyancy`` is not applied, so that a container's weight is the
liquid's.
"""

from __future__ import annotations

import math
import operator
import warnings

import numpy as np
import warp as wp

from pourbench.errors import (
    CapacityError,
    InvalidParameterError,
    check_array,
    check_finite,
    check_index,
    check_int,
    check_poses,
)
from pourbench.fluids import kernels as K
from pourbench.fluids import viscosity as V
from pourbench.fluids.buffers import DeviceBuffers
from pourbench.fluids.colliders import (
    KIND_NAMES,
    Collider,
    ColliderLayout,
    check_sizes,
    collider_table,
    shape_kind,
)
from pourbench.fluids.config import DensityConstants, SolverConfig
from pourbench.fluids.meshes import check_closed_mesh
from pourbench.fluids.params import LiquidProfile, liquid_profile
from pourbench.fluids.step import StepLaunches
from pourbench.fluids.warp_setup import load_kernels
from pourbench.geometry.fill import container_lattice
from pourbench.geometry.rotation import transform_points, warp_transforms
from pourbench.geometry.shapes import BoxShell, ContainerShape, RevolvedShell

RUNAWAY_ENERGY = 3.0
"""How many times the specific energy a world's scene holds (its liquid's height range under
gravity, its walls' motion) one particle may carry before :meth:`PBFSolver.diverged` calls it
a blow-up. Pressure concentrates energy in a few particles: the run-up of a collapsing column
against a wall carries its tip higher than the column stood (docs/contact.md)."""

OVERFLOW_CHECK_EVERY = 16
"""Steps between checks that no neighbour list is full (one small read-back each)."""

LIQUID_PARAMETERS = (
    "damping",
    "dissipation",
    "vorticity_confinement",
    "cohesion",
    "surface_tension",
    "static_friction",
    "dynamic_friction",
)
"""The FleX parameters of each world's liquid that the kernels read as they are."""


def cuda_available() -> bool:
    """Whether Warp sees a CUDA device (probing it here keeps Warp's greeting off stdout)."""
    try:
        return wp.get_cuda_device_count() > 0
    except Exception:  # a broken driver install counts as no device
        return False


def _as_rows(name: str, value: object) -> np.ndarray:
    """Points as an (n, 3) float array; a single point (3,) is one row."""
    arr = np.asarray(value, dtype=object)
    if arr.ndim == 1 and len(arr) == 3:
        value = [value]
    return check_array(name, value, (None, 3))


class PBFSolver:
    """Position-based fluids for ``num_worlds`` independent worlds.

    Build it, add colliders and liquid (``add_collider``/``add_container``/``fill``), then
    call :meth:`step`. Positions are SI metres in the world frame of each world.
    """

    def __init__(self, num_worlds: int = 1, config: SolverConfig | None = None) -> None:
        self.num_worlds = check_int("num_worlds", num_worlds, minimum=1)
        self.config = config or SolverConfig()
        if self.config.device != "cpu":
            count = wp.get_cuda_device_count() if cuda_available() else 0
            index = int(self.config.device.partition(":")[2] or 0)
            if index >= count:
                raise InvalidParameterError(
                    f"device {self.config.device!r}: Warp sees {count} CUDA device(s); "
                    "use device='cpu'"
                )
        self.device = wp.get_device(self.config.device)
        load_kernels([K, V], self.device)
        mode = self.config.pair_lists
        if mode == "auto":
            mode = "full" if self.device.is_cuda else "half"
        self.half_lists = mode == "half"
        self.constants = DensityConstants.from_config(self.config)
        self.liquids: list[LiquidProfile] = [liquid_profile("water")] * self.num_worlds
        self.colliders: list[Collider] = []
        self.num_body_slots = 0
        self._x = np.zeros((0, 3), np.float32)
        self._v = np.zeros((0, 3), np.float32)
        self._world = np.zeros(0, np.int32)
        # diverged(): per world, the highest and lowest its liquid has been (along −gravity)
        # and the fastest its colliders have moved (m/s), since its particles were added
        g = np.asarray(self.config.gravity, float)
        norm = float(np.linalg.norm(g))
        self._up = -g / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
        self._top = np.full(self.num_worlds, -np.inf, np.float32)
        self._bottom = np.full(self.num_worlds, np.inf, np.float32)
        self._wall_speed = np.zeros(self.num_worlds)
        self._diverged_args = (  # the wall speeds going down and the flags coming back
            wp.zeros(self.num_worlds, dtype=float, device=self.device),
            wp.zeros(self.num_worlds, dtype=wp.int32, device=self.device),
        )
        self._uploaded_poses: np.ndarray | None = None
        # the colliders' poses and torque centres, one row per collider (index order); each
        # Collider's pose/com is a view of its row (see _add_rows)
        self._pose_table = np.zeros((0, 7))
        self._com_table = np.zeros((0, 3))
        self._dirty = True
        self._poses_pending = False
        self._host_poses: tuple[np.ndarray, np.ndarray] | None = None  # set by _upload_poses
        self.time = 0.0
        self.steps = 0
        self._capacity_warned = False
        # set by _upload on the first step after a scene change
        self.buf: DeviceBuffers | None = None
        self._layout: ColliderLayout | None = None
        self.viscosity: V.ImplicitViscosity | None = None
        self.launches: StepLaunches | None = None  # the step's kernel launches
        self._moved = False  # x_prev holds the start of a step whose end is x

    # ------------------------------------------------------------------ scene building

    def set_liquid(self, world: int, liquid: str | LiquidProfile) -> None:
        """Set the liquid of one world (all its particles)."""
        self._check_world(world)
        self.liquids[world] = liquid_profile(liquid)
        self._mark_dirty()

    def add_collider(
        self,
        world: int,
        kind: str,
        params: np.ndarray | list[float],
        pose: np.ndarray | None = None,
        body: int = -1,
        mesh: tuple[np.ndarray, np.ndarray] | None = None,
        shape: ContainerShape | None = None,
    ) -> int:
        """Add a collider to ``world``; returns its index.

        Args:
            kind: "plane", "box", "sphere", "capsule", "cylinder", "mesh", "revolved",
                "box_shell".
            params: the kind's sizes (box: half-extents; sphere: radius; capsule/cylinder:
                radius, half-length; mesh: unused; container shells: ``kernel_params()``).
            pose: (x, y, z, qw, qx, qy, qz), world frame.
            body: reaction-force slot from :meth:`new_body_slot`, or −1 for none.
            mesh: (vertices (n, 3), triangles (m, 3)) for kind "mesh", local frame: closed and
                wound outward (:func:`pourbench.fluids.meshes.check_closed_mesh`).
        """
        self._check_world(world)
        if not isinstance(kind, str) or kind not in KIND_NAMES:
            raise InvalidParameterError(
                f"unknown collider kind {kind!r}; known: {list(KIND_NAMES)}"
            )
        if kind in ("revolved", "box_shell") and not isinstance(shape, RevolvedShell | BoxShell):
            raise InvalidParameterError(
                f"a {kind!r} collider is a container shell: add it with add_container(world, shape)"
            )
        arr = check_array("collider params", np.ravel(np.asarray(params, dtype=object)), (None,))
        check_sizes(kind, arr)
        if body != -1:
            check_index("body slot", body, self.num_body_slots)
        pose_arr = (
            None if pose is None else check_poses("pose", [check_array("pose", pose, (7,))], 1)[0]
        )
        wmesh = None
        if kind == "mesh":
            if not isinstance(mesh, tuple | list) or len(mesh) != 2:
                raise InvalidParameterError("a mesh collider needs mesh=(vertices, triangles)")
            verts, tris = mesh
            check_closed_mesh(verts, tris)
            wmesh = wp.Mesh(
                points=wp.array(np.asarray(verts, np.float32), dtype=wp.vec3, device=self.device),
                indices=wp.array(
                    np.asarray(tris, np.int32).ravel(), dtype=wp.int32, device=self.device
                ),
                support_winding_number=True,
            )
        c = Collider(world, KIND_NAMES[kind], arr.astype(np.float32), int(body), wmesh, shape=shape)
        if pose_arr is not None:
            c.pose = pose_arr
        self._add_rows(c)
        self._mark_dirty()
        return len(self.colliders) - 1

    def _add_rows(self, c: Collider) -> None:
        """Append ``c`` to the colliders and its pose and com as the next rows of the pose
        table; the table doubles when full (rebinding every collider's views), so adding n
        colliders costs O(n)."""
        k = len(self.colliders)
        if k == len(self._pose_table):
            cap = max(4, 2 * k)
            self._pose_table = np.concatenate([self._pose_table, np.zeros((cap - k, 7))])
            self._com_table = np.concatenate([self._com_table, np.zeros((cap - k, 3))])
            for i, col in enumerate(self.colliders):
                col.pose, col.com = self._pose_table[i], self._com_table[i]
        self._pose_table[k], self._com_table[k] = c.pose, c.com
        c.pose, c.com = self._pose_table[k], self._com_table[k]
        self.colliders.append(c)

    def add_container(
        self, world: int, shape: ContainerShape, pose: np.ndarray | None = None, body: int = -1
    ) -> int:
        """Add a container shell (from :mod:`pourbench.geometry.shapes`) as a collider."""
        kind, params = shape_kind(shape)
        name = "revolved" if kind == KIND_NAMES["revolved"] else "box_shell"
        return self.add_collider(world, name, params, pose=pose, body=body, shape=shape)

    def new_body_slot(self) -> int:
        """Reserve a slot that accumulates the liquid's reaction force and torque."""
        self.num_body_slots += 1
        self._mark_dirty()
        return self.num_body_slots - 1

    def add_particles(
        self, world: int, positions: np.ndarray, velocities: np.ndarray | None = None
    ) -> None:
        """Append particles (world-frame positions, m) to ``world``."""
        self._check_world(world)
        pos = _as_rows("particle positions", positions).astype(np.float32)
        vel = np.zeros_like(pos)
        if velocities is not None:
            vel = check_array("particle velocities", velocities, pos.shape).astype(np.float32)
        self._mark_dirty()
        if len(pos):
            height = pos @ self._up
            self._top[world] = max(self._top[world], float(height.max()))
            self._bottom[world] = min(self._bottom[world], float(height.min()))
        # keep particles grouped by world so each world's slice is contiguous
        idx = np.searchsorted(self._world, world, side="right")
        self._x = np.insert(self._x, idx, pos, axis=0)
        self._v = np.insert(self._v, idx, vel.reshape(-1, 3), axis=0)
        self._world = np.insert(self._world, idx, np.full(len(pos), world, np.int32))

    def clear_world(self, world: int) -> None:
        """Remove every particle of ``world`` (e.g. before refilling it on an episode reset)."""
        self._check_world(world)
        self._mark_dirty()
        self._top[world], self._bottom[world] = -np.inf, np.inf
        self._wall_speed[world] = 0.0
        keep = self._world != world
        self._x, self._v, self._world = self._x[keep], self._v[keep], self._world[keep]

    def fill(
        self,
        world: int,
        collider: int,
        mass_g: float,
        liquid: str | LiquidProfile | None = None,
        at_least: bool = False,
    ) -> int:
        """Place ``mass_g`` grams of liquid at rest density in a container collider.

        Particles fill the cavity from the bottom up at one per ``spacing``³ (see
        :func:`container_lattice`), so the liquid starts at its level. Their count is the
        nearest whole number to ``mass_g`` over a particle's mass, or with ``at_least`` the
        least count whose mass (count × :meth:`particle_mass`) is at least ``mass_g``.

        Returns:
            The number of particles added.

        Raises:
            CapacityError: more liquid than the container holds below its rim.
        """
        mass_g = check_finite("mass_g", mass_g, minimum=0.0)
        self._check_world(world)
        c = self.colliders[check_index("collider", collider, len(self.colliders))]
        if c.shape is None:
            raise InvalidParameterError(f"collider {collider} is not a container shell")
        if c.world != world:
            raise InvalidParameterError(
                f"collider {collider} is in world {c.world}, not in world {world}"
            )
        if liquid is not None:
            self.set_liquid(world, liquid)
        m = self.particle_mass(world)
        if at_least:  # the least n with n × (particle grams) ≥ mass_g in float arithmetic
            grams = m * 1e3
            n = math.ceil(mass_g / grams)
            while n * grams < mass_g:
                n += 1
            while n > 0 and (n - 1) * grams >= mass_g:
                n -= 1
        else:
            n = round(mass_g * 1e-3 / m)
        local = container_lattice(c.shape, self.config.spacing)
        if n > len(local):
            cap = len(local) * m * 1e3
            raise CapacityError(
                f"mass_g={mass_g:g} g of {self.liquids[world].name} exceeds the container's "
                f"capacity of {cap:.1f} g at spacing {self.config.spacing} m"
            )
        pts = transform_points(c.pose, local[:n])
        self.add_particles(world, pts)
        return n

    # ------------------------------------------------------------------------- device

    def _check_world(self, world: int) -> None:
        check_index("world", world, self.num_worlds)

    def _mark_dirty(self) -> None:
        """Pull the device state into the host copy, then flag a re-upload before the next
        step: host edits (particles, liquids, colliders) always start from the current state."""
        b = self.buf
        if not self._dirty:
            self._x = b.x.numpy().copy()
            self._v = b.v.numpy().copy()
            self._top = b.top.numpy().copy()
            self._bottom = b.bottom.numpy().copy()
            self._dirty = True

    def step_fractions(self) -> dict[str, np.ndarray]:
        """Per world, what is applied once per step, calibrated per step of
        ``calibration_dt`` and rescaled to ``dt`` (ratio r = dt / calibration_dt):

        - velocity relaxations, rescaled as 1 − (1 − f)^r, the same relaxation per second:
          XSPH viscosity's toward the neighbours' mean (``viscosity_frac``, κν / (1 + κν), ν the
          FleX coefficient, or ``xsph_viscosity`` for a liquid with a physical viscosity) and
          particle friction's share of the tangential relative velocity removed
          (``friction_frac``, 0.1 per unit, at most 1);
        - adhesion, which acts as a force. Its pull closes a share of the gap to a surface
          (``adhesion_frac``: f0 = ``adhesion_gain`` per unit, at most 1, at
          ``calibration_dt``); that is a spring of stiffness k with k dt0² = f0 / (1 − f0),
          solved with compliance as in XPBD, so at ``dt`` the share is k dt² / (1 + k dt²)
          (f0 = 1, a lock, stays 1). The grip it adds to wall friction (``adhesion_grip``,
          m: FleX adhesion × ``SolverConfig.adhesion_range``) is a force's position change per
          step and scales with r² (per second instead, adhesion grew as 1/dt: docs/contact.md).
        """
        cfg = self.config
        xsph = [
            liq.viscosity if liq.viscosity_pa_s is None else cfg.xsph_viscosity
            for liq in self.liquids
        ]
        kv = cfg.viscosity_rate * np.array(xsph)
        relax = {
            "viscosity_frac": kv / (1.0 + kv),
            "friction_frac": [min(0.1 * liq.particle_friction, 1.0) for liq in self.liquids],
        }
        ratio = cfg.dt / cfg.calibration_dt
        out = {k: 1.0 - (1.0 - np.asarray(f, float)) ** ratio for k, f in relax.items()}
        adhesion = np.array([liq.adhesion for liq in self.liquids], float)
        f0 = np.minimum(cfg.adhesion_gain * adhesion, 1.0)
        with np.errstate(divide="ignore"):
            k_dt2 = f0 / (1.0 - f0) * ratio**2  # k dt² of the pull's spring; inf: a lock
        out["adhesion_frac"] = 1.0 - 1.0 / (1.0 + k_dt2)
        out["adhesion_grip"] = adhesion * cfg.adhesion_range * ratio**2
        return out

    def viscous_diffusion(self) -> np.ndarray:
        """Per world, the viscous diffusion number ν dt / h² its implicit viscosity solve
        runs with: 0 for a liquid without a physical viscosity, or one below
        ``SolverConfig.min_viscous_diffusion`` (which XSPH alone smooths)."""
        cfg = self.config
        nu = np.array([(liq.viscosity_pa_s or 0.0) / liq.density for liq in self.liquids])
        number = nu * cfg.dt / cfg.h**2
        return np.where(number >= cfg.min_viscous_diffusion, number, 0.0)

    def _upload(self) -> None:
        """Allocate the device buffers for the host scene and upload it."""
        cfg = self.config
        values = {a: [getattr(liq, a) for liq in self.liquids] for a in LIQUID_PARAMETERS}
        values.update(self.step_fractions())
        table, self._layout = collider_table(
            self.colliders, self.num_worlds, self.num_body_slots, self.device
        )
        self.buf = DeviceBuffers.allocate(
            self.device,
            cfg,
            self.half_lists,
            (self._x, self._v, self._world, self._top, self._bottom),
            values,
            [liq.density * cfg.spacing**3 for liq in self.liquids],
            table,
        )
        self.launches = StepLaunches(
            cfg, self.device, self.constants, self.half_lists, self.buf, self._up, self.liquids
        )
        self.viscosity = None
        c_w = np.array([cfg.dt * (liq.viscosity_pa_s or 0.0) / liq.density for liq in self.liquids])
        c_w[self.viscous_diffusion() == 0.0] = 0.0  # ν dt per world; 0: no solve
        if c_w.any():
            sizes = np.bincount(self._world, minlength=self.num_worlds)
            self.viscosity = V.ImplicitViscosity(self, c_w, sizes, self._shear_laws(c_w))
        self.launches.viscosity = self.viscosity
        self._upload_poses(prev_too=True)
        self._moved = False
        self._dirty = False

    def _shear_laws(self, c_w: np.ndarray) -> np.ndarray:
        """(worlds, 4): τ_y, K, n and the reference viscosity (``viscosity_pa_s``) of each
        solved world whose liquid has a Herschel–Bulkley law; zeros for the others."""
        laws = np.zeros((self.num_worlds, 4))
        for w, liq in enumerate(self.liquids):
            if c_w[w] > 0 and liq.consistency_pa_sn is not None:
                law = liq.rheology()
                laws[w] = (
                    *(law.yield_stress_pa, law.consistency_pa_sn, law.flow_index),
                    liq.viscosity_pa_s,
                )
        return laws

    def shear_rates(self) -> np.ndarray:
        """Each particle's shear rate (1/s) as the last viscous solve of a world with a
        Herschel–Bulkley law took it (:func:`pourbench.fluids.viscosity.shear_viscosity`);
        zero elsewhere."""
        visc = self.viscosity
        if self._dirty or visc is None or not visc.has_law:
            return np.zeros(len(self._x))
        return visc.rate.numpy().astype(float)

    def _upload_poses(self, prev_too: bool = False) -> None:
        """Copy the pose table to the device as the end-of-step poses (the start-of-step
        ones are the last step's end poses, copied when it finished; with ``prev_too`` both
        are set). Arrays are updated in place, so the recorded kernel launches stay valid."""
        if len(self._layout.order):
            poses = warp_transforms(self._pose_table[self._layout.order])
            coms = self._com_table[self._layout.order].astype(np.float32)
        else:  # one placeholder collider that no world owns (Warp's layout)
            poses = np.array([[0, 0, 0, 0, 0, 0, 1]], np.float32)
            coms = np.zeros((1, 3), np.float32)
        last = self._uploaded_poses
        if not prev_too and last is not None and last.shape == (len(self._layout.bounds), 7):
            self._track_wall_speed(last, poses)
        self._uploaded_poses = poses
        c = self.buf.cols
        if prev_too:
            c.pose = wp.array(poses, dtype=wp.transform, device=self.device)
            c.pose_prev = wp.clone(c.pose)
            c.com = wp.array(coms, dtype=wp.vec3, device=self.device)
            # on the CPU the arrays' own memory, written through numpy without a copy
            self._host_poses = (c.pose.numpy(), c.com.numpy()) if self.device.is_cpu else None
        elif self._host_poses is not None:
            self._host_poses[0][:] = poses
            self._host_poses[1][:] = coms
        else:
            c.pose.assign(poses)
            c.com.assign(coms)
        self._poses_pending = False

    def _track_wall_speed(self, start: np.ndarray, end: np.ndarray) -> None:
        """Raise each world's fastest collider surface speed (m/s) by this step's moves: a
        collider's origin speed plus its angular speed times its bounding radius. ``start``
        and ``end`` are (colliders, 7) Warp transforms in upload order (grouped by world)."""
        d = end[:, :3] - start[:, :3]
        move = np.sqrt(np.einsum("ij,ij->i", d, d))
        cos_half = np.minimum(np.abs(np.einsum("ij,ij->i", end[:, 3:], start[:, 3:])), 1.0)
        turn = 2.0 * np.arccos(cos_half) * self._layout.bounds
        fastest = np.maximum.reduceat((move + turn) / self.config.dt, self._layout.world_first)
        owners = self._layout.worlds[self._layout.world_first]
        self._wall_speed[owners] = np.maximum(self._wall_speed[owners], fastest)

    def _collider_indices(self, indices: object) -> np.ndarray:
        """``indices`` as an integer array of valid collider indices (an integer numpy array
        is taken as it is; other sequences element by element)."""
        if isinstance(indices, np.ndarray) and indices.ndim == 1 and indices.dtype.kind in "iu":
            idx = indices
        else:
            try:
                idx = np.array([operator.index(i) for i in indices], dtype=np.int64)
            except TypeError:
                raise InvalidParameterError(
                    f"indices must be a list of collider indices, got {indices!r}"
                ) from None
        bad = (idx < 0) | (idx >= len(self.colliders))
        if bad.any():
            raise InvalidParameterError(
                f"collider {int(idx[bad][0])} not in [0, {len(self.colliders)})"
            )
        return idx

    def set_collider_poses(
        self, indices: list[int] | np.ndarray, poses: np.ndarray, com: np.ndarray | None = None
    ) -> None:
        """Set the world poses (n, 7: x y z qw qx qy qz; m, unit quaternion) of colliders
        ``indices``: one write of those rows of the pose table.

        Set them before :meth:`step` to the colliders' end-of-step poses (the last call before
        a step counts); the poses they had at the previous step become the start-of-step
        poses of the swept collision. ``com`` (n, 3, m) is the point each collider's reaction
        torque is taken about (its body's CoM). Everything is checked before anything changes.
        """
        idx = self._collider_indices(indices)
        arr = check_poses("collider poses", poses, len(idx))
        coms = None if com is None else check_array("com", com, (len(idx), 3))
        self._pose_table[idx] = arr
        if coms is not None:
            self._com_table[idx] = coms
        self._poses_pending = True  # uploaded at the next step, so repeated calls are fine

    def set_container_shape(self, collider: int, shape: ContainerShape) -> None:
        """Replace a container collider's shell (e.g. a new pouring container on reset)."""
        c = self.colliders[check_index("collider", collider, len(self.colliders))]
        if c.shape is None:
            raise InvalidParameterError(f"collider {collider} is not a container shell")
        c.kind, c.params = shape_kind(shape)
        c.shape = shape
        self._mark_dirty()

    # --------------------------------------------------------------------------- step

    def step(self, n: int = 1) -> None:
        """Advance every world by ``n`` steps of ``config.dt``."""
        n = check_int("steps", n, minimum=0)
        if self._dirty:
            self._upload()
        for _ in range(n):
            self._step_once()

    def _step_once(self) -> None:
        cfg, n, st = self.config, self.buf.n, self.launches
        # on CUDA the step's sorts allocate scratch memory, which a graph holds only from a pool
        graphs = cfg.graph and (self.device.is_cpu or wp.is_mempool_enabled(self.device))
        if self._poses_pending:
            self._upload_poses()
        if n > 0 and cfg.reorder_every > 0 and self.steps % cfg.reorder_every == 0:
            st.run("reorder", st.reorder, graphs)
        if n > 0 and self.steps % OVERFLOW_CHECK_EVERY == 1:
            self._check_list_capacity()
        if n == 0:
            self._advance_clock()
            return
        st.run("start", st.start, graphs)
        for _ in range(cfg.max_iterations - cfg.iterations):
            if not self.buf.any_active.numpy()[0]:  # on CUDA a 4-byte read-back
                break
            st.run("extra", st.extra_iteration, graphs)
        st.run("end", st.end, graphs)
        visc = self.viscosity
        if visc is not None:
            for shear_pass in range(visc.passes):
                if shear_pass:
                    st.run("viscosity_refine", visc.refine, graphs)
                for _ in range(cfg.viscosity_max_iterations):
                    if not visc.any_active.numpy()[0]:
                        break
                    st.run("viscosity", visc.iteration, graphs)
            st.run("viscosity_end", visc.finish, graphs)
        self._moved = True
        self._advance_clock()

    def iterations_used(self) -> np.ndarray:
        """Per world, the density iterations of the last step: ``iterations`` plus the shares
        of the extra ones ``max_density_error`` called for (a float)."""
        extra = np.zeros(self.num_worlds) if self._dirty else self.buf.extra.numpy()
        return self.config.iterations + extra

    def _check_list_capacity(self) -> None:
        """Warn (once per solver) when a neighbour list filled up: the pairs beyond
        ``max_neighbours`` were dropped, so that particle's density is underestimated."""
        if self._capacity_warned:
            return
        fullest = int(self.buf.nbr_count.numpy().max())
        if fullest >= self.config.max_neighbours:
            self._capacity_warned = True
            warnings.warn(
                f"a neighbour list reached max_neighbours={self.config.max_neighbours} at step "
                f"{self.steps}; pairs beyond it are dropped (raise SolverConfig.max_neighbours)",
                RuntimeWarning,
                stacklevel=4,
            )

    def _advance_clock(self) -> None:
        self.time += self.config.dt
        self.steps += 1

    # ----------------------------------------------------------------------- readback

    @property
    def num_particles(self) -> int:
        return len(self._x) if self._dirty else self.buf.n

    def positions(self) -> np.ndarray:
        """All particle positions (n, 3), m, grouped by world."""
        return self._x.copy() if self._dirty else self.buf.x.numpy().copy()

    def velocities(self) -> np.ndarray:
        """All particle velocities (n, 3), m/s: each particle's displacement over the last step
        divided by ``dt``, the motion an observer sees. The velocity the next step starts from
        also carries the end-of-step filters' impulses, which the density constraint balances
        there: at rest they are not motion (docs/rest.md). Before the first step after a scene
        change, the velocities the particles carry into it (as given to :meth:`add_particles`).
        """
        b = self.buf
        if self._dirty:
            return self._v.copy()
        if not self._moved:
            return b.v.numpy().copy()
        return (b.x.numpy() - b.x_prev.numpy()) / np.float32(self.config.dt)

    def worlds(self) -> np.ndarray:
        """World index of every particle."""
        return self._world.copy()

    def particle_arrays(self) -> tuple[wp.array, wp.array]:
        """Every particle's position (vec3, m) and world (int32) as arrays on the solver's
        device, for kernels that read the current state: the solver's own arrays, or copies
        of the host state while edits wait for the next step's upload."""
        if self._dirty:
            dev = self.device
            return (
                wp.array(self._x, dtype=wp.vec3, device=dev),
                wp.array(self._world, dtype=wp.int32, device=dev),
            )
        return self.buf.x, self.buf.world

    def world_slice(self, world: int) -> slice:
        """Index range of ``world``'s particles in :meth:`positions`."""
        self._check_world(world)
        lo = int(np.searchsorted(self._world, world, side="left"))
        hi = int(np.searchsorted(self._world, world, side="right"))
        return slice(lo, hi)

    def particle_mass(self, world: int) -> float:
        """Mass of one particle of ``world``, kg."""
        self._check_world(world)
        return self.liquids[world].density * self.config.spacing**3

    def densities(self) -> np.ndarray:
        """Last computed density of every particle over the rest density (1 = at rest)."""
        return self.buf.density.numpy().copy() if not self._dirty else np.ones(len(self._x))

    def neighbour_counts(self) -> np.ndarray:
        """Neighbours (within h) of every particle at the last step, counting both sides of
        each listed pair."""
        b = self.buf
        if self._dirty:
            return np.zeros(len(self._x), np.int32)
        count = b.nbr_count.numpy()
        if not self.half_lists:
            return count.copy()
        listed = b.nbr.numpy()[: int(count.sum())]  # half lists are packed back to back
        return (count + np.bincount(listed, minlength=b.n)).astype(np.int32)

    def neighbour_lists(self) -> list[np.ndarray]:
        """Particle indices listed by each particle at the last neighbour build (half lists:
        each pair once, by one of its particles; full lists: all neighbours)."""
        b = self.buf
        if self._dirty or b.n == 0:
            return [np.zeros(0, np.int32) for _ in range(len(self._x))]
        count, start = b.nbr_count.numpy(), b.nbr_start.numpy()
        nbr, stride = b.nbr.numpy(), b.nbr_stride
        return [nbr[s : s + c * stride : stride].copy() for s, c in zip(start, count, strict=True)]

    def density_error(self, world: int | None = None) -> float:
        """Mean |ρ/ρ0 − 1| over bulk particles (≥ 90 % of a lattice particle's neighbours).

        Free-surface and wall particles have deficient neighbourhoods by construction and are
        left out; the bulk is where the density constraint must hold.
        """
        rho, nc = self.densities(), self.neighbour_counts()
        full = self.constants.lattice_neighbours
        mask = nc >= 0.9 * full
        if world is not None:
            sl = self.world_slice(world)
            rho, mask = rho[sl], mask[sl]
        if not mask.any():
            return float("nan")
        return float(np.mean(np.abs(rho[mask] - 1.0)))

    def body_wrenches(self) -> tuple[np.ndarray, np.ndarray]:
        """Liquid's reaction force (N) and torque (N·m, about each body's CoM) per slot."""
        if self._dirty:
            z = np.zeros((self.num_body_slots, 3))
            return z, z.copy()
        unit = float(K.WRENCH_UNIT)
        f = self.buf.cols.force.numpy()[: self.num_body_slots] * unit
        t = self.buf.cols.torque.numpy()[: self.num_body_slots] * unit
        return f, t

    def body_drag(self) -> np.ndarray:
        """(slots, 6, 6) symmetric positive semi-definite, N·s/m and its angular kin: how the
        last step's viscous wall reaction on each body slot (force, then torque about its CoM)
        falls as the body's velocity (linear, then angular) rises, with the liquid beside it
        answering as the solve lets one particle answer its wall and its neighbours held
        (:func:`pourbench.fluids.viscosity.body_drag`, run by this call, not by the step).
        Zero without a viscous liquid.
        :class:`~pourbench.fluids.coupling.MujocoCoupling` integrates that part of the drag
        implicitly."""
        n = self.num_body_slots
        out = np.zeros((n, 6, 6))
        if self._dirty or n == 0 or self.viscosity is None:
            return out
        upper = self.viscosity.body_drag()
        rows, cols = np.triu_indices(6)
        out[:, rows, cols] = upper
        out[:, cols, rows] = upper
        return out

    def collider_sdf(self, collider: int, local_points: np.ndarray) -> np.ndarray:
        """The solver's own signed distance (m) and outward normal of a collider, (n, 4).

        Evaluated by the same Warp function the collision kernels use, at points given in
        the collider's local frame.
        """
        c = self.colliders[check_index("collider", collider, len(self.colliders))]
        pts = wp.array(
            _as_rows("local_points", local_points).astype(np.float32),
            dtype=wp.vec3,
            device=self.device,
        )
        out = wp.zeros(len(pts), dtype=wp.vec4, device=self.device)
        params = wp.array(c.params, dtype=float, device=self.device)
        mesh = c.mesh.id if c.mesh is not None else 0
        wp.launch(
            K.query_sdf,
            len(pts),
            inputs=[c.kind, params, len(c.params), mesh, pts, out],
            device=self.device,
        )
        return out.numpy().astype(float)

    def diverged(self) -> np.ndarray:
        """Per-world flag: a non-finite state, a particle 100 m from the origin, or a runaway
        particle.

        A particle runs away when it is faster than ``config.max_speed``, or when its
        mechanical energy per unit mass, ½v² + g (z − z_low), exceeds what the scene can give
        it: ``RUNAWAY_ENERGY`` × (g (z_high − z_low) + ½ (2 v_wall)²) + ½ v_rest². Here z_high
        and z_low are the highest and lowest its world's liquid has been and v_wall the
        fastest any of the world's colliders has moved (a wall flings liquid at up to twice
        its speed), all since the world's particles were added and tracked every step;
        v_rest, half a spacing per step, is the scale of the solver's own rearrangements.
        """
        b = self.buf
        cfg, dev = self.config, self.device
        if self.num_particles == 0:
            return np.zeros(self.num_worlds, bool)
        f = lambda a: wp.array(a, dtype=float, device=dev)  # noqa: E731
        x, world = self.particle_arrays()
        if self._dirty:  # host state: the velocities as given
            v, from_start = wp.array(self._v, dtype=wp.vec3, device=dev), 0
            top, bottom = f(self._top), f(self._bottom)
        else:
            top, bottom = b.top, b.bottom
            v, from_start = (b.x_prev, 1) if self._moved else (b.v, 0)
        wall_speed, flags = self._diverged_args
        wall_speed.assign(self._wall_speed.astype(np.float32))
        flags.zero_()
        g = float(np.linalg.norm(cfg.gravity))
        v_rest = 0.5 * cfg.spacing / cfg.dt
        wp.launch(
            K.flag_diverged,
            len(x),
            inputs=[
                *(x, v, from_start, 1.0 / cfg.dt, world, wp.vec3(*self._up), g),
                *(top, bottom, wall_speed, RUNAWAY_ENERGY, 0.5 * v_rest**2),
                *(cfg.max_speed, flags),
            ],
            device=dev,
        )
        return flags.numpy() > 0
