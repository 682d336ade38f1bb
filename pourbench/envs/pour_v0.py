"""``pourbench/Pour-v0``: PourNet's pouring task (thesis §6.4–6.6) as a Gymnasium env.

The single environment is the batch of one of :class:`~pourbench.envs.core.PourBatch`.
Each version of the task has its own module: a change to the task's observation, reward,
action handler or defaults becomes ``Pour-v1`` beside this one, which keeps v0's behaviour
(``tests/test_behaviour_fingerprint.py`` pins it).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import fields
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from pourbench.envs.core import OBS_BOUND, OBS_SIZE, PourBatch, PourConfig
from pourbench.errors import InvalidParameterError, check_int

RENDER_SIZE = (480, 640)  # height, width in pixels


def observation_space() -> gym.spaces.Box:
    """The 12-value observation space (float32)."""
    return gym.spaces.Box(-OBS_BOUND, OBS_BOUND, (OBS_SIZE,), np.float32)


def action_space() -> gym.spaces.Box:
    """``(ω, r)`` in [-1, 1]² (float32)."""
    return gym.spaces.Box(-1.0, 1.0, (2,), np.float32)


def check_settings(settings: Mapping[str, Any], also: Sequence[str] = ()) -> None:
    """Refuse a setting that is neither a :class:`PourConfig` field nor in ``also``.

    Raises:
        InvalidParameterError: naming the first unknown setting and listing the fields.
    """
    known = [f.name for f in fields(PourConfig)]
    unknown = sorted(set(settings) - {*known, *also})
    if unknown:
        raise InvalidParameterError(
            f"unknown environment setting {unknown[0]!r}; PourConfig fields: {', '.join(known)}"
        )


def make_config(**kwargs: Any) -> PourConfig:
    """A :class:`PourConfig` from keyword arguments (see :func:`check_settings`)."""
    check_settings(kwargs)
    return PourConfig(**kwargs)


class PourEnv(gym.Env):
    """Pour a target amount of liquid into a receiving container on a scale.

    The pouring container is held kinematically (a mocap body, as PourNet was trained); the
    receiving container (a tray of 10 cm radius) stands on a force/torque scale on a 0.75 m
    table.

    Observation (12 float32, the thesis' order):
        0. liquid density, g/ml (= kg/m³ / 1000)
        1. cohesion (FleX coefficient)
        2. surface tension (FleX coefficient)
        3. viscosity: log10 of the dynamic viscosity in mPa·s (water 0, honey 4)
        4. adhesion (FleX coefficient)
        5. pouring-container diameter, m
        6. pouring-container inner depth, m
        7. measured liquid weight in the receiving container, g (scale force, tared, with
           0.15 N noise, 2nd-order Butterworth low-pass at 1 Hz over 100 Hz samples)
        8. target, g
        9. fill-level difference: target − measured weight, g
        10. running average pouring error over the last n completed episodes, g (the
            thesis' Avg. Pouring Error, n = ``RewardConfig.window`` = 10). It is the
            environment's memory across episodes: resets keep it, a new environment starts
            at 0, and episodes that end by collision, truncation or divergence do not count.
        11. pouring-container tilt about its forward axis, rad (0 = upright)

    Action (2 float32 in [-1, 1]): ``ω`` rotational velocity (× ``limits.max_rate``, 0.8 rad/s)
    and ``r`` translational velocity (× ``limits.max_speed``, 0.15 m/s). With
    ``action_mode="thesis"`` (default) Algorithm 4 applies them; ``"free"`` applies both
    directly.

    Timing and resolution (defaults): 10 Hz steps of 12 physics substeps at 120 Hz, at most
    250 steps (25 s); liquid particles of 8 mm (0.51 g of water each; pass
    ``solver=SolverConfig(spacing=0.005, dt=1/240)`` for the solver's finer 0.125 g default).

    Reward: Algorithm 5 (see :mod:`pourbench.envs.reward`). The episode terminates when the
    container is upright again after pouring and the stream has stopped, or on a collision
    between the containers; it is truncated at ``max_steps`` or when the liquid simulation
    diverges (``info["sim_diverged"]``).

    ``reset(options=...)`` accepts ``liquid`` (profile name), ``target_g``, ``container``
    (pouring container name), ``initial_g`` and ``start`` (x, y, height of the pouring
    container's base relative to the receiving container's, m): see
    :class:`~pourbench.envs.options.ResetOptions`. Unknown names raise
    :class:`~pourbench.errors.UnknownNameError` listing the known ones.

    ``info``: ``poured_g``, ``spilled_g``, ``remaining_g``, ``in_flight_g``, ``initial_g``,
    ``error_g``, ``target_g``, ``measured_g``, ``liquid``, ``container``, ``tilt``,
    ``collided``, ``sim_diverged``, ``is_success``, ``average_error_g`` (the running
    average error of the last completed episodes, thesis §6.5.1; 0 before the first),
    ``completed_episodes`` (episodes completed so far, the average's count up to its window).

    Args:
        render_mode: None, "rgb_array" (MuJoCo offscreen renderer, particles as spheres;
            without a display ``import pourbench`` chooses EGL unless ``MUJOCO_GL`` is set) or
            "human" (MuJoCo's passive viewer, updated at every reset and step; refused
            without a display).
        record_path: if given, a rerun ``.rrd`` recording of the liquid and containers, one
            frame per reset and step. It is written to ``<record_path>.partial`` while the
            environment runs and moved to ``record_path`` by :meth:`close`, so an earlier
            recording there survives until this one is complete.
        **kwargs: fields of :class:`~pourbench.envs.core.PourConfig` (e.g. ``liquid="water"``,
            ``action_mode="free"``, ``container_set="novel"``, ``solver=SolverConfig(...)``).
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["human", "rgb_array"],
        "render_fps": 10,
    }

    def __init__(
        self, render_mode: str | None = None, record_path: str | None = None, **kwargs: Any
    ) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise InvalidParameterError(
                f"render_mode must be None, 'human' or 'rgb_array', got {render_mode!r}"
            )
        if render_mode == "human":
            from pourbench.view import check_display

            check_display(
                asked="render_mode='human' (MuJoCo's viewer)",
                instead="use render_mode='rgb_array', or record_path='pour.rrd' for a rerun "
                "recording",
            )
        self.render_mode = render_mode
        self.batch = PourBatch(1, make_config(**kwargs))
        self.config = self.batch.config
        self.metadata = {**self.metadata, "render_fps": self.config.control_hz}
        self.observation_space = observation_space()
        self.action_space = action_space()
        self._renderer: mujoco.Renderer | None = None
        self._viewer: Any = None  # MuJoCo's passive viewer (render_mode "human")
        self._recorder = None
        if record_path is not None:
            from pourbench.fluids.record import FluidRecorder

            self._recorder = FluidRecorder(record_path, self.batch.solver)

    def set_lesson(self, k: int) -> None:
        """Draw liquids from curriculum lesson ``k`` at later resets (when ``liquid`` is None)."""
        self.batch.set_lesson(k)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None:
            seed = check_int("seed", seed, minimum=0)
        draw = self.batch.draw_reset(0, seed, options)  # a refusal changes nothing
        super().reset(seed=seed)
        self.batch.apply_reset(0, draw)
        self.batch.flush()
        info = _world_info(self.batch.reset_info(), 0)
        if self._recorder is not None:
            self._recorder.log()
        if self.render_mode == "human":
            self.render()
        return self.batch.observe()[0], info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, rew, term, trunc, info = self.batch.step(action)  # checks the action
        if self._recorder is not None:
            self._recorder.log()
        if self.render_mode == "human":
            self.render()
        return obs[0], float(rew[0]), bool(term[0]), bool(trunc[0]), _world_info(info, 0)

    def render(self) -> np.ndarray | None:
        if self.render_mode == "human":
            self._show()
        if self.render_mode != "rgb_array":  # "human" shows and returns None
            return None
        if self._renderer is None:
            try:
                self._renderer = mujoco.Renderer(self.batch.model, *RENDER_SIZE, max_geom=20000)
            except (mujoco.FatalError, ImportError, RuntimeError) as exc:
                backend = os.environ.get("MUJOCO_GL") or "MuJoCo's default (GLFW)"
                raise RuntimeError(
                    f"offscreen rendering failed with the OpenGL backend {backend}: {exc}. "
                    "Without a display, set MUJOCO_GL=egl (or osmesa) before MuJoCo is imported"
                ) from None
        return render_world(self.batch, 0, self._renderer)

    def _show(self) -> None:
        """Update MuJoCo's passive viewer (opened on the first call) with the scene and the
        particles as spheres."""
        import mujoco.viewer

        data = self.batch.world_data(0)
        if self._viewer is None:
            self._viewer = mujoco.viewer.launch_passive(self.batch.model, data)
        with self._viewer.lock():
            scene = self._viewer.user_scn
            scene.ngeom = 0
            x = self.batch.solver.positions()
            add_particles(scene, x, self.batch.solver_config.spacing)
        self._viewer.sync()

    def discard_recording(self) -> None:
        """Drop the recording being written (an earlier one at ``record_path`` stays)."""
        if self._recorder is not None:
            self._recorder.discard()
            self._recorder = None

    def close(self) -> None:
        if self._recorder is not None:
            self._recorder.close()
            self._recorder = None
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None


def _world_info(info: dict[str, np.ndarray], w: int) -> dict[str, Any]:
    """World ``w``'s entries of a batch's info, numpy scalars as Python ones."""
    return {k: v[w].item() if isinstance(v[w], np.generic) else v[w] for k, v in info.items()}


def render_world(batch: PourBatch, world: int, renderer: mujoco.Renderer) -> np.ndarray:
    """RGB image (H, W, 3) of one world (:func:`render_scene`), seen from the side of the
    pour."""
    cam = mujoco.MjvCamera()
    cam.lookat[:] = [-0.05, 0.0, 0.85]
    cam.distance, cam.azimuth, cam.elevation = 0.75, 90.0, -20.0
    x = batch.solver.positions()[batch.solver.world_slice(world)]
    return render_scene(renderer, batch.world_data(world), cam, x, batch.solver_config.spacing)


def render_scene(
    renderer: mujoco.Renderer,
    data: mujoco.MjData,
    camera: mujoco.MjvCamera,
    particles: np.ndarray,
    spacing: float,
    hidden_groups: Sequence[int] = (),
) -> np.ndarray:
    """RGB image (H, W, 3) of ``data``'s scene from ``camera``: no sites, no geoms of
    ``hidden_groups``, the containers (the only meshes) translucent, and the finite
    ``particles`` (k, 3; m) as spheres of diameter ``spacing``."""
    opt = mujoco.MjvOption()
    opt.sitegroup[:] = 0
    for g in hidden_groups:
        opt.geomgroup[g] = 0
    renderer.update_scene(data, camera=camera, scene_option=opt)
    scene = renderer.scene
    for g in scene.geoms[: scene.ngeom]:
        if g.type == mujoco.mjtGeom.mjGEOM_MESH:
            g.rgba[3] = 0.35
    add_particles(scene, particles, spacing)
    return renderer.render()


def add_particles(scene: mujoco.MjvScene, particles: np.ndarray, spacing: float) -> None:
    """Append the finite ``particles`` (k, 3; m) to ``scene`` as spheres of diameter
    ``spacing``, as many as it has room for."""
    size = np.array([0.5 * spacing, 0.0, 0.0])
    eye = np.eye(3).ravel()
    rgba = np.array([0.2, 0.45, 0.9, 1.0], np.float32)
    for p in particles[np.isfinite(particles).all(1)][: scene.maxgeom - scene.ngeom]:
        sphere = mujoco.mjtGeom.mjGEOM_SPHERE
        mujoco.mjv_initGeom(scene.geoms[scene.ngeom], sphere, size, p.astype(float), eye, rgba)
        scene.ngeom += 1


__all__ = ["PourEnv", "action_space", "observation_space", "render_world"]
