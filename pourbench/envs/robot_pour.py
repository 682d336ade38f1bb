"""``pourbench/PourRobot-v0``: PourNet's task with the robot in the loop (thesis §6.5.3, §6.6.2).

The pouring container is the robot's end-effector. Each environment step (10 Hz):

1. Algorithm 4 (:func:`~pourbench.envs.action_handler.handle_actions`, Pour-v0's handler,
   unchanged) turns the action ``(ω, r)`` into the pouring container's next pose target:
   its base point and its tilt, in the *task frame* (origin at the receiving container's
   base, x toward the receiving container, tilt about +y through the rim centre, as in
   Pour-v0). The task frame's x axis is world +y for both robots: the right hand pours to
   its left.
2. The target becomes an end-effector pose: the rim centre of the pouring container (the
   planner's end-effector site ``pouring_rim``) and its orientation (the home orientation
   tilted about the task frame's y axis).
3. The planner (NMPC-MP, default, or the mink controller) returns the arm's joint
   velocities. At the default 10 Hz it is called once a step (its model period ``ts`` is
   the control period); at slower control rates it is called several times a step toward
   targets interpolated between the handler's poses, so it always runs at >= 10 Hz.
   NMPC-MP runs with an iteration cap and no time budget, so a seed gives the same episode
   on any machine.
4. MuJoCo simulates the robot: the velocities are the integrated-velocity servos' controls
   (``ctrl``), held for the control period's physics substeps. The containers are rigidly
   attached to the grippers (child bodies of the gripper bodies: a perfect weld, no
   contact grasp, no slip).
5. The liquid is coupled two-way to both containers by
   :class:`~pourbench.fluids.coupling.MujocoCoupling`: each substep the colliders take the
   bodies' poses, the liquid steps, and its reaction on each container enters MuJoCo as
   ``xfrc_applied`` for the next substep, so both wrist sensors feel the liquid.

Robots:

* ``robot="movo"``: the right Jaco2 pours; the stationary left arm holds the tray (10 cm
  radius). The weight observation is the left wrist's F/T force, gravity-compensated for the
  gripper (1.435 kg, Table 3.2; :mod:`pourbench.envs.ft_sensor`), tared on the empty tray,
  with 0.15 N noise and the 2nd-order Butterworth low-pass (100 Hz, 1 Hz).
* ``robot="panda"``: the Panda's hand pours into the tray standing on a table scale (the
  same noise and filter).

Safety: the planner keeps its hard clearance (``safety_distance``) between the pouring arm's
collision capsules plus a capsule around the held cup, and the robot's body boxes, the other
arm, the table and the receiving container. The episode ends (terminated) with
``info["collided"]`` when MuJoCo reports a contact (arm and table, container and table,
container and container) or the containers overlap, or the pouring arm, its gripper or the
cup overlaps the rest of the robot (robot links make no MuJoCo contacts with each other),
and with ``info["planner_failed"]`` when the end-effector is further than ``max_pos_error``
/ ``max_rot_error`` from the step's target after the step (``info["planner_qp_failed"]``
reports a QP that failed inside a call, which then returns its last iterate).

One world: the task's state is kept in ``(1, …)`` arrays and goes through Pour-v0's batched
functions (handler, filter, reward, liquid accounting); the planner call, the MuJoCo substeps
and the coupling's pose sync are per world, and there is no vector env.
``render_mode="rgb_array"`` draws the robot, containers and liquid; ``record_path`` writes a
rerun recording of the episode.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.error import ResetNeeded

from pourbench.containers import get_container
from pourbench.envs.action_handler import as_actions, handle_actions
from pourbench.envs.core import (
    check_draws,
    control_substeps,
    default_solver_config,
    draw_amounts,
    liquid_account,
    liquid_features,
    particle_grams,
    pouring_candidates,
    refuse_container,
    thesis_observation,
)
from pourbench.envs.curriculum import draw_liquid, load_curriculum
from pourbench.envs.ft_sensor import gravity_compensate, vertical_load
from pourbench.envs.observation import GRAVITY, WeightFilter, counter_normals
from pourbench.envs.options import ResetOptions, known_liquid
from pourbench.envs.pour_v0 import (
    RENDER_SIZE,
    action_space,
    make_config,
    observation_space,
    render_scene,
)
from pourbench.envs.reward import ErrorHistory, extrinsic_reward
from pourbench.errors import (
    InvalidParameterError,
    UnknownNameError,
    check_finite,
    check_index,
    check_int,
    check_positive,
)
from pourbench.fluids import MujocoCoupling, PBFSolver
from pourbench.fluids.accounting import LiquidCounter
from pourbench.geometry.rotation import (
    axis_angle_quat,
    quat_conj,
    quat_mul,
    rotation_error,
)
from pourbench.planners import (
    MinkController,
    NMPCConfig,
    NMPCPlanner,
    PlanningWorld,
    arm_spec,
)
from pourbench.planners.distance import Box, Obstacle, obstacle_from_mujoco_geom
from pourbench.planners.kinematics import ArmKinematics
from pourbench.planners.robots import joint_speed_limits
from pourbench.scene import ROBOTS, STATIC_CONTYPE, body_clearance, build_pour_scene

PLANNERS: tuple[str, ...] = ("nmpc", "mink")
PLANNER_PERIOD = 0.1
"""Longest planner period, s: the planner runs at >= 10 Hz whatever the control rate."""
CUP_CAPSULE = "pouring_col"
"""The planner's collision capsule of the held cup (geom group 3, no MuJoCo contacts)."""
EE_SITE = "pouring_rim"
# task frame -> world: task x (toward the receiving container) is world +y
_TASK_R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class RobotSettings:
    """Robot-in-the-loop settings (SI units).

    Attributes:
        safety_distance: the planner's hard clearance to every obstacle, m.
        nmpc_max_iter: NMPC-MP's SQP iteration cap per call (no time budget, so runs repeat).
        q_pos, q_quat, pf_pos, pf_quat, r: NMPC-MP's weights. Table 4.2's (5, 0.1, 50, 10, 2)
            trail the handler's moving target by several cm at the 0.1 s control period
            (Table 4.2 predicts with 0.2 s steps toward still goals) and fall far behind a
            full-rate tilt. These (100× the position weights, 2000× / 500× the quaternion
            ones, a tenth of the input weight) track within 1.7 cm and 0.06 rad at the
            handler's full speeds (docs/robot_pour.md).
        max_pos_error: end-effector position error after a step above which the planner has
            failed, m.
        max_rot_error: the same for the orientation, rad.
    """

    safety_distance: float = 0.02
    nmpc_max_iter: int = 5
    q_pos: float = 500.0
    q_quat: float = 200.0
    pf_pos: float = 5000.0
    pf_quat: float = 5000.0
    r: float = 0.2
    max_pos_error: float = 0.05
    max_rot_error: float = 0.35

    def __post_init__(self) -> None:
        check_finite("safety_distance", self.safety_distance, minimum=0.0)
        check_positive("max_pos_error", self.max_pos_error)
        check_positive("max_rot_error", self.max_rot_error)
        check_int("nmpc_max_iter", self.nmpc_max_iter, minimum=1)


