"""The device arrays of a :class:`~pourbench.fluids.solver.PBFSolver` step, in one dataclass.

The solver keeps its scene on the host and allocates these on the first step after any
change (:meth:`DeviceBuffers.allocate`); until the next change they are never swapped or
reallocated, so recorded kernel launches and graphs stay valid. Layouts of the neighbour
lists are in :mod:`pourbench.fluids.kernels`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import warp as wp

from pourbench.fluids import kernels as K
from pourbench.fluids.config import SolverConfig


@dataclass
class DeviceBuffers:
    """Per-particle state and scratch, neighbour lists, spatial hash, per-world parameters and
    the collider table of ``n`` particles on one device.

    Particle state: ``x`` positions (m) and ``v`` velocities (m/s) of the step's start,
    ``world`` each particle's world, ``top`` / ``bottom`` per world the highest and lowest
    its liquid has been along −gravity (m). Per world: ``params`` the liquid parameters and
    step fractions by name (:meth:`PBFSolver.step_fractions`), ``mass`` one particle's mass
    (kg); ``active`` / ``share`` whether a world takes part in an iteration and with what
    share of a correction, ``extra`` its extra iterations so far, ``worst`` its largest
    density error of the last iteration, ``any_active`` (one int) whether any world is still
    iterating (``SolverConfig.max_density_error``).
    """

    n: int
    x: wp.array
    v: wp.array
    world: wp.array
    top: wp.array
    bottom: wp.array
    # per-particle scratch of a step
    x_prev: wp.array
    p: wp.array
    p_sorted: wp.array
    delta: wp.array
    corr: wp.array  # gradient-correction matrices (SolverConfig.corrected_pressure)
    omega: wp.array
    normal: wp.array
    v_tmp: wp.array
    eta: wp.array
    lam: wp.array
    sums: wp.array
    vsum: wp.array
    dv_sum: wp.array
    push: wp.array
    clear: wp.array  # collider clearance (K.predict)
    wall: wp.array  # nearest wall (K.predict)
    wall_collider: wp.array
    density: wp.array
    scorr_mean: wp.array  # kernel-weighted mean s_corr of a particle's pairs (bulk_scorr_spread)
    contacts: wp.array
    order_keys: wp.array
    order: wp.array
    # neighbour lists: half lists are built with a fixed capacity per particle, then packed,
    # and cache their pair terms; full lists are interleaved, written in place by the build
    # (start[i] = i, stride n)
    nbr_build: wp.array
    nbr_count: wp.array
    nbr_start: wp.array
    nbr_stride: int
    nbr: wp.array
    pair: wp.array
    world_sorted: wp.array
    # spatial hash: buckets = next power of two ≥ 2n; sort buffers need 2n entries
    bucket_mask: int
    bucket_start: wp.array
    bucket_end: wp.array
    keys: wp.array
    sorted_idx: wp.array
    cell: wp.array
    cell_sorted: wp.array
    # per world
    params: dict[str, wp.array]
    mass: wp.array
    active: wp.array
    share: wp.array
    extra: wp.array
    worst: wp.array
    any_active: wp.array
    cols: K.Colliders

    @property
    def lists(self) -> tuple[wp.array, wp.array, wp.array, int]:
        """The neighbour lists as the pair kernels take them: entries, starts, counts, stride."""
        return self.nbr, self.nbr_start, self.nbr_count, self.nbr_stride

    @classmethod
    def allocate(
        cls,
        device: wp.Device,
        cfg: SolverConfig,
        half_lists: bool,
        state: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        params: Mapping[str, Sequence[float] | np.ndarray],
        mass: Sequence[float],
        cols: K.Colliders,
    ) -> DeviceBuffers:
        """Buffers for the host ``state`` (positions, velocities, worlds, tops, bottoms), the
        per-world ``params`` and particle ``mass`` (kg), and the collider table ``cols``."""
        x, v, world, top, bottom = state
        n = len(x)
        num_worlds = len(mass)

        def zeros(size: int, dtype: type = wp.vec3) -> wp.array:
            return wp.zeros(size, dtype=dtype, device=device)

        def floats(values: object) -> wp.array:
            return wp.array(values, dtype=float, device=device)

        cap = max(n * cfg.max_neighbours, 1)
        start = np.zeros(n, np.int32) if half_lists else np.arange(n, dtype=np.int32)
        buckets = 1 << max(10, math.ceil(math.log2(max(2 * n, 1))))
        sort_size = 2 * max(n, 1)
        vectors = ("x_prev", "p", "p_sorted", "delta", "omega", "normal", "v_tmp", "eta", "dv_sum")
        return cls(
            n=n,
            x=wp.array(x, dtype=wp.vec3, device=device),
            v=wp.array(v, dtype=wp.vec3, device=device),
            world=wp.array(world, dtype=wp.int32, device=device),
            top=floats(top),
            bottom=floats(bottom),
            **{name: zeros(n) for name in vectors},
            **{name: zeros(n, float) for name in ("lam", "push", "clear", "density", "scorr_mean")},
            sums=zeros(n, K.vec5),
            corr=zeros(n if cfg.corrected_pressure else 1, wp.mat33),
            vsum=zeros(n, wp.vec4),
            wall=zeros(n, K.vec5),
            wall_collider=wp.full(n, -1, dtype=wp.int32, device=device),
            contacts=zeros(n, wp.int32),
            order_keys=zeros(sort_size, wp.int64),
            order=zeros(sort_size, wp.int32),
            nbr_build=zeros(cap if half_lists else 1, wp.int32),
            nbr_count=zeros(n, wp.int32),
            nbr_start=wp.array(start, dtype=wp.int32, device=device),
            nbr_stride=1 if half_lists else max(n, 1),
            nbr=zeros(cap, wp.int32),
            pair=zeros(cap if half_lists else 1, wp.vec2),
            world_sorted=zeros(max(n, 1), wp.int32),
            bucket_mask=buckets - 1,
            bucket_start=zeros(buckets, wp.int32),
            bucket_end=zeros(buckets, wp.int32),
            keys=zeros(sort_size, wp.int32),
            sorted_idx=zeros(sort_size, wp.int32),
            cell=zeros(max(n, 1), wp.vec3i),
            cell_sorted=zeros(max(n, 1), wp.vec3i),
            params={name: floats(values) for name, values in params.items()},
            mass=floats(mass),
            active=wp.ones(num_worlds, dtype=wp.int32, device=device),
            share=wp.ones(num_worlds, dtype=float, device=device),
            extra=zeros(num_worlds, float),
            worst=zeros(num_worlds, float),
            any_active=zeros(1, wp.int32),
            cols=cols,
        )
