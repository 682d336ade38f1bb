"""The batched pouring task: one fluid solver, one MuJoCo model, ``num_worlds`` worlds.

Both front-ends drive this class: :class:`~pourbench.envs.pour_v0.PourEnv` is the batch of one,
:class:`~pourbench.envs.vector.PourVectorEnv` the batch of N. Each world has its own random
generator (seeded per world on reset), liquid, pouring container, weight filter, noise key and
episode counters, so world ``k`` of a batch follows the same episode as a batch of one given
world ``k``'s seed.

Scene: the receiving container (``tray`` by default) stands on a table scale at 0.75 m; the
pouring container is a mocap body. Every candidate pouring container of the chosen set is a
mocap body in the one MuJoCo model (those not in use in a world are parked far below the
floor), and each world has one fluid collider for its pouring container whose shell is
swapped on reset. The containers are kinematic: every physics substep the pouring
containers' poses of all worlds, interpolated between control steps, go to the solver in one
call. The step does no per-world Python: the scale reading (the liquid's reaction on the
receiving container, recorded on the solver's device every substep and read back once a
control step), the sensor noise and filter, the liquid accounting, divergence, collision,
reward and observation are array operations over the worlds.
"""

from __future__ import annotations

import copy
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import mujoco
import numpy as np
import warp as wp
from gymnasium.error import ResetNeeded

from pourbench.containers import Container, add_container_body, container_names, get_container
from pourbench.envs.action_handler import ACTION_MODES, ActionLimits, as_actions, handle_actions
from pourbench.envs.curriculum import Lesson, draw_liquid, load_curriculum
from pourbench.envs.observation import GRAVITY, WeightFilter, counter_normals
from pourbench.envs.options import ResetOptions, known_liquid
from pourbench.envs.reward import (
    ErrorHistory,
    RewardConfig,
    extrinsic_reward,
    shaping_potential,
)
from pourbench.errors import (
    CapacityError,
    InvalidParameterError,
    UnknownNameError,
    check_finite,
    check_index,
    check_int,
    check_positive,
)
from pourbench.fluids import (
    LiquidProfile,
    MujocoCoupling,
    PBFSolver,
    SolverConfig,
)
from pourbench.fluids.accounting import LiquidCounter
from pourbench.fluids.coupling import ReactionLog
from pourbench.geometry.fill import container_lattice
from pourbench.geometry.rotation import quat_to_matrix
from pourbench.scene import TABLE_HALF_XY, TABLE_HEIGHT, body_clearance, build_pour_scene


def liquid_account(
    inside: np.ndarray,
    spilled: np.ndarray,
    flight: np.ndarray,
    particle_g: np.ndarray,
    initial_g: np.ndarray,
    target_g: np.ndarray,
) -> dict[str, np.ndarray]:
    """Per-world grams from :class:`pourbench.fluids.accounting.LiquidCounter`'s particle counts
    (``inside``: (n, 2), the pouring then the receiving container): poured, spilled,
    remaining, in flight, the episode's initial and target grams and |poured − target|."""
    poured = inside[:, 1] * particle_g
    return {
        "poured_g": poured,
        "spilled_g": spilled * particle_g,
        "remaining_g": inside[:, 0] * particle_g,
        "in_flight_g": flight * particle_g,
        "initial_g": np.array(initial_g, dtype=float, copy=True),
        "target_g": np.array(target_g, dtype=float, copy=True),
        "error_g": np.abs(poured - target_g),
    }


def particle_grams(liquid: LiquidProfile, spacing: float) -> float:
    """Mass of one particle of ``liquid`` at ``spacing`` (m), g."""
    return liquid.density * spacing**3 * 1e3


def container_capacity_g(container: str, density: float, spacing: float) -> float:
    """Liquid (g) of ``density`` (kg/m³) the container holds at particle ``spacing`` (m)."""
    n = len(container_lattice(get_container(container).shape, spacing))  # cached
    return n * spacing**3 * 1e3 * density


def check_draws(
    cfg: PourConfig,
    candidates: Sequence[str],
    liquid: LiquidProfile | None,
    lessons: Sequence[Lesson],
    spacing: float,
) -> None:
    """Refuse settings under which a reset without options could be refused, so that no
    autoreset ever is. A reset draws a liquid (``liquid``, else from ``lessons``), a container
    of ``candidates`` (one holding the largest target plus the least extra if any does) and a
    target, which must fit that container and weigh at least one particle (at ``spacing``, m).

    Raises:
        CapacityError: a container a reset may draw cannot hold the largest target of the
            lightest liquid; InvalidParameterError: the least target is under one particle
            of the heaviest.
    """
    if liquid is not None:
        lo = hi = liquid.density
    else:
        densities = [lesson.ranges["density"] for lesson in lessons]
        lo, hi = min(d[0] for d in densities), max(d[1] for d in densities)
    least, most = cfg.target_range_g
    holds = {c: 0.85 * container_capacity_g(c, lo, spacing) for c in candidates}
    small = [c for c in candidates if holds[c] < most]
    if small and all(g < most + cfg.extra_range_g[0] for g in holds.values()):
        raise CapacityError(
            f"target_range_g reaches {most:g} g, more than the pouring container "
            f"{small[0]!r} holds of the lightest liquid a reset may draw ({lo:g} kg/m^3): "
            f"{holds[small[0]]:.0f} g, 85 % of its capacity; "
            "narrow target_range_g or choose a larger container"
        )
    particle_g = hi * spacing**3 * 1e3
    if least < particle_g:
        raise InvalidParameterError(
            f"target_range_g starts at {least:g} g, less than one particle ({particle_g:.3g} g "
            f"at {hi:g} kg/m^3 and {spacing * 1e3:g} mm spacing)"
        )