def _add_cup_capsule(spec: mujoco.MjSpec, cup: object) -> None:
    """Give the pouring container a planner capsule: its axis from base to rim, radius its
    outer radius (a conservative cover, as the arms' capsules are)."""
    r = 0.5 * cup.diameter  # type: ignore[attr-defined]
    spec.body("pouring").add_geom(
        name=CUP_CAPSULE,
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        fromto=[0.0, 0.0, 0.0, 0.0, 0.0, cup.rim_height],  # type: ignore[attr-defined]
        size=[r, 0.0, 0.0],
        contype=0,
        conaffinity=0,
        group=3,
        mass=0.0,
        rgba=[0.2, 0.4, 1.0, 0.25],
    )


class RobotPourEnv(gym.Env):
    """Pour a target amount with a robot: Pour-v0's task, its spaces, and a planner that
    executes the action handler's end-effector motion (see the module docstring).

    Observation and action: identical to ``pourbench/Pour-v0`` (12 values, 2 values), so a
    Pour-v0 policy runs unchanged. Observation 7 is the wrist (Movo) or table-scale (Panda)
    weight; observation 11 is the handler's tilt (the commanded one, as in Pour-v0; the
    measured tilt is ``info["tilt_measured"]``).

    ``info`` holds Pour-v0's keys plus ``tilt_measured``, ``planner_failed``,
    ``planner_qp_failed``, ``pos_error_m`` and
    ``rot_error_rad`` (end-effector against the step's target),
    ``force_raw_n`` (the weight sensor's vertical force, gravity-compensated, not tared) and
    ``joint_velocity`` (the commanded arm velocities, rad/s).

    Args:
        robot: "movo" (default) or "panda".
        planner: "nmpc" (default) or "mink".
        render_mode: None or "rgb_array" (MuJoCo's offscreen renderer: the robot, the
            containers, translucent, and the liquid's particles as spheres).
        record_path: if given, a rerun ``.rrd`` recording of the episode, one frame per
            reset and step (:mod:`pourbench.envs.robot_record`: particles, bodies, the
            end-effector's target against its pose, joint velocities, the weight reading
            raw and filtered); written to ``<record_path>.partial`` and moved into place by
            :meth:`close`.
        **kwargs: fields of :class:`~pourbench.envs.core.PourConfig`. The pouring container
            is ``container``, else the first of ``container_set`` (the training cup).

    Raises:
        UnknownNameError: unknown robot or planner (a ``ValueError`` naming it and the known
            ones).
        InvalidParameterError: an unknown setting or a bad value.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        robot: str = "movo",
        planner: str = "nmpc",
        settings: RobotSettings | None = None,
        render_mode: str | None = None,
        record_path: str | None = None,
        **kwargs: Any,
    ) -> None:
        if not isinstance(robot, str) or robot not in ROBOTS:
            raise UnknownNameError("robot", robot, ROBOTS)
        if not isinstance(planner, str) or planner not in PLANNERS:
            raise UnknownNameError("planner", planner, PLANNERS)
        if render_mode not in (None, "rgb_array"):
            raise InvalidParameterError(
                f"render_mode must be None or 'rgb_array', got {render_mode!r}"
            )
        cfg = make_config(**kwargs)
        for name in ("shaping", "progress_per_g"):
            if getattr(cfg.reward, name):
                raise InvalidParameterError(
                    f"reward.{name}={getattr(cfg.reward, name)!r}: PourRobot-v0 pours with the "
                    f"policies Pour-v0 trained and has no {name} term; give it Pour-v0's reward "
                    "without it"
                )
        self.default_liquid = None if cfg.liquid is None else known_liquid(cfg.liquid)
        self.settings = settings or RobotSettings()
        self.robot, self.planner_name, self.config = robot, planner, cfg
        self.render_mode = render_mode
        self._renderer: mujoco.Renderer | None = None
        self.observation_space = observation_space()
        self.action_space = action_space()
        self.lessons = load_curriculum(cfg.curriculum)
        self.set_lesson(cfg.lesson)
        self.container = pouring_candidates(cfg)[0]
        self.pour = get_container(self.container)
        self.recv = get_container(cfg.receiving)
        scfg = cfg.solver or default_solver_config()
        self.solver_config = scfg
        check_draws(cfg, [self.container], self.default_liquid, self.lessons, scfg.spacing)
        self.substeps = control_substeps(cfg.control_hz, scfg.dt)
        self.control_dt = self.substeps * scfg.dt
        self.metadata = {**self.metadata, "render_fps": cfg.control_hz}
        # planner calls per step: the fewest that divide the substeps and run it at >= 10 Hz
        self.plans = next(
            k
            for k in range(1, self.substeps + 1)
            if self.substeps % k == 0 and self.control_dt / k <= PLANNER_PERIOD + 1e-9
        )
        self.plan_dt = self.control_dt / self.plans
        # --- MuJoCo
        self.scene = build_pour_scene(self.container, cfg.receiving, robot)
        _add_cup_capsule(self.scene.spec, self.pour)
        self.model = self.scene.spec.compile()
        self.model.opt.timestep = scfg.dt
        self.data = mujoco.MjData(self.model)
        mujoco.mj_resetDataKeyframe(self.model, self.data, self.model.key("home").id)
        mujoco.mj_forward(self.model, self.data)
        self.home_qpos = self.data.qpos.copy()
        m = self.model
        arm = arm_spec("movo" if robot == "movo" else "panda")
        self.arm = arm
        self.capsules = (*arm.capsules, CUP_CAPSULE)
        self.kin = ArmKinematics(m, arm.joints, EE_SITE, self.capsules, base_qpos=self.home_qpos)
        jids = [m.joint(j).id for j in arm.joints]
        self.act_ids = np.array(
            [a for j in jids for a in range(m.nu) if m.actuator_trnid[a, 0] == j], int
        )
        self.act_adr = np.array([m.actuator_actadr[a] for a in self.act_ids], int)
        self.vmax = joint_speed_limits(m, arm.joints, arm.speed_cap)
        self.sensor_force = self.scene.scale_force
        self.sensor_torque = self.scene.scale_torque
        site_name = "left_ft" if robot == "movo" else "scale"
        self.sensor_site = m.site(site_name).id
        # task frame: origin at the receiving container's base at home
        self.origin = self.data.xpos[m.body("receiving").id].copy()
        self.tilt_axis = _TASK_R @ np.array([0.0, 1.0, 0.0])
        self.rim_quat0 = self.kin.ee_pose(self.kin.home())[1]
        self._self_pairs = _SelfCollision(m, arm.joints[0])
        # --- planner
        self.obstacles = self._obstacles()
        ts, s = self.plan_dt, self.settings
        if planner == "nmpc":
            ncfg = NMPCConfig(
                q_pos=s.q_pos,
                q_quat=s.q_quat,
                pf_pos=s.pf_pos,
                pf_quat=s.pf_quat,
                r=s.r,
                ts=ts,
                safety_distance=self.settings.safety_distance,
                max_joint_speed=tuple(self.vmax),
                max_iter=self.settings.nmpc_max_iter,
            )
            self.planner = NMPCPlanner(self.kin, ncfg)
            self.plan_obstacles = self.obstacles
        else:
            statics = (*arm.body_boxes, *arm.other_capsules)
            pw_spec = build_pour_scene(self.container, cfg.receiving, robot).spec
            _add_cup_capsule(pw_spec, self.pour)
            world = PlanningWorld(pw_spec, self.capsules, self._dynamic_obstacles(), statics)
            self.planner = MinkController(
                world, arm.joints, EE_SITE, self.capsules, ts=ts,
                safety_distance=self.settings.safety_distance, max_joint_speed=self.vmax,
                base_qpos=self.home_qpos,
            )  # fmt: skip
            self.plan_obstacles = self._dynamic_obstacles()  # the robot's own geoms are in world
        # --- liquid
        self.solver = PBFSolver(1, scfg)
        self.coupling = MujocoCoupling(self.solver, m, [self.data])
        self.coupling.add_geoms(["table_top"])
        self.pour_col = self.coupling.add_container("pouring", self.pour.shape)[0]
        self.recv_col = self.coupling.add_container("receiving", self.recv.shape)[0]
        self.filter = WeightFilter(
            1, cfg.sensor_rate_hz, cfg.sensor_cutoff_hz, noise_n=cfg.sensor_noise_n
        )
        self.history = ErrorHistory(1, cfg.reward.window)
        self._counter = LiquidCounter(self.solver, [self.pour.shape, self.recv.shape], scfg.spacing)
        self._half = np.array([max(self.recv.mouth_diameter / 2 - self.pour.diameter / 2, 0.01)])
        self.rng: np.random.Generator | None = None
        self.planner_time_s = 0.0  # wall time of the last planner call, s
        self._was_reset = False
        self._done = False
        self._recorder = None
        if record_path is not None:
            from pourbench.envs.robot_record import RobotRecorder

            self._recorder = RobotRecorder(record_path, self)

    def set_lesson(self, k: int) -> None:
        """Draw liquids from curriculum lesson ``k`` at later resets (when ``liquid`` is None)."""
        self.lesson = check_index("lesson", k, len(self.lessons))

    # ------------------------------------------------------------------ geometry

    def _obstacles(self) -> list:
        """Planner obstacles: body boxes and the other arm (Movo), the table top, and a box
        around the receiving container (all still during an episode)."""
        geoms = [*self.arm.body_boxes, *self.arm.other_capsules]
        return [self._geom_obstacle(g) for g in geoms] + self._dynamic_obstacles()

    def _geom_obstacle(self, name: str) -> Obstacle:
        """The planner obstacle of MuJoCo geom ``name`` where it is now."""
        m, d = self.model, self.data
        g = m.geom(name).id
        return obstacle_from_mujoco_geom(
            int(m.geom_type[g]), d.geom_xpos[g], d.geom_xmat[g], m.geom_size[g]
        )

    def _dynamic_obstacles(self) -> list:
        """The obstacles that are not robot geoms: table top and receiving container."""
        table = self._geom_obstacle("table_top")
        r = self.recv.diameter / 2
        h = self.recv.rim_height
        tray = Box(self.origin + np.array([0.0, 0.0, h / 2]), np.array([r, r, h / 2]))
        return [table, tray]

    def _to_world(self, base_task: np.ndarray, tilt: float) -> tuple[np.ndarray, np.ndarray]:
        """End-effector target (rim centre, quaternion w x y z) of a task-frame base point
        and tilt."""
        rim = self.origin + _TASK_R @ (base_task + np.array([0.0, 0.0, self.pour.rim_height]))
        return rim, quat_mul(axis_angle_quat(self.tilt_axis, tilt), self.rim_quat0)

    def _measured(self) -> tuple[np.ndarray, float, np.ndarray]:
        """Rim centre (world), signed tilt about the task's tilt axis (rad), quaternion."""
        p = self.data.site_xpos[self.model.site(EE_SITE).id].copy()
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, self.data.site_xmat[self.model.site(EE_SITE).id])
        # relative rotation from home; its angle about the tilt axis
        rel = quat_mul(q, quat_conj(self.rim_quat0))
        if rel[0] < 0:
            rel = -rel
        tilt = 2.0 * np.arctan2(float(rel[1:] @ self.tilt_axis), rel[0])
        return p, float(tilt), q

    # ------------------------------------------------------------------ reset

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        opts = ResetOptions.parse(options)
        cfg = self.config
        fresh = seed is not None or self.rng is None
        rng = np.random.default_rng(seed) if fresh else copy.deepcopy(self.rng)  # kept if accepted
        if opts.container not in (None, self.container):
            refuse_container(opts.container, (self.container,))
        liquid = opts.liquid if opts.liquid is not None else self.default_liquid
        if liquid is None:
            liquid = draw_liquid(self.lessons, self.lesson, rng, cfg.rehearse)
        spacing = self.solver_config.spacing
        target, initial = draw_amounts(opts, rng, cfg, liquid, self.container, spacing)
        start = opts.start
        if start is None:
            xy = [rng.uniform(*cfg.start_x), rng.uniform(*cfg.start_y)]
            start = np.array([*xy, rng.uniform(*cfg.start_height)])
        # the robot at home, the pouring arm moved to the start by IK (checked before any
        # state changes: a refused reset leaves the episode as it was)
        goal_p, goal_q = self._to_world(start, 0.0)
        q, err = self._ik(self.kin.home(), goal_p, goal_q)
        if err > 2e-3:
            raise InvalidParameterError(
                f"start {start.tolist()} is out of the {self.robot}'s reach (IK error "
                f"{err * 1e3:.1f} mm)"
            )
        super().reset(seed=seed)
        self.rng = rng
        d, m = self.data, self.model
        mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
        d.qpos[self.kin.qadr] = q
        d.act[self.act_adr] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        if isinstance(self.planner, NMPCPlanner):
            self.planner.reset()  # forget the last episode's warm start
        # episode state (arrays of one world)
        self.liquid = liquid
        self.base = start[None].copy()
        self.tilt = np.zeros(1)
        self.max_tilt = np.zeros(1)
        self.measured_tilt = 0.0
        self.target_g = np.array([target])
        self.particle_g = particle_g = particle_grams(liquid, self.solver_config.spacing)
        self.steps = 0
        self.substep_count = 0
        self.started = False
        self.upright_steps = 0
        self.liquid_obs = np.array([liquid_features(liquid)])
        self.noise_key = rng.integers(0, 2**63, dtype=np.uint64)
        self.noise_count = 0
        # liquid
        self.coupling.sync()
        self.solver.clear_world(0)
        self.solver.set_liquid(0, liquid)
        n = self.solver.fill(0, self.pour_col, initial, at_least=True)
        self.initial_g = n * particle_g
        self.solver.step(0)
        d.xfrc_applied[:] = 0.0
        mujoco.mj_forward(m, d)
        self.force_n = self._load_n()
        self.filter.reset(0, self.force_n)  # tared on the empty receiving container
        self._was_reset, self._done = True, False
        info = self._info(self._measure())
        info.update(collided=False, planner_failed=False, sim_diverged=False, is_success=False)
        info["average_error_g"] = float(self.history.average()[0])
        info["completed_episodes"] = int(self.history.count[0])
        info.update(  # a step's keys, in its order: the arm starts still, at its target
            planner_qp_failed=False,
            pos_error_m=0.0,
            rot_error_rad=0.0,
            joint_velocity=np.zeros(len(self.vmax)),
            force_raw_n=float(self.force_n),
        )
        if self._recorder is not None:
            self._recorder.log()
        return self._observe(self.history.average()), info

    def _ik(
        self, q: np.ndarray, goal_p: np.ndarray, goal_q: np.ndarray
    ) -> tuple[np.ndarray, float]:
        """Damped least-squares IK of the pouring arm (rim site) to a pose; (q, pos error)."""
        q = q.copy()
        for _ in range(200):
            s = self.kin.forward(q)
            ep = goal_p - s.ee_pos[0]
            rel = quat_mul(goal_q, quat_conj(s.ee_quat[0]))
            er = 2.0 * rel[1:] * (1.0 if rel[0] >= 0 else -1.0)
            e = np.r_[ep, er]
            if np.linalg.norm(ep) < 1e-5 and np.linalg.norm(er) < 1e-4:
                break
            J = np.r_[s.jac_pos[0], s.jac_rot[0]]
            q = q + J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(6), e)
        return q, float(np.linalg.norm(goal_p - self.kin.forward(q).ee_pos[0]))

    # ------------------------------------------------------------------ step

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._was_reset or self._done:
            when = "before its first reset" if not self._was_reset else "after its episode ended"
            raise ResetNeeded(f"PourRobot-v0 was stepped {when}; call reset() first")
        a = as_actions(action, 1)
        cfg, d, m = self.config, self.data, self.model
        new_base, new_tilt, _ = handle_actions(
            a, self.base, self.tilt, np.zeros((1, 3)), self._half,
            self.recv.rim_height, self.filter.value_g, self.target_g, cfg.tolerance_g,
            self.control_dt, cfg.limits, cfg.action_mode,
        )  # fmt: skip
        if cfg.action_mode == "free":
            new_base[:, 2] = np.maximum(new_base[:, 2], 0.0)
        collided, qp_failed, self.planner_time_s = False, False, 0.0
        rate = self.solver_config.dt * cfg.sensor_rate_hz
        per_plan = self.substeps // self.plans
        for k in range(1, self.plans + 1):  # the planner at >= 10 Hz, targets interpolated
            f = k / self.plans
            base = self.base[0] + f * (new_base[0] - self.base[0])
            tilt = self.tilt[0] + f * (new_tilt[0] - self.tilt[0])
            if k == self.plans:  # exactly the handler's target (a + (b - a) may miss b)
                base, tilt = new_base[0], new_tilt[0]
            goal_p, goal_q = self._to_world(base, float(tilt))
            q0 = d.qpos[self.kin.qadr].copy()
            res = self.planner.plan(q0, goal_p, goal_q, self.plan_obstacles)
            self.planner_time_s += float(res.solve_time_s)  # wall time: kept out of info
            # the QP solvers' SIMD sums depend on where numpy put their arrays (1e-15 rad/s
            # differences between runs): rounding keeps a seed's episode the same
            u = np.clip(np.round(np.asarray(res.u, float), 9), -self.vmax, self.vmax)
            qp_failed |= getattr(res, "status", "") == "qp_failed"
            d.ctrl[self.act_ids] = u
            for _ in range(per_plan):
                mujoco.mj_step(m, d)
                mujoco.mj_kinematics(m, d)
                self.coupling.sync()
                self.solver.step()
                self.coupling.apply()
                collided |= bool(np.any(d.contact.dist[: d.ncon] < 0.0)) if d.ncon else False
                self.substep_count += 1
                s = self.substep_count
                if np.floor(s * rate + 1e-9) > np.floor((s - 1) * rate + 1e-9):
                    self.force_n = self._load_n()
                    noise = counter_normals(
                        np.array([self.noise_key]), np.array([self.noise_count], np.uint64)
                    )
                    self.noise_count += 1
                    self.filter.sample(np.array([0]), np.array([self.force_n]), noise)
        d.ctrl[self.act_ids] = 0.0
        self.base, self.tilt = new_base, new_tilt
        self.max_tilt = np.maximum(self.max_tilt, self.tilt)
        p, self.measured_tilt, quat = self._measured()
        pos_err = float(np.linalg.norm(p - goal_p))
        rot_err = rotation_error(quat, goal_q)
        collided |= body_clearance(m, d, "pouring", "receiving") < 0.0
        collided |= self._self_pairs.overlapping(d)
        s = self.settings
        # the planner failed when the arm no longer follows; a QP that failed inside one
        # SQP call (the call still returns its last iterate) is reported, not fatal
        planner_failed = (pos_err > s.max_pos_error or rot_err > s.max_rot_error) and not collided
        diverged = bool(self.solver.diverged()[0]) or not np.all(np.isfinite(d.qpos))
        info = self._measure()
        self.steps += 1
        if self.max_tilt[0] >= cfg.pour_tilt:
            self.started = True
        upright = self.started and self.tilt[0] <= cfg.upright_tilt
        self.upright_steps = self.upright_steps + 1 if upright else 0
        finished = (
            upright
            and (
                info["in_flight_g"][0] < cfg.stream_stop_g
                or self.upright_steps * self.control_dt >= cfg.settle_time - 1e-9
            )
            and not collided
            and not diverged
            and not planner_failed
        )
        if finished:
            self.history.add(np.array([0]), info["error_g"])
        avg = self.history.average()
        pouring = self.filter.value_g < self.target_g - cfg.tolerance_g
        hit = np.array([collided or planner_failed])
        timed_out = np.array([self.steps >= cfg.max_steps and not (hit[0] or finished or diverged)])
        reward = extrinsic_reward(
            pouring, hit, np.array([finished]), info["error_g"], avg, cfg.max_steps, cfg.reward,
            timed_out,
        )  # fmt: skip
        terminated = (collided or planner_failed or finished) and not diverged
        truncated = (self.steps >= cfg.max_steps and not terminated) or diverged
        self._done = terminated or truncated
        out = self._info(info)
        out.update(
            collided=bool(collided),
            planner_failed=bool(planner_failed),
            sim_diverged=diverged,
            is_success=bool(finished and out["error_g"] <= cfg.reward.success_g),
            average_error_g=float(avg[0]),
            completed_episodes=int(self.history.count[0]),
            planner_qp_failed=bool(qp_failed),
            pos_error_m=pos_err,
            rot_error_rad=rot_err,
            joint_velocity=u.copy(),
            force_raw_n=float(self.force_n),
        )
        if self._recorder is not None:
            self._recorder.log(commanded=u)
        return self._observe(avg), float(reward[0]), bool(terminated), bool(truncated), out

    # ------------------------------------------------------------------ render

    def render(self) -> np.ndarray | None:
        """RGB image (480, 640, 3) of the robot, the containers and the liquid, seen from
        in front of the robot; None unless ``render_mode="rgb_array"``."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, *RENDER_SIZE, max_geom=20000)
        cam = mujoco.MjvCamera()
        cam.lookat[:] = self.origin + np.array([0.0, -0.1, 0.1])
        cam.distance, cam.azimuth, cam.elevation = 1.3, 200.0, -25.0
        x, spacing = self.solver.positions(), self.solver_config.spacing
        # geom group 3: the planner's capsules
        return render_scene(self._renderer, self.data, cam, x, spacing, hidden_groups=(3,))

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._recorder is not None:
            self._recorder.close()
            self._recorder = None

    # ------------------------------------------------------------------ read

    def _load_n(self) -> float:
        """The weight sensor's vertical load, N (gravity-compensated on the Movo)."""
        d = self.data
        f = d.sensor(self.sensor_force).data.copy()[None]
        rot = d.site_xmat[self.sensor_site].reshape(1, 3, 3)
        if self.robot == "movo":
            t = d.sensor(self.sensor_torque).data.copy()[None]
            f, _ = gravity_compensate(f, t, rot)
        return float(vertical_load(f, rot)[0])

    def pouring_wrist_g(self) -> float:
        """The Movo's right wrist F/T, gravity-compensated, as a vertical load in g: the cup
        and the liquid it holds (the liquid's reaction enters MuJoCo through the coupling).

        Raises:
            InvalidParameterError: the robot is not the Movo (the Panda has no wrist sensor).
        """
        if self.robot != "movo":
            raise InvalidParameterError(f"robot {self.robot!r} has no wrist F/T sensor")
        d, m = self.data, self.model
        f = d.sensor("right_ft_force").data.copy()[None]
        t = d.sensor("right_ft_torque").data.copy()[None]
        rot = d.site_xmat[m.site("right_ft").id].reshape(1, 3, 3)
        comp, _ = gravity_compensate(f, t, rot)
        return float(vertical_load(comp, rot)[0] / GRAVITY * 1e3)

    def weight_g_true(self) -> float:
        """Noise-free, unfiltered, tared weight reading after the last step, g."""
        return (self.force_n - self.filter.tare_n[0]) / GRAVITY * 1e3

    def _measure(self) -> dict[str, np.ndarray]:
        m, d = self.model, self.data
        poses = np.empty((1, 2, 7))
        for k, name in enumerate(("pouring", "receiving")):
            b = m.body(name).id
            poses[0, k, :3] = d.xpos[b]
            poses[0, k, 3:] = d.xquat[b]
        counts = self._counter.count(np.array([0]), poses, np.array([[0, 1]]))
        out = liquid_account(*counts, self.particle_g, [self.initial_g], self.target_g)
        out["measured_g"] = self.filter.value_g.copy()
        out["tilt"] = self.tilt.copy()
        out["tilt_measured"] = np.array([self.measured_tilt])
        return out

    def _info(self, info: dict[str, np.ndarray]) -> dict[str, Any]:
        out: dict[str, Any] = {k: float(v[0]) for k, v in info.items()}
        out["liquid"] = self.liquid.name
        out["container"] = self.container
        out["robot"] = self.robot
        out["planner"] = self.planner_name
        return out

    def _observe(self, avg: np.ndarray) -> np.ndarray:
        return thesis_observation(
            self.liquid_obs, self.pour.diameter, self.pour.depth, self.filter.value_g,
            self.target_g, avg, self.tilt,  # the handler's tilt, as Pour-v0 observes it
        )[0]  # fmt: skip

    def ee_target(self) -> tuple[np.ndarray, np.ndarray]:
        """The end-effector pose (rim centre, quaternion w x y z) the handler asked for last."""
        return self._to_world(self.base[0], float(self.tilt[0]))

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The end-effector's measured pose (rim centre, quaternion w x y z)."""
        p, _, q = self._measured()
        return p, q


