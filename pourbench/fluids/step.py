"""The kernel launches of one PBF step over every world (Macklin & Müller's loop).

A :class:`StepLaunches` is built on each upload of a solver's scene, on that upload's
:class:`~pourbench.fluids.buffers.DeviceBuffers`. Each distinct launch is recorded once and
replayed, and each part of a step (its start, one extra iteration, its end) can be captured
once as a graph and replayed; the solver decides which parts run
(:meth:`pourbench.fluids.solver.PBFSolver.step`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from pourbench.fluids import kernels as K
from pourbench.fluids.buffers import DeviceBuffers
from pourbench.fluids.config import DensityConstants, SolverConfig
from pourbench.fluids.params import LiquidProfile

if TYPE_CHECKING:
    from pourbench.fluids.viscosity import ImplicitViscosity


def lattice_sites(h: float, spacing: float, grad_c: float) -> np.ndarray:
    """The sites of :func:`~pourbench.fluids.kernels.solid_moments`' lattice: the cubic
    lattice of ``spacing`` s about a particle, the particle left out, within the kernel
    radius h. A row per site: its offset e = (p_i − site) / s in the lattice's frame, its
    distance |e| s (m), and the weight −spiky_factor(|e| s) s² of its moments (a site that
    counts c of the solid adds c · weight · e ⊗ e to the particle's M, in the lattice's
    frame)."""
    m = math.ceil(h / spacing) - 1  # the sites within h lie m spacings out or less
    steps = np.arange(-m, m + 1, dtype=float)
    e = np.stack(np.meshgrid(steps, steps, steps, indexing="ij"), -1).reshape(-1, 3)
    dist = np.linalg.norm(e, axis=1) * spacing
    keep = (dist > 1.0e-9) & (dist < h)
    e, dist = e[keep], dist[keep]
    weight = -grad_c * (h - dist) ** 2 / dist * spacing**2
    return np.column_stack([e, dist, weight]).astype(np.float32)


class StepLaunches:
    """The launches of a step on ``buf`` (on ``device``), for the density constraint's
    ``constants`` of ``config``, with half neighbour lists or full ones (``half_lists``,
    ``SolverConfig.pair_lists``) and ``up`` the unit vector against gravity. The curl is
    computed when some of ``liquids`` (one per world) has vorticity confinement, colour-field
    normals with it or when some has surface tension.
    """

    def __init__(
        self,
        config: SolverConfig,
        device: wp.Device,
        constants: DensityConstants,
        half_lists: bool,
        buf: DeviceBuffers,
        up: np.ndarray,
        liquids: Sequence[LiquidProfile],
    ) -> None:
        self.config, self.device, self.k, self.buf = config, device, constants, buf
        self.half_lists = half_lists
        self.pairk = K.HALF_LISTS if half_lists else K.FULL_LISTS
        self.num_worlds = len(liquids)
        self._up = up
        self._needs_curl = any(liq.vorticity_confinement > 0 for liq in liquids)
        self._needs_curl_and_normals = self._needs_curl or any(
            liq.surface_tension > 0 for liq in liquids
        )
        self.scorr = wp.vec4(*constants.scorr)
        sites = lattice_sites(config.h, config.spacing, constants.grad_c)
        self.sites = wp.array(sites, dtype=K.vec5, device=device)
        self.site_reach = float(sites[:, 3].max() + 0.5 * config.spacing)
        self.viscosity: ImplicitViscosity | None = None  # started at the end of each step
        self._cmds: dict[str, wp.Launch] = {}
        self._graphs: dict[str, wp.Graph] = {}

    def launch(
        self,
        key: str,
        kernel: wp.Kernel,
        inputs: list,
        outputs: list | None = None,
        dim: int | None = None,
    ) -> None:
        """Launch ``kernel`` over the particles (or ``dim`` threads), replaying a recorded launch
        after the first.

        Packing a launch's arguments costs more Python time than a small kernel runs, so each
        distinct launch is recorded once per upload and replayed; the arrays it binds are
        never swapped or reallocated until the next upload.
        """
        cmd = self._cmds.get(key)
        if cmd is None:
            cmd = wp.launch(
                kernel,
                self.buf.n if dim is None else dim,
                inputs=inputs,
                outputs=outputs or [],
                device=self.device,
                record_cmd=True,
            )
            self._cmds[key] = cmd
        cmd.launch()

    def reorder(self) -> None:
        """Sort particles by (world, Morton cell) so neighbours sit close in memory.

        Worlds stay contiguous and each world's particles keep an order that depends only on
        that world, so batched and single-world runs stay identical.
        """
        b = self.buf
        self.launch(
            "order_keys", K.order_keys, [b.x, b.world, 1.0 / self.config.h], [b.order_keys, b.order]
        )
        # keys: world above 33 Morton bits; sorting only the bits in use is several times faster
        key_bits = 33 + max(1, (self.num_worlds - 1).bit_length())
        wp.utils.radix_sort_pairs(b.order_keys, b.order, b.n, end_bit=key_bits)
        self.launch("gather_state", K.gather_state, [b.order, b.x, b.v, b.p, b.v_tmp])
        self.launch("copy_state", K.copy_state, [b.p, b.v_tmp, b.x, b.v])

    def run(self, key: str, launches: Callable[[], None], graphs: bool) -> None:
        """Run one part of a step: recorded once as a graph and replayed, or launched."""
        if not graphs:
            launches()
            return
        graph = self._graphs.get(key)
        if graph is None:
            with wp.ScopedCapture(device=self.device) as capture:
                launches()
            graph = self._graphs[key] = capture.graph
        wp.capture_launch(graph)

    def start(self) -> None:
        """Predict, list neighbours, and every world's first ``iterations`` iterations."""
        b = self.buf
        cfg = self.config
        self.launch(
            "start_worlds", K.start_worlds, [], [b.active, b.share, b.extra], self.num_worlds
        )
        b.cols.force.zero_()
        b.cols.torque.zero_()
        b.push.zero_()
        P = b.params
        self.launch(
            "predict",
            K.predict,
            [
                b.x,
                b.v,
                b.world,
                P["damping"],
                wp.vec3(*cfg.gravity),
                cfg.dt,
                b.cols,
                cfg.radius,
                cfg.h,
            ],
            [b.x_prev, b.p, b.clear, b.wall, b.wall_collider],
        )
        self.build_neighbours()
        if cfg.corrected_pressure:
            self.correct_gradients()
        for _ in range(cfg.iterations):
            self.density_iteration()
        if cfg.max_iterations > cfg.iterations:
            self.update_active()

    def correct_gradients(self) -> None:
        """Every particle's gradient-correction matrix from its neighbour list
        (``SolverConfig.corrected_pressure``), for the step's density iterations."""
        b = self.buf
        b.corr.zero_()
        self.launch(
            "gradient_moments",
            self.pairk.gradient_moments,
            [b.p, *b.lists, b.wall, b.wall_collider, self.config.h, self.k.grad_c],
            [b.corr],
        )
        self.launch(
            "solid_moments",
            K.solid_moments,
            [
                b.p,
                b.world,
                b.wall,
                b.wall_collider,
                b.cols,
                self.sites,
                self.site_reach,
                self.config.spacing,
                self.config.h,
                self.k.grad_c,
            ],
            [b.corr],
        )
        self.launch("correction_matrices", K.correction_matrices, [b.corr])

    def extra_iteration(self) -> None:
        """One more iteration for the worlds still above ``max_density_error``."""
        self.density_iteration(extra=True)
        self.update_active()

    def update_active(self) -> None:
        b = self.buf
        b.any_active.zero_()
        self.launch(
            "update_active",
            K.update_active,
            [b.worst, self.config.max_density_error],
            [b.active, b.share, b.extra, b.any_active],
            self.num_worlds,
        )

    def density_iteration(self, extra: bool = False) -> None:
        """One Jacobi iteration of the density constraints (worlds not ``active`` skip it).
        An ``extra`` one (past ``iterations``) leaves out the tensile term s_corr, so that the
        artificial pressure a step applies does not grow with the iterations it takes."""
        b = self.buf
        cfg = self.config
        tag = "_extra" if extra else ""
        scorr = wp.vec4(0.0, 4.0, 1.0, 0.0) if extra else self.scorr
        b.worst.zero_()
        if cfg.bulk_scorr_spread < 1.0:
            b.scorr_mean.zero_()  # half lists sum into it
        self.launch(
            "density_sums" + tag,
            self.pairk.density_sums,
            [
                b.p,
                *b.lists,
                cfg.h,
                self.k.grad_c,
                scorr,
                self.k.w0,
                self.k.eps,
                b.wall,
                self.k.wall_coef,
                b.world,
                b.active,
                cfg.bulk_scorr_spread,
            ],
            [b.sums, b.pair, b.lam, b.density, b.worst, b.scorr_mean],
        )
        if self.half_lists:  # full lists compute λ in the density pass
            self.launch(
                "compute_lambda" + tag,
                K.compute_lambda,
                [
                    b.sums,
                    b.p,
                    b.wall,
                    self.k.wall_coef,
                    cfg.h,
                    self.k.w0,
                    self.k.eps,
                    b.world,
                    b.active,
                    cfg.bulk_scorr_spread,
                ],
                [b.lam, b.density, b.worst, b.scorr_mean],
            )
        pairk = self.pairk
        delta = pairk.compute_delta_corrected if cfg.corrected_pressure else pairk.compute_delta
        self.launch(
            "compute_delta" + tag,
            delta,
            [
                b.p,
                *b.lists,
                b.lam,
                b.density,
                b.pair,
                cfg.h,
                self.k.grad_c,
                scorr,
                self.k.surface_band,
                b.world,
                b.active,
                b.corr,
                cfg.bulk_scorr_spread,
                b.scorr_mean,
            ],
            [b.delta],
        )
        self.launch(
            "apply_delta" + tag,
            K.apply_delta,
            [
                b.p,
                b.delta,
                cfg.sor,
                b.world,
                b.cols,
                b.mass,
                cfg.radius,
                cfg.dt,
                b.lam,
                b.wall,
                b.wall_collider,
                self.k.wall_coef,
                cfg.h,
                self.k.w0,
                b.active,
                b.share,
            ],
            [b.push, b.clear],
        )

    def end(self) -> None:
        """Swept collision, velocity update and the velocity filters."""
        b = self.buf
        cfg = self.config
        P = b.params
        self.launch(
            "collide",
            K.collide,
            [
                b.p,
                b.x_prev,
                b.world,
                b.cols,
                b.mass,
                P["static_friction"],
                P["dynamic_friction"],
                P["adhesion_grip"],
                cfg.radius,
                cfg.adhesion_range,
                P["adhesion_frac"],
                cfg.dt,
                b.clear,
            ],
            [b.push, b.contacts],
        )
        self.launch(
            "update_velocity",
            K.update_velocity,
            [
                b.p,
                b.x_prev,
                b.contacts,
                b.world,
                P["dissipation"],
                cfg.sleep_threshold,
                cfg.dt,
                wp.vec3(*self._up),
            ],
            [b.v, b.x, b.top, b.bottom],
        )
        if self._needs_curl_and_normals:
            self.launch(
                "vorticity_and_normals",
                self.pairk.vorticity_and_normals,
                [
                    b.x,
                    b.v,
                    *b.lists,
                    cfg.h,
                    self.k.grad_c,
                    int(self._needs_curl),
                ],
                [b.omega, b.normal],
            )
        self.launch(
            "filter_sums",
            self.pairk.filter_sums,
            [
                b.x,
                b.v,
                b.omega,
                b.normal,
                *b.lists,
                b.world,
                P["vorticity_confinement"],
                P["cohesion"],
                P["surface_tension"],
                P["friction_frac"],
                cfg.h,
                self.k.grad_c,
                cfg.spacing,
                cfg.dt,
                cfg.cohesion_accel,
                cfg.surface_tension_accel,
                self.k.coh_norm,
                self.k.curv_norm,
            ],
            [b.vsum, b.eta, b.dv_sum],
        )
        self.launch(
            "apply_filters",
            K.apply_filters,
            [
                b.world,
                P["viscosity_frac"],
                P["vorticity_confinement"],
                cfg.dt,
                cfg.h,
                b.vsum,
                b.eta,
                b.dv_sum,
                b.omega,
                b.normal,
            ],
            [b.v],
        )
        if self.viscosity is not None:
            self.viscosity.start()
        # next step's start-of-step collider poses are this step's end poses
        wp.copy(b.cols.pose_prev, b.cols.pose)

    def build_neighbours(self) -> None:
        """Hash particles by (world, cell), sort the buckets, and list neighbours within h."""
        b = self.buf
        cfg, n = self.config, b.n
        inv_cell = 1.0 / cfg.h
        self.launch(
            "hash_particles",
            self.pairk.hash_particles,
            [b.p, b.world, inv_cell, b.bucket_mask],
            [b.cell, b.keys, b.sorted_idx],
        )
        # bucket keys are below the table size, a power of two: sort only those bits
        wp.utils.radix_sort_pairs(
            b.keys, b.sorted_idx, n, end_bit=(b.bucket_mask + 1).bit_length() - 1
        )
        b.bucket_start.zero_()
        b.bucket_end.zero_()
        self.launch(
            "bucket_ranges",
            K.bucket_ranges,
            [b.keys, b.sorted_idx, b.p, b.world, b.cell, n],
            [b.bucket_start, b.bucket_end, b.p_sorted, b.world_sorted, b.cell_sorted],
        )
        self.launch(
            "build_neighbours",
            self.pairk.build_neighbours,
            [
                b.p,
                b.world,
                b.cell,
                b.sorted_idx,
                b.p_sorted,
                b.world_sorted,
                b.cell_sorted,
                b.bucket_start,
                b.bucket_end,
                b.bucket_mask,
                cfg.h,
                cfg.max_neighbours,
                cfg.max_neighbours if self.half_lists else 1,
                0,
            ],
            [b.nbr_build if self.half_lists else b.nbr, b.nbr_count],
        )
        if self.half_lists:
            wp.utils.array_scan(b.nbr_count, b.nbr_start, inclusive=False)
            self.launch(
                "pack_neighbours",
                K.pack_neighbours,
                [b.nbr_build, cfg.max_neighbours, b.nbr_count, b.nbr_start],
                [b.nbr],
            )
