"""Rerun recording of a PourRobot-v0 episode, one frame per reset and step.

``world/``: the liquid's particles coloured by speed and the containers' wireframes
(:class:`~pourbench.fluids.record.FluidRecorder`), every robot and scene geom as a mesh logged
once in its own frame and moved by a transform each frame, and the end-effector (the pouring
container's rim centre) where the action handler asked for it (orange) and where it is
(green), each with its rim axis. ``plots/``: the end-effector's position error (m), the arm's
commanded and actual joint velocities (rad/s), and the weight reading (g): the sensor's tared
force raw and through the Butterworth filter, as the policy observes it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from pourbench.fluids.record import FluidRecorder
from pourbench.geometry.rotation import quat_to_matrix
from pourbench.view import local_meshes

if TYPE_CHECKING:
    from pourbench.envs.robot_pour import RobotPourEnv

TARGET_COLOUR = (255, 160, 0)
ACTUAL_COLOUR = (0, 200, 80)
AXIS_LENGTH = 0.06
"""m: the drawn rim axis."""


class RobotRecorder:
    """Writes a :class:`~pourbench.envs.robot_pour.RobotPourEnv`'s episode to ``path``: to
    ``<path>.partial`` while it runs, moved into place by :meth:`close` (as Pour-v0's)."""

    def __init__(self, path: str | Path, env: RobotPourEnv, groups: tuple[int, ...] = (0, 1, 2)):
        self.fluid = FluidRecorder(path, env.solver)
        self.rec = self.fluid.rec
        self.env = env
        m = env.model
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.geoms: list[tuple[int, str]] = []
        for g, name, verts, tris, rgba in local_meshes(m, groups):
            entity = f"world/robot/{name}"
            colour = (np.clip(rgba, 0.0, 1.0) * 255).astype(np.uint8)
            mesh3d = rr.Mesh3D(vertex_positions=verts, triangle_indices=tris, albedo_factor=colour)
            self.rec.log(entity, mesh3d, static=True)
            self.geoms.append((g, entity))

    def log(self, commanded: np.ndarray | None = None) -> None:
        """One frame at the solver's time; ``commanded``: the step's joint velocities."""
        env, rec = self.env, self.rec
        self.fluid.log()
        d = env.data
        for g, entity in self.geoms:
            rot = d.geom_xmat[g].reshape(3, 3)
            rec.log(entity, rr.Transform3D(translation=d.geom_xpos[g], mat3x3=rot))
        (tp, tq), (p, q) = env.ee_target(), env.ee_pose()
        for name, pos, quat, colour in (
            ("target", tp, tq, TARGET_COLOUR),
            ("actual", p, q, ACTUAL_COLOUR),
        ):
            rec.log(f"world/ee/{name}", rr.Points3D([pos], radii=0.006, colors=[colour]))
            rec.log(
                f"world/ee/{name}_axis",
                rr.Arrows3D(
                    origins=[pos],
                    vectors=[AXIS_LENGTH * quat_to_matrix(quat)[:, 2]],
                    colors=[colour],
                ),
            )
        rec.log("plots/ee_position_error_m", rr.Scalars(float(np.linalg.norm(p - tp))))
        names = env.kin.joint_names
        actual = d.qvel[env.kin.dadr]
        for k, name in enumerate(names):
            rec.log(f"plots/joint_velocity/{name}/actual", rr.Scalars(float(actual[k])))
            if commanded is not None:
                rec.log(f"plots/joint_velocity/{name}/commanded", rr.Scalars(float(commanded[k])))
        rec.log("plots/weight_g/raw", rr.Scalars(env.weight_g_true()))
        rec.log("plots/weight_g/filtered", rr.Scalars(float(env.filter.value_g[0])))

    def close(self) -> Path:
        """Finish the recording and move it into place; returns its path."""
        return self.fluid.close()