def draw_amounts(
    opts: ResetOptions,
    rng: np.random.Generator,
    cfg: PourConfig,
    liquid: LiquidProfile,
    container: str,
    spacing: float,
) -> tuple[float, float]:
    """An episode's (target_g, initial_g): from reset ``opts`` or drawn from ``cfg``'s ranges,
    checked against one particle's mass (at ``spacing``, m) and 85 % of the pouring
    container's capacity for ``liquid``."""
    target = opts.target_g
    if target is None:  # drawn, at most the initial amount asked for
        low, high = cfg.target_range_g
        if opts.initial_g is not None:
            if opts.initial_g < low:
                raise InvalidParameterError(
                    f"initial_g={opts.initial_g:g} g is less than the least target drawn "
                    f"(target_range_g={cfg.target_range_g!r}); give target_g too"
                )
            high = min(high, opts.initial_g)
        target = float(rng.uniform(low, high))
    particle_g = particle_grams(liquid, spacing)
    if target < particle_g:
        raise InvalidParameterError(
            f"target_g={target:g} g is less than one particle of {liquid.name} "
            f"({particle_g:.3g} g at {spacing * 1e3:g} mm spacing)"
        )
    cap = 0.85 * container_capacity_g(container, liquid.density, spacing)
    holds = (
        f"container {container!r} holds {cap:.0f} g of {liquid.name} at "
        f"{liquid.density:.0f} kg/m^3 (85 % of its capacity)"
    )
    if target > cap:
        raise CapacityError(f"target_g={target:g} g is more than {holds}")
    initial = opts.initial_g
    if initial is None:
        initial = min(target + float(rng.uniform(*cfg.extra_range_g)), cap)
    if initial > cap:
        raise CapacityError(f"initial_g={initial:g} g is more than {holds}")
    if initial < target:
        raise InvalidParameterError(f"initial_g={initial:g} g is less than target_g={target:g} g")
    return target, initial


CONTAINER_SETS: tuple[str, ...] = ("training", "novel")
OBS_SIZE = 12
_PARK = np.array([0.0, 0.0, -5.0])  # unused pouring containers wait here


def control_substeps(control_hz: float, dt: float) -> int:
    """Solver steps (of ``dt`` s) an environment step at ``control_hz`` takes.

    Raises:
        InvalidParameterError: ``control_hz`` is above the solver's rate, or a whole number of
            solver steps would run it more than 1 % away from the rate asked for.
    """
    if control_hz * dt > 1.0 + 1e-9:
        raise InvalidParameterError(
            f"control_hz={control_hz:g} is above the liquid solver's rate ({1.0 / dt:g} Hz): "
            "an environment step is at least one solver step"
        )
    substeps = round(1.0 / (control_hz * dt))
    if abs(1.0 / (substeps * dt) - control_hz) > 0.01 * control_hz:
        near = sorted({1.0 / (k * dt) for k in (max(1, substeps - 1), substeps, substeps + 1)})
        raise InvalidParameterError(
            f"control_hz={control_hz:g} is not a whole number of the liquid solver's "
            f"{1.0 / dt:g} Hz steps; rates near it: {', '.join(f'{r:.4g}' for r in near)} Hz"
        )
    return substeps


def default_solver_config() -> SolverConfig:
    """The environment's default liquid resolution: 8 mm particles (0.51 g of water each),
    120 Hz physics, 3 density iterations, so that an episode runs in seconds on a CPU. A world
    iterates further only while some particle is over 15 % too dense: an ordinary fill of the
    training cup settles within that on its 3 iterations, while a filled bottle or pitcher
    needs more to stand (docs/contact.md).

    Particles are re-sorted every 6 steps, twice per 10 Hz environment step, so a world's
    re-sorts fall on the same substeps of its episode whether or not its batch held it still
    for an autoreset (world ``k`` of a vector env matches the single env bit for bit).

    Water, ink and milk take no implicit viscosity solve (``min_viscous_diffusion``): at their
    viscous diffusion number at this resolution, 3–7e-5, the solve moves no particle
    (docs/performance.md gives what it cost)."""
    return SolverConfig(
        spacing=0.008,
        dt=1.0 / 120.0,
        iterations=3,
        max_density_error=0.15,
        reorder_every=6,
        min_viscous_diffusion=1.0e-3,
    )