class _SelfCollision:
    """Overlaps MuJoCo makes no contacts for: the pouring arm (its links from the body of
    joint ``first_joint`` on, its gripper and the held cup) against the rest of the robot
    (body, head, the other arm and its tray), and the cup against the robot. Bounding
    spheres pick the pairs that ``mj_geomDistance`` then measures."""

    def __init__(self, model: mujoco.MjModel, first_joint: str) -> None:
        root = int(model.jnt_bodyid[model.joint(first_joint).id])
        sub = np.zeros(model.nbody, bool)
        for b in range(model.nbody):  # bodies are numbered parents first
            sub[b] = b == root or (b > 0 and sub[model.body_parentid[b]])
        parent = int(model.body_parentid[root])
        solid = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        # floor, table, pedestal: MuJoCo makes the contacts with them
        scenery = (model.geom_contype == STATIC_CONTYPE) & (model.geom_conaffinity == 0)
        body = model.geom_bodyid
        self.a = np.flatnonzero(solid & sub[body])
        self.b = np.flatnonzero(solid & ~scenery & ~sub[body] & (body != parent))
        self.model = model

    def overlapping(self, data: mujoco.MjData) -> bool:
        """Whether a pouring-side geom overlaps a geom of the rest of the robot."""
        m = self.model
        xa, xb = data.geom_xpos[self.a], data.geom_xpos[self.b]
        gap = np.linalg.norm(xa[:, None] - xb[None], axis=2)
        gap -= m.geom_rbound[self.a][:, None] + m.geom_rbound[self.b][None]
        for i, j in zip(*np.nonzero(gap < 0.0), strict=True):
            g1, g2 = int(self.a[i]), int(self.b[j])
            if mujoco.mj_geomDistance(m, data, g1, g2, 0.01, None) < 0.0:
                return True
        return False


__all__ = ["PLANNERS", "RobotPourEnv", "RobotSettings"]
