"""A world-by-world Pour-v0 step, the timing baseline of the batched one.

:class:`LoopedPourBatch` is a :class:`~pourbench.envs.core.PourBatch` whose step does the
batched step's work world by world: every substep it sets each world's mocap pose in its
own ``MjData``, steps MuJoCo once per world, reads every world's body poses into the
colliders and writes the liquid's wrenches back (:class:`~pourbench.fluids.MujocoCoupling`),
and samples each due sensor with a draw from that world's generator; after the substeps it
checks each world's clearance with MuJoCo, measures the liquid through per-world
:class:`~pourbench.fluids.LiquidMetrics` and builds each world's observation row. The
liquid solver is the same one, so ``pourbench bench env`` times the two steps against each
other in the same process. It is a benchmark reference, not an environment: its episodes
are not the environment's (the scale reads MuJoCo's sensor one substep late, the noise
comes from other draws).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from pourbench.containers import get_container
from pourbench.envs.action_handler import as_actions, handle_actions
from pourbench.envs.core import OBS_BOUND, OBS_SIZE, PourBatch, PourConfig, viscosity_feature
from pourbench.envs.reward import extrinsic_reward
from pourbench.fluids import MujocoCoupling, liquid_metrics_all
from pourbench.scene import TABLE_HEIGHT, body_clearance


class LoopedPourBatch(PourBatch):
    """``num_worlds`` worlds stepped with the per-world loops of the old step (see the
    module docstring); reset and settings as :class:`PourBatch`."""

    def __init__(self, num_worlds: int = 1, config: PourConfig | None = None) -> None:
        super().__init__(num_worlds, config)
        self.datas = [mujoco.MjData(self.model) for _ in range(self.n)]
        for d in self.datas:
            self._park_all(d)
            mujoco.mj_forward(self.model, d)
        # the same colliders, bound to one MjData per world
        self.looped = MujocoCoupling(self.solver, self.model, self.datas)
        self.looped.bindings = self.coupling.bindings
        self.looped.slots = self.coupling.slots
        scale = self.model.sensor("scale_force").id
        self.sensor_adr = int(self.model.sensor_adr[scale])

    def reset_world(self, world: int, seed: int | None = None, options: dict | None = None) -> None:
        super().reset_world(world, seed, options)
        d = self.datas[world]
        mujoco.mj_resetData(self.model, d)
        self._park_all(d)
        self._place_looped([world])
        mujoco.mj_forward(self.model, d)
        self.looped.sync()
        self.filter.reset(world, float(d.sensordata[self.sensor_adr + 2]))

    def _place_looped(self, worlds: list[int]) -> None:
        poses = self.pouring_poses(worlds)
        for k, w in enumerate(worlds):
            mid = self.mocap_id[self.worlds[w].container]
            self.datas[w].mocap_pos[mid] = poses[k, :3]
            self.datas[w].mocap_quat[mid] = poses[k, 3:]
        self.solver.set_collider_poses([self.pour_col[w] for w in worlds], poses)

    def step(
        self, actions: np.ndarray, active: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        cfg = self.config
        a = as_actions(actions, self.n)
        active = np.ones(self.n, bool) if active is None else np.asarray(active, bool)
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
        if cfg.action_mode == "free":
            new_base[:, 2] = np.maximum(new_base[:, 2], TABLE_HEIGHT)
        old_base, old_tilt = self.base.copy(), self.tilt.copy()
        dt = self.solver_config.dt
        for k in range(1, self.substeps + 1):
            f = k / self.substeps
            self.base = old_base + f * (new_base - old_base)
            self.tilt = old_tilt + f * (new_tilt - old_tilt)
            self._place_looped(list(range(self.n)))
            for d in self.datas:
                mujoco.mj_step(self.model, d)
                mujoco.mj_kinematics(self.model, d)
            self.looped.sync()
            t0 = self._clock()
            self.solver.step()
            self.solver_seconds += self._clock() - t0
            self.looped.apply()
            s = self.substep_count + 1
            self.substep_count = s
            idx = np.array(
                [
                    i
                    for i in range(self.n)
                    if active[i]
                    and math.floor(s[i] * dt * cfg.sensor_rate_hz + 1e-9)
                    > math.floor((s[i] - 1) * dt * cfg.sensor_rate_hz + 1e-9)
                ],
                dtype=int,
            )
            if len(idx):
                force = np.array([self.datas[i].sensordata[self.sensor_adr + 2] for i in idx])
                noise = np.array([self.worlds[i].rng.standard_normal() for i in idx])
                self.filter.sample(idx, force, noise)
        self.base, self.tilt = new_base, new_tilt
        self.max_tilt = np.maximum(self.max_tilt, self.tilt)
        return self._evaluate_looped(active)

    def _evaluate_looped(
        self, active: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        cfg = self.config
        diverged = self.solver.diverged()
        info = self._measure_looped()
        collided = np.zeros(self.n, bool)
        for w in range(self.n):
            name = self.body_names[self.worlds[w].container]
            collided[w] = body_clearance(self.model, self.datas[w], name, "receiving") < 0.0
        for w in range(self.n):
            if active[w]:
                self.steps[w] += 1
                self.started[w] |= bool(self.max_tilt[w] >= cfg.pour_tilt)
                upright = self.started[w] and self.tilt[w] <= cfg.upright_tilt
                self.upright_steps[w] = self.upright_steps[w] + 1 if upright else 0
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
        for w in np.flatnonzero(finished & active):
            self.history.add(int(w), float(info["error_g"][w]))
        avg = self.history.average()
        pouring = self.filter.value_g < info["target_g"] - cfg.tolerance_g
        reward = extrinsic_reward(
            pouring, collided, finished, info["error_g"], avg, cfg.max_steps, cfg.reward
        )
        terminated = (collided | finished) & ~diverged
        truncated = ((self.steps >= cfg.max_steps) & ~terminated) | diverged
        info["collided"] = collided
        info["sim_diverged"] = diverged
        info["is_success"] = finished & (info["error_g"] <= cfg.reward.success_g)
        info["average_error_g"] = avg
        for w in np.flatnonzero(terminated | truncated):
            self.done[w] = True
        return self._observe_looped(), reward.astype(float), terminated, truncated, info

    def _measure_looped(self) -> dict[str, np.ndarray]:
        keys = ("poured_g", "spilled_g", "remaining_g", "in_flight_g", "initial_g", "target_g")
        out = {k: np.zeros(self.n) for k in keys}
        cups = {w: [self.pour_col[w], self.recv_col[w]] for w in range(self.n)}
        metrics = liquid_metrics_all(self.solver, cups)
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

    def _observe_looped(self) -> np.ndarray:
        obs = np.zeros((self.n, OBS_SIZE))
        avg = self.history.average()
        for w, st in enumerate(self.worlds):
            liq, c = st.liquid, get_container(st.container)
            weight = self.filter.value_g[w]
            obs[w] = [
                liq.density / 1000.0,
                liq.cohesion,
                liq.surface_tension,
                viscosity_feature(liq),
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