@dataclass(frozen=True)
class PourConfig:
    """Task settings (SI units; grams where the name ends in ``_g``).

    Attributes:
        control_hz: policy (environment step) rate, Hz; at least 1 (the thesis' policy runs at
            10 Hz; below that one step would hold most of a pour).
        max_steps: step limit of an episode (Algorithm 5's Max.Number.of.Steps).
        action_mode: "thesis" (Algorithm 4) or "free".
        limits: action scaling and tilt bound.
        tolerance_g: Algorithm 4's ΔL_w, g.
        reward: Algorithm 5's constants.
        target_range_g: target drawn uniformly from this range, g.
        extra_range_g: initial amount = target + a draw from this range, g (capped at 85 % of
            the container's capacity).
        start_x, start_y: ranges of the pouring container's start, m, relative to the
            receiving container's axis.
        start_height: range of the pouring container's base above the receiving one's, m.
        upright_tilt: tilt below which the container counts as upright again, rad.
        pour_tilt: tilt that marks the pour as started, rad.
        stream_stop_g: liquid in flight below which the stream has stopped, g.
        settle_time: time upright after which the stream counts as stopped whatever is still
            "in flight" (drops clinging to a rim), s.
        sensor_rate_hz, sensor_cutoff_hz, sensor_noise_n: the weight filter (Hz, Hz, N).
        receiving: receiving container name.
        container_set: "training" or "novel" (the pouring containers drawn from).
        container: one pouring container by name, from either set (``pourbench
            containers``); it is then the only one, whatever ``container_set`` says.
        liquid: a named profile, or None to draw from the current curriculum lesson.
        lesson: curriculum lesson index used when ``liquid`` is None.
        rehearse: with ``liquid`` None, draw each reset's liquid from a lesson chosen
            uniformly among lessons 0…``lesson``, rather than from ``lesson`` alone.
        curriculum: path of a curriculum TOML file (None: the shipped three lessons).
        solver: fluid solver settings (None: :func:`default_solver_config`).
    """

    control_hz: float = 10.0
    max_steps: int = 250
    action_mode: str = "thesis"
    limits: ActionLimits = field(default_factory=ActionLimits)
    tolerance_g: float = 2.0
    reward: RewardConfig = field(default_factory=RewardConfig)
    target_range_g: tuple[float, float] = (50.0, 200.0)
    extra_range_g: tuple[float, float] = (50.0, 150.0)
    start_x: tuple[float, float] = (-0.30, -0.20)
    start_y: tuple[float, float] = (-0.05, 0.05)
    start_height: tuple[float, float] = (0.10, 0.16)
    upright_tilt: float = 0.05
    pour_tilt: float = 0.3
    stream_stop_g: float = 2.0
    settle_time: float = 1.0
    sensor_rate_hz: float = 100.0
    sensor_cutoff_hz: float = 1.0
    sensor_noise_n: float = 0.15
    receiving: str = "tray"
    container_set: str = "training"
    container: str | None = None
    liquid: str | None = None
    lesson: int = 0
    rehearse: bool = False
    curriculum: str | None = None
    solver: SolverConfig | None = None

    def __post_init__(self) -> None:
        if self.action_mode not in ACTION_MODES:
            raise UnknownNameError("action_mode", self.action_mode, ACTION_MODES)
        if self.container_set not in CONTAINER_SETS:
            raise UnknownNameError("container_set", self.container_set, CONTAINER_SETS)
        if self.container is not None and self.container not in _pouring_sets():
            refuse_container(self.container, ())
        if self.liquid is not None:
            known_liquid(self.liquid)
        for name, kind in (("limits", ActionLimits), ("reward", RewardConfig)):
            if not isinstance(getattr(self, name), kind):
                raise InvalidParameterError(
                    f"{name} must be {kind.__name__}(...), got {getattr(self, name)!r}"
                )
        if self.solver is not None and not isinstance(self.solver, SolverConfig):
            raise InvalidParameterError(
                f"solver must be SolverConfig(...) or None, got {self.solver!r}"
            )
        if not isinstance(self.rehearse, bool):
            raise InvalidParameterError(f"rehearse must be True or False, got {self.rehearse!r}")
        positive = ("control_hz", "pour_tilt", "upright_tilt", "sensor_rate_hz", "sensor_cutoff_hz")
        for name in positive:
            check_positive(name, getattr(self, name))
        if self.control_hz < 1.0:
            raise InvalidParameterError(
                f"control_hz must be >= 1 Hz (an environment step of at most 1 s of "
                f"simulation), got {self.control_hz!r}"
            )
        for name in ("tolerance_g", "stream_stop_g", "settle_time", "sensor_noise_n"):
            check_finite(name, getattr(self, name), minimum=0.0)
        check_int("max_steps", self.max_steps, minimum=1)
        if self.upright_tilt >= self.pour_tilt:
            raise InvalidParameterError(
                f"upright_tilt ({self.upright_tilt!r} rad) must be below pour_tilt "
                f"({self.pour_tilt!r} rad)"
            )
        if self.sensor_cutoff_hz >= self.sensor_rate_hz / 2:
            raise InvalidParameterError(
                f"sensor_cutoff_hz={self.sensor_cutoff_hz!r} must be below half of "
                f"sensor_rate_hz={self.sensor_rate_hz!r} (Nyquist)"
            )
        for name, low in (
            ("target_range_g", 1e-9),
            ("extra_range_g", 0.0),
            ("start_x", None),
            ("start_y", None),
            ("start_height", None),
        ):
            _check_range(name, getattr(self, name), low)
        for name, half in (("start_x", TABLE_HALF_XY[0]), ("start_y", TABLE_HALF_XY[1])):
            if max(abs(v) for v in getattr(self, name)) > half:
                raise InvalidParameterError(
                    f"{name}={getattr(self, name)!r} reaches off the table (within {half} m of "
                    "the receiving container's axis, at the table's centre)"
                )
        if not 0.0 <= self.start_height[0] <= self.start_height[1] <= MAX_START_HEIGHT:
            raise InvalidParameterError(
                f"start_height={self.start_height!r} must lie within 0-{MAX_START_HEIGHT} m "
                "above the receiving container's base"
            )


def thesis_observation(
    liquid: np.ndarray,
    diameter: np.ndarray,
    depth: np.ndarray,
    weight_g: np.ndarray,
    target_g: np.ndarray,
    average_error_g: np.ndarray,
    tilt: np.ndarray,
) -> np.ndarray:
    """(n, 12) float32 observations in the thesis' order: the liquid's five features (n, 5),
    the pouring container's diameter and depth (m), the filtered weight, the target and what
    is left to pour (g), the average error of the earlier episodes (g) and the tilt (rad),
    each (n,). NaN or infinite entries read 0; all are clipped to ±``OBS_BOUND``."""
    obs = np.empty((len(weight_g), OBS_SIZE))
    obs[:, :5] = liquid
    obs[:, 5] = diameter
    obs[:, 6] = depth
    obs[:, 7] = weight_g
    obs[:, 8] = target_g
    obs[:, 9] = target_g - weight_g
    obs[:, 10] = average_error_g
    obs[:, 11] = tilt
    obs = np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(obs, -OBS_BOUND, OBS_BOUND).astype(np.float32)


def _pouring_sets() -> dict[str, str]:
    """Every pouring container's name and its set."""
    return {n: s for s in CONTAINER_SETS for n in container_names(s)}


def pouring_candidates(cfg: PourConfig) -> tuple[str, ...]:
    """The pouring containers a task with ``cfg`` draws from (its scene holds each)."""
    return (cfg.container,) if cfg.container is not None else container_names(cfg.container_set)


def refuse_container(name: object, candidates: tuple[str, ...]) -> None:
    """Raise for a reset's pouring container ``name`` outside the task's ``candidates``:
    saying how to make a task with it when it is a shipped one."""
    sets = _pouring_sets()
    if name in sets:
        raise InvalidParameterError(
            f"pouring container {name!r} ({sets[name]} set) is not in this task's scene, which "
            f"holds {list(candidates)}: make the env with container={name!r}"
        )
    raise UnknownNameError("pouring container", name, [f"{n} ({sets[n]})" for n in sets])


def _check_range(name: str, value: object, minimum: float | None) -> None:
    """``value`` must be (low, high), finite, low <= high, low >= ``minimum``."""
    try:
        low, high = (float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"{name} must be (low, high), got {value!r}") from exc
    check_finite(name, low, minimum=minimum)
    check_finite(name, high)
    if low > high:
        raise InvalidParameterError(f"{name} must be (low, high) with low <= high, got {value!r}")


class ResetDraw(NamedTuple):
    """A world's checked reset, not yet applied (:meth:`PourBatch.draw_reset`): its generator
    after the draws, liquid, pouring container, target and initial grams, base position (m)."""

    rng: np.random.Generator
    liquid: LiquidProfile
    container: str
    target_g: float
    initial_g: float
    base: np.ndarray


