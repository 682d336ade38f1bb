"""The batched pouring task: one fluid solver, one MuJoCo model, ``num_worlds`` worlds.

Both front-ends drive this class: :class:`~pourbench.envs.pour.PourEnv` is the batch of one,
:class:`~pourbench.envs.vector.PourVectorEnv` the batch of N. Each world has its own random
generator (seeded per world on reset), liquid, pouring container, MjData, weight filter and
episode counters, so world ``k`` of a batch follows the same episode as a batch of one given
world ``k``'s seed.

Scene: the receiving container (``tray`` by default) stands on a table scale at 0.75 m; the
pouring container is a mocap body. Every candidate pouring container of the chosen set is a
mocap body in the one MuJoCo model (those not in use in a world are parked far below the
floor), and each world has one fluid collider for its pouring container whose shell is
swapped on reset. Poses are set kinematically every physics substep, interpolated between
control steps.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import mujoco
import numpy as np
from gymnasium.error import ResetNeeded

from pourbench.containers import Container, container_names, get_container
from pourbench.envs.action_handler import ACTION_MODES, ActionLimits, as_actions, handle_actions
from pourbench.envs.curriculum import Lesson, load_curriculum
from pourbench.envs.observation import GRAVITY, WeightFilter
from pourbench.envs.reward import ErrorHistory, RewardConfig, extrinsic_reward
from pourbench.errors import (
    CapacityError,
    InvalidParameterError,
    UnknownNameError,
    check_finite,
    check_index,
    check_positive,
)
from pourbench.fluids import (
    LiquidProfile,
    MujocoCoupling,
    PBFSolver,
    SolverConfig,
    liquid_metrics_all,
    liquid_names,
    liquid_profile,
)
from pourbench.fluids.solver import container_lattice
from pourbench.scene import TABLE_HALF_XY, TABLE_HEIGHT, body_clearance, build_pour_scene

CONTAINER_SETS: tuple[str, ...] = ("training", "novel")
OBS_SIZE = 12
_PARK = np.array([0.0, 0.0, -5.0])  # unused pouring containers wait here


def default_solver_config() -> SolverConfig:
    """The environment's default liquid resolution: 8 mm particles (0.51 g of water each),
    120 Hz physics, 3 density iterations, so that an episode runs in seconds on a CPU."""
    return SolverConfig(spacing=0.008, dt=1.0 / 120.0, iterations=3)


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
        liquid: a named profile, or None to draw from the current curriculum lesson.
        lesson: curriculum lesson index used when ``liquid`` is None.
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
    liquid: str | None = None
    lesson: int = 0
    curriculum: str | None = None
    solver: SolverConfig | None = None

    def __post_init__(self) -> None:
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
        if isinstance(self.max_steps, bool) or not isinstance(self.max_steps, int | np.integer):
            raise InvalidParameterError(f"max_steps must be an integer, got {self.max_steps!r}")
        if self.max_steps < 1:
            raise InvalidParameterError(
                f"max_steps must be an integer >= 1, got {self.max_steps!r}"
            )
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


@dataclass
class WorldState:
    """Per-world episode state."""

    rng: np.random.Generator
    liquid: LiquidProfile
    container: str
    target_g: float
    initial_g: float
    steps: int = 0
    substeps: int = 0
    started: bool = False
    upright_steps: int = 0
    done: bool = False


class PourBatch:
    """``num_worlds`` pouring worlds stepped together (see the module docstring).

    Args:
        num_worlds: number of worlds.
        config: task settings.
    """

    def __init__(self, num_worlds: int = 1, config: PourConfig | None = None) -> None:
        cfg = config or PourConfig()
        if cfg.action_mode not in ACTION_MODES:
            raise ValueError(f"unknown action_mode {cfg.action_mode!r}; known: {ACTION_MODES}")
        if cfg.container_set not in CONTAINER_SETS:
            raise ValueError(
                f"unknown container_set {cfg.container_set!r}; known: {list(CONTAINER_SETS)}"
            )
        if cfg.liquid is not None:
            _known_liquid(cfg.liquid)
        self.config, self.n = cfg, int(num_worlds)
        self.lessons: tuple[Lesson, ...] = load_curriculum(cfg.curriculum)
        self.lesson = 0
        self.set_lesson(cfg.lesson)
        scfg = cfg.solver or default_solver_config()
        self.solver_config = scfg
        if cfg.control_hz * scfg.dt > 1.0 + 1e-9:
            raise InvalidParameterError(
                f"control_hz={cfg.control_hz:g} is above the liquid solver's rate "
                f"({1.0 / scfg.dt:g} Hz): an environment step is at least one solver step"
            )
        self.substeps = max(1, round(1.0 / (cfg.control_hz * scfg.dt)))
        self.control_dt = self.substeps * scfg.dt
        self.candidates = container_names(cfg.container_set)
        # MuJoCo: the first candidate is body "pouring", the others "pouring_<name>"
        scene = build_pour_scene(pouring=self.candidates[0], receiving=cfg.receiving)
        from pourbench.containers import add_container_body

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
        self.sensor_adr = int(self.model.sensor(scene.scale_force).adr[0])
        self.datas = [mujoco.MjData(self.model) for _ in range(self.n)]
        for d in self.datas:
            self._park_all(d)
            mujoco.mj_forward(self.model, d)
        self.target_pos = np.array([0.0, 0.0, TABLE_HEIGHT])
        self.solver = PBFSolver(self.n, scfg)
        self.coupling = MujocoCoupling(self.solver, self.model, self.datas)
        self.coupling.add_geoms(["table_top"])
        self.recv_col = self.coupling.add_container("receiving", self.receiving.shape)
        first = get_container(self.candidates[0])
        self.pour_col = [self.solver.add_container(w, first.shape) for w in range(self.n)]
        self.filter = WeightFilter(
            self.n, cfg.sensor_rate_hz, cfg.sensor_cutoff_hz, noise_n=cfg.sensor_noise_n
        )
        self.history = ErrorHistory(self.n, cfg.reward.window)
        self.base = np.zeros((self.n, 3))
        self.tilt = np.zeros(self.n)
        self.max_tilt = np.zeros(self.n)
        self.rim_height = np.zeros(self.n)  # of each world's pouring container, m
        self.worlds: list[WorldState | None] = [None] * self.n

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
        spacing = self.solver_config.spacing
        n = len(container_lattice(get_container(container).shape, spacing))  # cached
        return n * spacing**3 * 1e3 * density  # g

    def pouring_poses(self, worlds: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Body positions (k, 3; m) and quaternions (k, 4; w, x, y, z) of ``worlds``' pouring
        containers: the base's position, tilted by ``tilt`` about the y axis through the rim's
        centre, height ``rim_height`` above the base."""
        w = np.asarray(worlds, int)
        h, th = self.rim_height[w], self.tilt[w]
        pos = self.base[w]  # a copy (fancy indexing)
        pos[:, 2] += h  # the rim's centre, which the tilt keeps in place
        pos[:, 0] += np.sin(th) * -h
        pos[:, 2] += np.cos(th) * -h
        quat = np.zeros((len(w), 4))
        quat[:, 0], quat[:, 2] = np.cos(th / 2), np.sin(th / 2)
        return pos, quat

    def _place(self, worlds: list[int]) -> None:
        """Set the pouring containers' poses (:meth:`pouring_poses`) of ``worlds`` in MuJoCo
        and in the fluid colliders, the latter in one call."""
        pos, quat = self.pouring_poses(worlds)
        for k, w in enumerate(worlds):
            mid = self.mocap_id[self.worlds[w].container]
            self.datas[w].mocap_pos[mid] = pos[k]
            self.datas[w].mocap_quat[mid] = quat[k]
        # the solver sweeps each collider from its last step's pose to this one
        poses = np.empty((len(worlds), 7))  # x y z qx qy qz qw
        poses[:, :3], poses[:, 3:6], poses[:, 6] = pos, quat[:, 1:], quat[:, 0]
        self.solver.set_collider_poses([self.pour_col[w] for w in worlds], poses)

    # ----------------------------------------------------------------------------- reset

    def reset_world(self, world: int, seed: int | None = None, options: dict | None = None) -> None:
        """Start a new episode in ``world`` (draws from its generator; reseeds it if given)."""
        cfg = self.config
        old = self.worlds[world]
        rng = np.random.default_rng(seed) if (seed is not None or old is None) else old.rng
        if options is not None and not isinstance(options, Mapping):
            raise InvalidParameterError(
                f"reset options must be a dict such as {{'liquid': 'water'}}, got {options!r}"
            )
        opts = dict(options or {})
        unknown = set(opts) - {"liquid", "target_g", "container", "initial_g", "start"}
        if unknown:
            raise ValueError(
                f"unknown reset options {sorted(unknown)}; known: "
                "['container', 'initial_g', 'liquid', 'start', 'target_g']"
            )
        # liquid
        liq = opts.get("liquid", cfg.liquid)
        if liq is None:
            liquid = self.lessons[self.lesson].sample(rng)
        else:
            liquid = _known_liquid(liq)
        # container: one that holds the drawn range's largest target with room to pour,
        # and in any case the amount asked for
        name = opts.get("container")
        key = "initial_g" if "initial_g" in opts else "target_g"
        asked = None if opts.get(key) is None else check_finite(key, opts[key])
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
                    raise CapacityError(
                        f"{key}={asked:g} g is more than any {cfg.container_set} "
                        f"pouring container holds: the largest holds {0.85 * most:.0f} g of "
                        f"{liquid.name} at {liquid.density:.0f} kg/m^3 (85 % of its capacity)"
                    )
            name = fits[int(rng.integers(len(fits)))]
        elif name not in self.candidates:
            raise UnknownNameError("pouring container", name, self.candidates)
        # amounts
        target = opts.get("target_g")
        if target is None:
            target = float(rng.uniform(*cfg.target_range_g))
        target = check_positive("target_g", target)
        particle_g = liquid.density * self.solver_config.spacing**3 * 1e3
        if target < particle_g:
            raise ValueError(
                f"target_g={target:g} g is less than one particle of {liquid.name} "
                f"({particle_g:.3g} g at {self.solver_config.spacing * 1e3:g} mm spacing)"
            )
        cap = 0.85 * self.capacity_g(name, liquid.density)
        holds = (
            f"container {name!r} holds {cap:.0f} g of {liquid.name} at "
            f"{liquid.density:.0f} kg/m^3 (85 % of its capacity)"
        )
        if target > cap:
            raise CapacityError(f"target_g={target:g} g is more than {holds}")
        initial = opts.get("initial_g")
        if initial is None:
            initial = min(target + float(rng.uniform(*cfg.extra_range_g)), cap)
        initial = check_finite("initial_g", initial)
        if initial > cap:
            raise CapacityError(f"initial_g={initial:g} g is more than {holds}")
        if initial < target:
            raise ValueError(f"initial_g={initial:g} g is less than target_g={target:g} g")
        start = opts.get("start")
        if start is None:
            start = [
                rng.uniform(*cfg.start_x),
                rng.uniform(*cfg.start_y),
                rng.uniform(*cfg.start_height),
            ]
        start = np.asarray(start, float)
        if start.shape != (3,) or not np.all(np.isfinite(start)):
            raise ValueError(
                f"start must be three finite numbers (x, y, height of the pouring container's "
                f"base relative to the receiving container's, m), got {opts.get('start')!r}"
            )
        base = self.target_pos + start
        if not (np.all(np.abs(base[:2]) <= TABLE_HALF_XY) and 0.0 <= start[2] <= MAX_START_HEIGHT):
            raise ValueError(
                f"start {start.tolist()} puts the pouring container's base off the table "
                f"(|x|, |y| of the base within {TABLE_HALF_XY} m of the table's centre) or "
                f"outside 0-{MAX_START_HEIGHT} m above the receiving container's base"
            )
        # MuJoCo world
        d = self.datas[world]
        mujoco.mj_resetData(self.model, d)
        self._park_all(d)
        self.worlds[world] = WorldState(rng, liquid, name, target, 0.0)
        self.base[world], self.tilt[world], self.max_tilt[world] = base, 0.0, 0.0
        self.rim_height[world] = get_container(name).rim_height
        self._place([world])
        mujoco.mj_forward(self.model, d)
        self.coupling.sync()
        # liquid
        self.solver.set_container_shape(self.pour_col[world], get_container(name).shape)
        self.solver.clear_world(world)
        self.solver.set_liquid(world, liquid)
        n = self.solver.fill(world, self.pour_col[world], initial)
        self.worlds[world].initial_g = n * self.solver.particle_mass(world) * 1e3
        self.filter.reset(world, float(d.sensordata[self.sensor_adr + 2]))

    def flush(self) -> None:
        """Upload pending particle/collider changes now, so the next step sweeps every
        collider from its current pose (keeps a batch's worlds independent of resets)."""
        self.solver.step(0)

    # ------------------------------------------------------------------------------ step

    def step(
        self, actions: np.ndarray, active: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Advance every world by one control step.

        Args:
            actions: (n, 2) ``(ω, r)`` in [-1, 1]; NaN raises ``ValueError``.
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
        for w in np.flatnonzero(active):
            st = self.worlds[w]
            if st is None or st.done:
                when = "before its first reset" if st is None else "after its episode ended"
                raise ResetNeeded(f"world {w} was stepped {when}; call reset() first")
        a = np.where(active[:, None], a, 0.0)
        recv = self.receiving
        pour = [get_container(w.container) for w in self.worlds]
        half = np.array([max(recv.mouth_diameter / 2 - p.diameter / 2, 0.01) for p in pour])
        target_g = np.array([w.target_g for w in self.worlds])
        new_base, new_tilt, _ = handle_actions(
            a,
            self.base,
            self.tilt,
            np.broadcast_to(self.target_pos, (self.n, 3)),
            half,
            recv.rim_height,
            self.filter.value_g,
            target_g,
            cfg.tolerance_g,
            self.control_dt,
            cfg.limits,
            cfg.action_mode,
        )
        if cfg.action_mode == "free":  # keep the base above the table
            new_base[:, 2] = np.maximum(new_base[:, 2], TABLE_HEIGHT)
        old_base, old_tilt = self.base.copy(), self.tilt.copy()
        dt = self.solver_config.dt
        for k in range(1, self.substeps + 1):
            f = k / self.substeps
            self.base = old_base + f * (new_base - old_base)
            self.tilt = old_tilt + f * (new_tilt - old_tilt)
            self._place(list(range(self.n)))
            self.coupling.step(1)
            for w in self.worlds:
                w.substeps += 1
            idx = np.array(
                [
                    i
                    for i, w in enumerate(self.worlds)
                    if active[i]
                    and math.floor(w.substeps * dt * cfg.sensor_rate_hz + 1e-9)
                    > math.floor((w.substeps - 1) * dt * cfg.sensor_rate_hz + 1e-9)
                ],
                dtype=int,
            )
            if len(idx):
                force = np.array([self.datas[i].sensordata[self.sensor_adr + 2] for i in idx])
                noise = np.array([self.worlds[i].rng.standard_normal() for i in idx])
                self.filter.sample(idx, force, noise)
        self.base, self.tilt = new_base, new_tilt
        self.max_tilt = np.maximum(self.max_tilt, self.tilt)
        return self._evaluate(active)

    def _evaluate(
        self, active: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        cfg = self.config
        diverged = self.solver.diverged()
        info = self.measure()
        collided = np.zeros(self.n, bool)
        for w in range(self.n):
            name = self.body_names[self.worlds[w].container]
            collided[w] = body_clearance(self.model, self.datas[w], name, "receiving") < 0.0
        for w, st in enumerate(self.worlds):
            if active[w]:
                st.steps += 1
                st.started |= bool(self.max_tilt[w] >= cfg.pour_tilt)
                upright = st.started and self.tilt[w] <= cfg.upright_tilt
                st.upright_steps = st.upright_steps + 1 if upright else 0
        steps = np.array([w.steps for w in self.worlds])
        started = np.array([w.started for w in self.worlds])
        finished = (
            started
            & (self.tilt <= cfg.upright_tilt)
            & (
                (info["in_flight_g"] < cfg.stream_stop_g)
                | (
                    np.array([w.upright_steps for w in self.worlds]) * self.control_dt
                    >= cfg.settle_time - 1e-9
                )
            )
            & ~collided
            & ~diverged
        )
        for w in np.flatnonzero(finished & active):
            self.history.add(int(w), float(info["error_g"][w]))
        avg = self.history.average()
        pouring = self.filter.value_g < info["target_g"] - cfg.tolerance_g
        reward = extrinsic_reward(
            pouring, collided, finished, info["error_g"], avg, cfg.max_steps, cfg.reward
        )
        terminated = (collided | finished) & ~diverged
        truncated = ((steps >= cfg.max_steps) & ~terminated) | diverged
        info["collided"] = collided
        info["sim_diverged"] = diverged
        info["is_success"] = finished & (info["error_g"] <= cfg.reward.success_g)
        info["average_error_g"] = avg
        for w in np.flatnonzero(terminated | truncated):
            self.worlds[w].done = True
        return self.observe(), reward.astype(float), terminated, truncated, info

    # ------------------------------------------------------------------------------ read

    def measure(self) -> dict[str, np.ndarray]:
        """Ground-truth liquid accounting and task numbers per world (grams)."""
        keys = ("poured_g", "spilled_g", "remaining_g", "in_flight_g", "initial_g", "target_g")
        out = {k: np.zeros(self.n) for k in keys}
        cups = {w: [self.pour_col[w], self.recv_col[w]] for w in range(self.n)}
        metrics = liquid_metrics_all(self.solver, cups)  # one read of the particles
        for (w, st), m in zip(enumerate(self.worlds), metrics, strict=True):
            out["remaining_g"][w], out["poured_g"][w] = m.inside_g
            out["spilled_g"][w], out["in_flight_g"][w] = m.spilled_g, m.in_flight_g
            out["initial_g"][w], out["target_g"][w] = st.initial_g, st.target_g
        out["error_g"] = np.abs(out["poured_g"] - out["target_g"])
        out["measured_g"] = self.filter.value_g.copy()
        out["liquid"] = np.array([w.liquid.name for w in self.worlds], dtype=object)
        out["container"] = np.array([w.container for w in self.worlds], dtype=object)
        out["tilt"] = self.tilt.copy()
        return out

    def observe(self) -> np.ndarray:
        """(n, 12) float32 observations in the thesis' order (see ``PourEnv``)."""
        obs = np.zeros((self.n, OBS_SIZE))
        avg = self.history.average()
        for w, st in enumerate(self.worlds):
            liq, c = st.liquid, get_container(st.container)
            weight = self.filter.value_g[w]
            obs[w] = [
                liq.density / 1000.0,
                liq.cohesion,
                liq.surface_tension,
                liq.viscosity,
                liq.adhesion,
                c.diameter,
                c.depth,
                weight,
                st.target_g,
                st.target_g - weight,
                avg[w],
                self.tilt[w],
            ]
        obs = np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0)
        return np.clip(obs, -OBS_BOUND, OBS_BOUND).astype(np.float32)

    def weight_g_true(self, world: int) -> float:
        """Unfiltered, noise-free tared scale reading of ``world``, g."""
        fz = self.datas[world].sensordata[self.sensor_adr + 2]
        return float((fz - self.filter.tare_n[world]) / GRAVITY * 1e3)


OBS_BOUND = 1e4
MAX_START_HEIGHT = 0.5
"""Highest start of the pouring container's base above the receiving one's, m."""


def _known_liquid(liquid: str | LiquidProfile) -> LiquidProfile:
    """The profile for ``liquid``; a ``ValueError`` listing the known names otherwise."""
    try:
        return liquid_profile(liquid)
    except UnknownNameError:
        raise
    except Exception as exc:  # e.g. a non-string
        raise UnknownNameError("liquid", liquid, liquid_names()) from exc
