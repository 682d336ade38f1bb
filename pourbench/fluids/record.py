"""Rerun recordings of the liquid: particles coloured by speed, containers as wireframes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from pourbench.errors import check_index, check_positive
from pourbench.fluids.solver import PBFSolver
from pourbench.geometry.rotation import transform_points
from pourbench.geometry.shapes import BoxShell, ContainerShape, RevolvedShell
from pourbench.outputs import AtomicOutput, check_output_path


def container_wireframe(shape: ContainerShape, segments: int = 24) -> list[np.ndarray]:
    """Line strips (local frame) outlining a container's wall mid-surface."""
    if isinstance(shape, RevolvedShell):
        ang = np.linspace(0, 2 * np.pi, segments + 1)
        rings = [
            np.stack([r * np.cos(ang), r * np.sin(ang), np.full_like(ang, z)], 1)
            for r, z in shape.points[1:]
        ]
        rho, height = shape.points[:, 0], shape.points[:, 1]
        return rings + [np.c_[rho * np.cos(a), rho * np.sin(a), height] for a in ang[:-1:3]]
    assert isinstance(shape, BoxShell)
    hx, hy, w = shape.half_x, shape.half_y, shape.wall
    sq = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]])
    strips = [np.c_[sq, np.full(5, z)] for z in (w, shape.rim_height)]
    strips += [np.array([[x, y, w], [x, y, shape.rim_height]]) for x, y in sq[:4]]
    return strips


def speed_colors(v: np.ndarray, vmax: float = 1.0) -> np.ndarray:
    """Blue (still) to white (``vmax`` m/s and above, or not finite), uint8 RGB."""
    vmax = check_positive("vmax", vmax)
    s = np.clip(np.nan_to_num(np.linalg.norm(v, axis=1) / vmax, nan=1.0), 0.0, 1.0)[:, None]
    slow, fast = np.array([30, 90, 200]), np.array([235, 245, 255])
    return (slow + s * (fast - slow)).astype(np.uint8)


class FluidRecorder:
    """Writes one world of a solver to a rerun ``.rrd`` file, frame by frame.

    With ``atomic`` (the default: the demo, an environment's recording) frames go to
    ``<path>.partial`` and :meth:`close` moves the finished recording to ``path``, so a run
    that fails first leaves an earlier recording there untouched; without it frames go
    straight to ``path``.

    Raises:
        OutputPathError: ``path`` is a folder or its folder cannot be written.
    """

    def __init__(
        self, path: str | Path, solver: PBFSolver, world: int = 0, atomic: bool = True
    ) -> None:
        check_index("world", world, solver.num_worlds)  # before any file is opened
        self.out = AtomicOutput(path) if atomic else None
        self.path = self.out.path if self.out else check_output_path(path)
        self.solver, self.world = solver, world
        self.rec = rr.RecordingStream("pourbench")
        self.rec.save(self.out.partial if self.out else self.path)

    def log(self) -> None:
        """Log the current particles and container poses at the solver's time."""
        s = self.solver
        self.rec.set_time("sim_time", duration=s.time)
        sl = s.world_slice(self.world)
        x, v = s.positions()[sl], s.velocities()[sl]
        self.rec.log(
            "world/liquid", rr.Points3D(x, radii=0.5 * s.config.spacing, colors=speed_colors(v))
        )
        for k, c in enumerate(s.colliders):
            if c.world != self.world or c.shape is None:
                continue
            strips = [transform_points(c.pose, st) for st in container_wireframe(c.shape)]
            self.rec.log(f"world/container_{k}", rr.LineStrips3D(strips, radii=0.0008))

    def discard(self) -> None:
        """Stop recording and delete what an atomic recording wrote (``path`` is untouched)."""
        self.rec.disconnect()
        if self.out:
            self.out.discard()

    def close(self) -> Path:
        """Finish the recording and move it into place; returns its path."""
        self.rec.flush()
        self.rec.disconnect()
        return self.out.commit() if self.out else self.path