@dataclass
class WorldState:
    """Per-world episode draws (the counters of every world are arrays of :class:`PourBatch`)."""

    rng: np.random.Generator
    liquid: LiquidProfile
    container: str
    target_g: float
    initial_g: float


class PourBatch:
    """``num_worlds`` pouring worlds stepped together (see the module docstring).

    The containers are kinematic: the pouring containers' poses for every world are arrays
    handed to the solver in one call a substep, and the scale reads the liquid's reaction on
    the receiving container as the solver sums it (what MuJoCo's force sensor under the
    container reads when that reaction is applied to it). MuJoCo holds the model; a world's
    ``MjData`` is made on demand (:meth:`world_data`) for rendering and collision checks.

    Raises:
        CapacityError: the worlds' estimated memory (:func:`estimate_memory`) exceeds what
            the machine has free; nothing is allocated.
    """

    def __init__(self, num_worlds: int = 1, config: PourConfig | None = None) -> None:
        cfg = config or PourConfig()
        self.default_liquid = None if cfg.liquid is None else known_liquid(cfg.liquid)
        self.config, self.n = cfg, check_int("num_worlds", num_worlds, minimum=1)
        self.lessons: tuple[Lesson, ...] = load_curriculum(cfg.curriculum)
        self.lesson = 0
        self.set_lesson(cfg.lesson)
        scfg = cfg.solver or default_solver_config()
        self.solver_config = scfg
        self.substeps = control_substeps(cfg.control_hz, scfg.dt)
        self.control_dt = self.substeps * scfg.dt
        check_memory(self.n, cfg)  # before anything of the worlds is allocated
        self.candidates = pouring_candidates(cfg)
        check_draws(cfg, self.candidates, self.default_liquid, self.lessons, scfg.spacing)
        # MuJoCo: the first candidate is body "pouring", the others "pouring_<name>"
        scene = build_pour_scene(pouring=self.candidates[0], receiving=cfg.receiving)
        for name in self.candidates[1:]:
            add_container_body(
                scene.spec, scene.spec.worldbody, name, name=f"pouring_{name}", mocap=True
            )
        self.model = scene.spec.compile()
        self.model.opt.timestep = scfg.dt
        self.receiving: Container = scene.receiving
        self.body_names = {
            c: ("pouring" if i == 0 else f"pouring_{c}") for i, c in enumerate(self.candidates)
        }
        self.mocap_id = {
            c: int(self.model.body_mocapid[self.model.body(b).id])
            for c, b in self.body_names.items()
        }
        self._data = mujoco.MjData(self.model)  # the scene at rest: every candidate parked
        self._park_all(self._data)
        mujoco.mj_forward(self.model, self._data)
        self.target_pos = np.array([0.0, 0.0, TABLE_HEIGHT])
        self.solver = PBFSolver(self.n, scfg)
        # the table and the receiving container never move: every world's colliders take
        # their poses from the one resting MjData
        self.coupling = MujocoCoupling(self.solver, self.model, [self._data] * self.n)
        self.coupling.add_geoms(["table_top"])
        self.recv_col = self.coupling.add_container("receiving", self.receiving.shape)
        recv_body = self.model.body("receiving").id
        self.recv_slot = np.array([self.coupling.slots[(w, recv_body)] for w in range(self.n)])
        self.recv_pose = np.array(self.solver.colliders[self.recv_col[0]].pose)
        first = get_container(self.candidates[0])
        self.pour_col = np.array([self.solver.add_container(w, first.shape) for w in range(self.n)])
        self.filter = WeightFilter(
            self.n, cfg.sensor_rate_hz, cfg.sensor_cutoff_hz, noise_n=cfg.sensor_noise_n
        )
        self.history = ErrorHistory(self.n, cfg.reward.window)
        self.reactions = ReactionLog(self.solver, self.substeps)
        # per-candidate geometry (index c of self.candidates)
        boxes = [get_container(c) for c in self.candidates]
        self._shapes = [b.shape for b in boxes] + [self.receiving.shape]
        self._counter = LiquidCounter(self.solver, self._shapes, scfg.spacing)
        self._diameter = np.array([b.diameter for b in boxes])
        self._depth = np.array([b.depth for b in boxes])
        self._rim = np.array([b.rim_height for b in boxes])
        self._half = np.maximum(self.receiving.mouth_diameter / 2 - self._diameter / 2, 0.01)
        self._clearance = _ClearanceCheck(self.model, self._data, self.body_names, "receiving")
        # per-world state
        n = self.n
        self.base = np.zeros((n, 3))
        self.tilt = np.zeros(n)
        self.max_tilt = np.zeros(n)
        self.rim_height = np.zeros(n)  # of each world's pouring container, m
        self.cidx = np.zeros(n, np.int64)  # each world's pouring container (in candidates)
        self.steps = np.zeros(n, np.int64)  # environment steps of the episode
        self.substep_count = np.zeros(n, np.int64)  # physics substeps of the episode
        self.started = np.zeros(n, bool)
        self.upright_steps = np.zeros(n, np.int64)
        self.done = np.zeros(n, bool)
        self.was_reset = np.zeros(n, bool)
        self.target_g = np.zeros(n)
        self.initial_g = np.zeros(n)
        self.particle_g = np.zeros(n)  # mass of one particle, g
        self.potential = np.zeros(n)  # the reward's shaping potential Φ (RewardConfig.shaping)
        self.error_g = np.zeros(n)  # pouring error after the last step, g (progress_per_g)
        self.liquid_obs = np.zeros((n, 5))  # density / 1000, cohesion, tension, viscosity, adhesion
        self.noise_key = np.zeros(n, np.uint64)
        self.noise_count = np.zeros(n, np.uint64)
        self.force_n = np.zeros(n)  # the scale's last noise-free reading (tare 0), N
        self.liquid_names = np.full(n, "", dtype=object)
        self.container_names = np.full(n, "", dtype=object)
        self.worlds: list[WorldState | None] = [None] * n
        self.solver_seconds = 0.0  # wall time inside the solver's steps (see time_solver)
        self._sync = False

    def time_solver(self, synchronize: bool) -> None:
        """Count in ``solver_seconds`` the solver's kernels (``synchronize``: the device is
        synchronised around each step, which costs CUDA its overlap of host and device) or,
        without, the time its calls take on the host (on the CPU, where kernels run inside
        the call, the same)."""
        self._sync = bool(synchronize)

    def _clock(self) -> float:
        if self._sync:
            wp.synchronize_device(self.solver.device)
        return time.perf_counter()

    # ----------------------------------------------------------------------------- setup

    def set_lesson(self, k: int) -> None:
        """Use curriculum lesson ``k`` for liquids drawn at later resets."""
        self.lesson = check_index("lesson", k, len(self.lessons))

    def _park_all(self, d: mujoco.MjData) -> None:
        for i, c in enumerate(self.candidates):
            d.mocap_pos[self.mocap_id[c]] = _PARK + np.array([0.5 * i, 0.0, 0.0])
            d.mocap_quat[self.mocap_id[c]] = [1.0, 0.0, 0.0, 0.0]

    def capacity_g(self, container: str, density: float) -> float:
        """Liquid (g) of ``density`` (kg/m³) the container holds at the solver's spacing."""
        return container_capacity_g(container, density, self.solver_config.spacing)

    def pouring_poses(self, worlds: np.ndarray | list[int] | None = None) -> np.ndarray:
        """Poses (k, 7; m) of ``worlds``' pouring containers (None: all):
        the base's position, tilted by ``tilt`` about the y axis through the rim's centre,
        height ``rim_height`` above the base."""
        w = slice(None) if worlds is None else np.asarray(worlds, int)
        return _rim_poses(self.base[w], self.tilt[w], self.rim_height[w])

    def _place(self, worlds: list[int] | None = None) -> None:
        """Hand the pouring containers' poses of ``worlds`` (None: all) to the solver in one
        call (it sweeps each collider from its last step's pose to this one)."""
        cols = self.pour_col if worlds is None else self.pour_col[np.asarray(worlds, int)]
        self.solver.set_collider_poses(cols, self.pouring_poses(worlds))

    def world_data(self, world: int) -> mujoco.MjData:
        """An ``MjData`` of the scene with ``world``'s pouring container at its pose (the
        other candidates parked), kinematics computed; valid until the next call."""
        w = check_index("world", world, self.n)
        if self.worlds[w] is None:
            raise ResetNeeded(f"world {w} has not been reset")
        d = self._data
        self._park_all(d)
        pose = self.pouring_poses([w])[0]
        mid = self.mocap_id[self.worlds[w].container]
        d.mocap_pos[mid] = pose[:3]
        d.mocap_quat[mid] = pose[3:]
        mujoco.mj_forward(self.model, d)
        return d

    # ----------------------------------------------------------------------------- reset

    def reset_world(
        self, world: int, seed: int | None = None, options: Mapping | ResetOptions | None = None
    ) -> None:
        """Start a new episode in ``world`` (draws from its generator; reseeds it if given);
        a refusal leaves the world as it was (:meth:`draw_reset`)."""
        self.apply_reset(world, self.draw_reset(world, seed, options))

    def draw_reset(
        self, world: int, seed: int | None = None, options: Mapping | ResetOptions | None = None
    ) -> ResetDraw:
        """Check and draw ``world``'s next episode without changing the world: the draws are
        made on a copy of its generator, which :meth:`apply_reset` gives the world. So the
        resets of several worlds can all be checked before any of them is applied."""
        cfg = self.config
        opts = ResetOptions.parse(options)
        old = self.worlds[world]
        fresh = seed is not None or old is None
        rng = np.random.default_rng(seed) if fresh else copy.deepcopy(old.rng)
        liquid = opts.liquid if opts.liquid is not None else self.default_liquid
        if liquid is None:
            liquid = draw_liquid(self.lessons, self.lesson, rng, cfg.rehearse)
        # container: one that holds the drawn range's largest target with room to pour,
        # and in any case the amount asked for
        name = opts.container
        key = "initial_g" if opts.initial_g is not None else "target_g"
        asked = getattr(opts, key)
        if name is None:

            def fits_in(c: str, grams: float) -> bool:
                return self.capacity_g(c, liquid.density) * 0.85 >= grams

            need = cfg.target_range_g[1] + cfg.extra_range_g[0]
            fits = [c for c in self.candidates if fits_in(c, need)] or list(self.candidates)
            if asked is not None:
                fits = [c for c in fits if fits_in(c, asked)] or [
                    c for c in self.candidates if fits_in(c, asked)
                ]
                if not fits:
                    most = max(self.capacity_g(c, liquid.density) for c in self.candidates)
                    group = cfg.container_set if cfg.container is None else repr(cfg.container)
                    raise CapacityError(
                        f"{key}={asked:g} g is more than any {group} "
                        f"pouring container holds: the largest holds {0.85 * most:.0f} g of "
                        f"{liquid.name} at {liquid.density:.0f} kg/m^3 (85 % of its capacity)"
                    )
            name = fits[int(rng.integers(len(fits)))]
        elif name not in self.candidates:
            refuse_container(name, self.candidates)
        target, initial = draw_amounts(opts, rng, cfg, liquid, name, self.solver_config.spacing)
        start = opts.start
        if start is None:
            xy = [rng.uniform(*cfg.start_x), rng.uniform(*cfg.start_y)]
            start = np.array([*xy, rng.uniform(*cfg.start_height)])
        base = self.target_pos + start
        if not (np.all(np.abs(base[:2]) <= TABLE_HALF_XY) and 0.0 <= start[2] <= MAX_START_HEIGHT):
            raise InvalidParameterError(
                f"start {start.tolist()} puts the pouring container's base off the table "
                f"(|x|, |y| of the base within {TABLE_HALF_XY} m of the table's centre) or "
                f"outside 0-{MAX_START_HEIGHT} m above the receiving container's base"
            )
        return ResetDraw(rng, liquid, name, target, initial, base)

    def apply_reset(self, world: int, draw: ResetDraw) -> None:
        """Start ``world``'s episode as :meth:`draw_reset` drew it."""
        rng, liquid, name, target = draw.rng, draw.liquid, draw.container, draw.target_g
        c = self.candidates.index(name)
        self.worlds[world] = WorldState(rng, liquid, name, target, 0.0)
        self.base[world], self.tilt[world], self.max_tilt[world] = draw.base, 0.0, 0.0
        self.rim_height[world], self.cidx[world] = self._rim[c], c
        self.steps[world] = self.substep_count[world] = self.upright_steps[world] = 0
        self.started[world] = self.done[world] = False
        self.was_reset[world] = True
        self.target_g[world] = target
        self.particle_g[world] = particle_g = particle_grams(liquid, self.solver_config.spacing)
        self.liquid_obs[world] = liquid_features(liquid)
        self.liquid_names[world], self.container_names[world] = liquid.name, name
        self.noise_key[world] = rng.integers(0, 2**63, dtype=np.uint64)
        self.noise_count[world] = 0
        self.force_n[world] = 0.0
        self._place([world])
        # liquid
        self.solver.set_container_shape(self.pour_col[world], get_container(name).shape)
        self.solver.clear_world(world)
        self.solver.set_liquid(world, liquid)
        n = self.solver.fill(world, self.pour_col[world], draw.initial_g, at_least=True)
        self.initial_g[world] = self.worlds[world].initial_g = n * particle_g
        self.filter.reset(world, 0.0)  # the empty receiving container weighs 0 g
        self.error_g[world] = self.target_g[world]  # nothing poured yet
        if self.config.reward.shaping:
            self.potential[world] = self.shaping_potential()[world]

    def flush(self) -> None:
        """Upload pending particle/collider changes now, so the next step sweeps every
        collider from its current pose (keeps a batch's worlds independent of resets)."""
        self.solver.step(0)
        if self.reactions.slots != max(self.solver.num_body_slots, 1):  # pragma: no cover
            self.reactions = ReactionLog(self.solver, self.substeps)

    # ------------------------------------------------------------------------------ step

    def step(
        self, actions: np.ndarray, active: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Advance every world by one control step.

        Args:
            actions: (n, 2) ``(ω, r)`` in [-1, 1]; NaN raises ``InvalidParameterError``.
            active: (n,) worlds whose action is applied; the others hold still (their liquid
                still moves) and their reward/flags are meaningless.

        Returns:
            observations (n, 12), rewards (n,), terminated (n,), truncated (n,), infos (dict
            of (n,) arrays).

        Raises:
            ResetNeeded: an active world was never reset, or its episode has ended
                (terminated or truncated); nothing is stepped.
        """
        cfg = self.config
        a = as_actions(actions, self.n)
        active = np.ones(self.n, bool) if active is None else np.asarray(active, bool)
        bad = np.flatnonzero(active & (~self.was_reset | self.done))
        if len(bad):
            w = int(bad[0])
            when = "before its first reset" if not self.was_reset[w] else "after its episode ended"
            raise ResetNeeded(f"world {w} was stepped {when}; call reset() first")
        a = np.where(active[:, None], a, 0.0)
        new_base, new_tilt, _ = handle_actions(
            a,
            self.base,
            self.tilt,
            np.broadcast_to(self.target_pos, (self.n, 3)),
            self._half[self.cidx],
            self.receiving.rim_height,
            self.filter.value_g,
            self.target_g,
            cfg.tolerance_g,
            self.control_dt,
            cfg.limits,
            cfg.action_mode,
        )
        if cfg.action_mode == "free":  # keep the base above the table
            new_base[:, 2] = np.maximum(new_base[:, 2], TABLE_HEIGHT)
        # every substep's poses at once: base and tilt interpolated between control steps
        frac = np.arange(1, self.substeps + 1) / self.substeps
        bases = self.base + frac[:, None, None] * (new_base - self.base)
        tilts = self.tilt + frac[:, None] * (new_tilt - self.tilt)
        poses = _rim_poses(bases, tilts, self.rim_height)  # (substeps, n, 7)
        for k in range(self.substeps):
            self.solver.set_collider_poses(self.pour_col, poses[k])
            t0 = self._clock()
            self.solver.step()
            self.solver_seconds += self._clock() - t0
            self.reactions.record(k)
        self.base, self.tilt = new_base, new_tilt
        self.max_tilt = np.maximum(self.max_tilt, self.tilt)
        self._sense(active)
        return self._evaluate(active)

    def _sense(self, active: np.ndarray) -> None:
        """Feed the scale samples due in the last control step to the weight filter: the
        receiving container's reaction after each substep (one read-back), sampled at
        ``sensor_rate_hz`` on each world's own episode clock, with its noise."""
        cfg, dt = self.config, self.solver_config.dt
        weight = -self.reactions.read()[:, self.recv_slot, 2]  # (substeps, n) N, down = +
        self.force_n = weight[-1].copy()
        s = self.substep_count + np.arange(1, self.substeps + 1)[:, None]  # (substeps, n)
        self.substep_count += self.substeps
        rate = dt * cfg.sensor_rate_hz
        due = (np.floor(s * rate + 1e-9) > np.floor((s - 1) * rate + 1e-9)) & active
        # each due sample's index on its world's noise counter, all drawn in one call
        nth = self.noise_count + np.cumsum(due, 0).astype(np.uint64) - np.uint64(1)
        noise = np.zeros(due.shape)
        noise[due] = counter_normals(np.broadcast_to(self.noise_key, due.shape)[due], nth[due])
        self.noise_count += due.sum(0).astype(np.uint64)
        for k in range(self.substeps):
            idx = np.flatnonzero(due[k])
            if len(idx):
                self.filter.sample(idx, weight[k, idx], noise[k, idx])

    def _evaluate(
        self, active: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        cfg = self.config
        diverged = self.solver.diverged()
        info = self.measure()
        collided = self.collided()
        self.steps += active
        self.started |= active & (self.max_tilt >= cfg.pour_tilt)
        upright = self.started & (self.tilt <= cfg.upright_tilt)
        self.upright_steps = np.where(
            active, np.where(upright, self.upright_steps + 1, 0), self.upright_steps
        )
        finished = (
            self.started
            & (self.tilt <= cfg.upright_tilt)
            & (
                (info["in_flight_g"] < cfg.stream_stop_g)
                | (self.upright_steps * self.control_dt >= cfg.settle_time - 1e-9)
            )
            & ~collided
            & ~diverged
        )
        done_now = np.flatnonzero(finished & active)
        self.history.add(done_now, info["error_g"][done_now])
        avg = self.history.average()
        pouring = self.filter.value_g < info["target_g"] - cfg.tolerance_g
        timed_out = (self.steps >= cfg.max_steps) & ~collided & ~finished & ~diverged
        reward = extrinsic_reward(
            pouring,
            collided,
            finished,
            info["error_g"],
            avg,
            cfg.max_steps,
            cfg.reward,
            timed_out,
            previous_error_g=self.error_g,
        )
        self.error_g = np.where(active, info["error_g"], self.error_g)
        terminated = (collided | finished) & ~diverged
        truncated = ((self.steps >= cfg.max_steps) & ~terminated) | diverged
        if cfg.reward.shaping:  # Φ = 0 at every end the learner does not bootstrap
            potential = np.where(
                terminated | (truncated & ~diverged), 0.0, self.shaping_potential()
            )
            shaped = cfg.reward.shaping_gamma * potential - self.potential
            reward = reward + np.where(active, shaped, 0.0)
            self.potential = np.where(active, potential, self.potential)
        info["collided"] = collided
        info["sim_diverged"] = diverged
        info["is_success"] = finished & (info["error_g"] <= cfg.reward.success_g)
        info["average_error_g"] = avg
        info["completed_episodes"] = self.history.count.copy()
        self.done |= terminated | truncated
        return self.observe(avg), reward.astype(float), terminated, truncated, info

    # ------------------------------------------------------------------------------ read

    def shaping_potential(self) -> np.ndarray:
        """(n,) the reward's shaping potential Φ of every world's state (0 without
        ``RewardConfig.shaping``): the pouring container's horizontal distance from the
        square over the receiving container where Algorithm 4 lets it pour, its tilt, and the
        scale's reading against the target."""
        d_xy = np.abs(self.target_pos[:2] - self.base[:, :2]) - self._half[self.cidx][:, None]
        distance = np.linalg.norm(np.maximum(d_xy, 0.0), axis=1)
        target = np.maximum(self.target_g, 1e-9)  # worlds never reset have no target
        return shaping_potential(
            distance, self.tilt, self.filter.value_g, target, self.config.reward.shaping
        )

    def collided(self) -> np.ndarray:
        """(n,) whether each world's pouring container overlaps the receiving one."""
        return self._clearance.overlapping(self.cidx, self.pouring_poses(), self.was_reset)

    def measure(self) -> dict[str, np.ndarray]:
        """Ground-truth liquid accounting and task numbers per world (grams)."""
        poses = np.empty((self.n, 2, 7))
        poses[:, 0] = self.pouring_poses()
        poses[:, 1] = self.recv_pose
        shape_index = np.stack([self.cidx, np.full(self.n, len(self._shapes) - 1)], 1)
        counts = self._counter.count(np.arange(self.n), poses, shape_index)
        out = liquid_account(*counts, self.particle_g, self.initial_g, self.target_g)
        out["measured_g"] = self.filter.value_g.copy()
        out["liquid"] = self.liquid_names.copy()
        out["container"] = self.container_names.copy()
        out["tilt"] = self.tilt.copy()
        return out

    def observe(self, average_error_g: np.ndarray | None = None) -> np.ndarray:
        """(n, 12) float32 observations in the thesis' order (see ``PourEnv``)."""
        avg = self.history.average() if average_error_g is None else average_error_g
        return thesis_observation(
            self.liquid_obs, self._diameter[self.cidx], self._depth[self.cidx],
            self.filter.value_g, self.target_g, avg, self.tilt,
        )  # fmt: skip

    def reset_info(self) -> dict[str, np.ndarray]:
        """Every world's info as a reset leaves it: its measurements (:meth:`measure`), no
        flag raised, and the average error of its episodes so far, g (the keys and order of a
        step's info)."""
        info = self.measure()
        for key in ("collided", "sim_diverged", "is_success"):
            info[key] = np.zeros(self.n, bool)
        info["average_error_g"] = self.history.average()
        info["completed_episodes"] = self.history.count.copy()
        return info

    def weight_g_true(self, world: int) -> float:
        """Unfiltered, noise-free tared scale reading of ``world`` after its last step, g."""
        w = check_index("world", world, self.n)
        return float(self.force_n[w] / GRAVITY * 1e3)


class _ClearanceCheck:
    """Which worlds' pouring containers overlap the receiving container, for all worlds.

    Bounding spheres (of each body, then of each geom pair) are compared as arrays over the
    worlds; only worlds whose geoms' spheres overlap get MuJoCo's exact geom distances
    (:func:`~pourbench.scene.body_clearance`), in the one ``MjData``.
    """

    def __init__(
        self, model: mujoco.MjModel, data: mujoco.MjData, bodies: dict[str, str], other: str
    ) -> None:
        self.model, self.data = model, data
        self.names = list(bodies.values())
        self.mocap = [int(model.body_mocapid[model.body(b).id]) for b in self.names]
        self.other = other
        rid = model.body(other).id
        rg = np.flatnonzero(model.geom_bodyid == rid)
        self.r_pos = data.geom_xpos[rg].copy()  # the receiving body never moves
        self.r_rad = model.geom_rbound[rg].copy()
        self.r_centre, self.r_radius = _enclosing(self.r_pos, self.r_rad)
        self.r_rel = self.r_pos - self.r_centre
        self.r_sq = (self.r_rel * self.r_rel).sum(1)
        self.local: list[tuple[np.ndarray, np.ndarray, np.ndarray, float]] = []
        for b in self.names:
            g = np.flatnonzero(model.geom_bodyid == model.body(b).id)
            pos, rad = model.geom_pos[g].copy(), model.geom_rbound[g].copy()
            centre, radius = _enclosing(pos, rad)
            self.local.append((pos, rad, centre, radius))

    def overlapping(self, cidx: np.ndarray, poses: np.ndarray, live: np.ndarray) -> np.ndarray:
        """(n,) overlap flags of the worlds whose pouring container is candidate ``cidx``
        at ``poses`` (n, 7); worlds not ``live`` read False."""
        out = np.zeros(len(cidx), bool)
        rot = quat_to_matrix(poses[:, 3:])
        for c in np.unique(cidx[live]):
            pos, rad, centre, radius = self.local[c]
            rows = np.flatnonzero(live & (cidx == c))
            mid = poses[rows, :3] + rot[rows] @ centre
            near = np.linalg.norm(mid - self.r_centre, axis=1) < radius + self.r_radius + _SLACK
            rows = rows[near]
            if not len(rows):
                continue
            # geom centres relative to the receiving body's centre; squared distances by one
            # matrix product (a prefilter: exact distances follow where it passes)
            xg = poses[rows, None, :3] - self.r_centre + np.einsum("wij,gj->wgi", rot[rows], pos)
            d2 = (xg * xg).sum(2)[:, :, None] + self.r_sq[None, None] - 2.0 * (xg @ self.r_rel.T)
            reach = (rad[:, None] + self.r_rad[None] + _SLACK) ** 2
            gap = d2 - reach[None]
            for w in rows[(gap < 0.0).any(axis=(1, 2))]:
                out[w] = self._exact(c, poses[w]) < 0.0
        return out

    def _exact(self, c: int, pose: np.ndarray) -> float:
        d = self.data
        d.mocap_pos[self.mocap[c]] = pose[:3]
        d.mocap_quat[self.mocap[c]] = pose[3:]
        mujoco.mj_kinematics(self.model, d)
        try:
            return body_clearance(self.model, d, self.names[c], self.other)
        finally:
            d.mocap_pos[self.mocap[c]] = _PARK + np.array([0.5 * c, 0.0, 0.0])
            d.mocap_quat[self.mocap[c]] = [1.0, 0.0, 0.0, 0.0]
            mujoco.mj_kinematics(self.model, d)


_SLACK = 1e-4  # m: bounding spheres this close go to the exact check


def _rim_poses(base: np.ndarray, tilt: np.ndarray, rim_height: np.ndarray) -> np.ndarray:
    """Poses (..., 7) of containers whose base point is ``base`` (..., 3),
    tilted by ``tilt`` (...) about the y axis through the rim's centre, ``rim_height`` (m,
    broadcast over the leading axes) above the base."""
    h = np.broadcast_to(rim_height, tilt.shape)
    poses = np.zeros((*tilt.shape, 7))
    poses[..., :3] = base
    poses[..., 2] += h  # the rim's centre, which the tilt keeps in place
    poses[..., 0] += np.sin(tilt) * -h
    poses[..., 2] += np.cos(tilt) * -h
    poses[..., 3], poses[..., 5] = np.cos(tilt / 2), np.sin(tilt / 2)
    return poses


def _enclosing(pos: np.ndarray, rad: np.ndarray) -> tuple[np.ndarray, float]:
    """A sphere (centre, radius) holding every sphere (pos[i], rad[i])."""
    centre = pos.mean(0) if len(pos) else np.zeros(3)
    radius = float(np.max(np.linalg.norm(pos - centre, axis=1) + rad)) if len(pos) else 0.0
    return centre, radius


_HOST_BYTES_PER_PARTICLE = 250  # host copies: the solver's staging and a step's read-back
_DEVICE_BYTES_PER_PARTICLE = 400  # the solver's per-particle arrays besides the lists
_BYTES_PER_LISTED_NEIGHBOUR = {"half": 16, "full": 4}  # list entries (and half's pair cache)
_BYTES_PER_WORLD = 32 * 1024  # colliders, generator, filter and episode state


def estimate_memory(num_worlds: int, config: PourConfig | None = None) -> tuple[int, int]:
    """Upper estimate of the memory ``num_worlds`` worlds take, bytes: (host, device); on the
    CPU both are host memory. Each world is counted at its largest pouring container full
    (the most liquid a reset can ask for)."""
    cfg = config or PourConfig()
    scfg = cfg.solver or default_solver_config()
    worlds = check_int("num_worlds", num_worlds, minimum=1)
    most = max(
        len(container_lattice(get_container(c).shape, scfg.spacing))
        for c in pouring_candidates(cfg)
    )
    mode = scfg.pair_lists
    if mode == "auto":
        mode = "half" if scfg.device == "cpu" else "full"
    per_particle = _DEVICE_BYTES_PER_PARTICLE + _BYTES_PER_LISTED_NEIGHBOUR[mode] * int(
        scfg.max_neighbours
    )
    particles = worlds * most
    host = particles * _HOST_BYTES_PER_PARTICLE + worlds * _BYTES_PER_WORLD
    return host, particles * per_particle


def available_memory(device: str = "cpu") -> int:
    """Free memory (bytes) of the host (``"cpu"``) or of a CUDA device."""
    if device != "cpu":
        return int(wp.get_device(device).free_memory)
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def check_memory(num_worlds: int, config: PourConfig | None = None) -> None:
    """Refuse ``num_worlds`` worlds whose :func:`estimate_memory` exceeds the free memory.

    Raises:
        CapacityError: with the estimate and what is free.
    """
    cfg = config or PourConfig()
    device = (cfg.solver or default_solver_config()).device
    host, dev = estimate_memory(num_worlds, cfg)
    if device == "cpu":
        host, dev = host + dev, 0
    checks = [("host", host, available_memory("cpu"))]
    if dev:
        checks.append((device, dev, available_memory(device)))
    for where, need, free in checks:
        if need > free:
            raise CapacityError(
                f"num_envs={num_worlds} does not fit: about {need / 2**30:.3g} GiB of {where} "
                f"memory estimated ({need / num_worlds / 2**20:.3g} MiB a world at its largest "
                f"pouring container full), {free / 2**30:.3g} GiB free"
            )


OBS_BOUND = 1e4
MAX_START_HEIGHT = 0.5
"""Highest start of the pouring container's base above the receiving one's, m."""


def viscosity_feature(liquid: LiquidProfile) -> float:
    """The observation's viscosity: log10 of the dynamic viscosity in mPa·s (water 0, honey 4,
    ketchup 4.4), a scale on which the liquids a policy meets are evenly spread."""
    return math.log10(liquid.viscosity_pa_s * 1e3)


def liquid_features(liquid: LiquidProfile) -> list[float]:
    """The observation's five liquid values: density (g/ml), FleX's cohesion and surface
    tension, :func:`viscosity_feature`, FleX's adhesion."""
    return [
        liquid.density / 1000.0,
        liquid.cohesion,
        liquid.surface_tension,
        viscosity_feature(liquid),
        liquid.adhesion,
    ]
