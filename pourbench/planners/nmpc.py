"""NMPC-MP: nonlinear model predictive control motion planner (thesis chapter 4, Algorithm 1).

Written here by hand (numpy + MuJoCo kinematics); the QP subproblems go to proxsuite through
qpsolvers. The model is ``q⁺ = q + u·t_s`` with joint-velocity inputs ``u``. The decision
variable is ``U = [u_0, …, u_{ch−1}]`` (control horizon ``ch``); predicted configurations
``Q = S_U U + Q_0`` over the prediction horizon ``ph`` hold the last input (Eq. 4.48–4.49).

Cost (Eq. 4.51, without the constant stage-0 term)::

    f(U) = Σ_{i=1}^{ph−1} e_iᵀ Q e_i + e_phᵀ P_f e_ph + Uᵀ R̄ U,
    e_i = [T_d − T_i ; Π_d ξ_i]   (position error; vector part of the quaternion error, Eq. 4.47)

Constraints, at every predicted step i = 1…ph: the signed distance between each arm capsule
and each obstacle ≥ the safety distance (gradient ``nᵀ J(p_r)``, Eq. 4.60), joint-velocity
bounds ``lb ≤ U ≤ ub``, and for joints with position limits ``q_min ≤ q_i ≤ q_max``, which are
linear in U: per-step bounds on the accumulated velocities (for step 1 exactly the thesis'
``(q_max − q_0)/t_s`` velocity bound).

Solver: SQP. Each iteration solves a QP (Eq. 4.65) with either the damped-BFGS Hessian of the
Lagrangian (Eq. 4.66–4.68, the thesis) or the Gauss-Newton Hessian ``2 JᵀJ`` of the
least-squares cost, then a backtracking line search on the ℓ1 merit function (Eq. 4.69).
Warm start: the previous solution shifted by one step with its last input repeated, made
feasible by a restoration solve (Eq. 4.70: minimum-norm change of U subject to the
linearised constraints, with slacks so it always has a solution). An iteration cap and an
optional time budget bound each call.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import qpsolvers
from scipy.linalg import block_diag

from pourbench.errors import (
    InvalidParameterError,
    check_array,
    check_finite,
    check_int,
    check_positive,
    check_quat,
)
from pourbench.planners.distance import Obstacle, capsule_obstacle_distances, check_obstacles
from pourbench.planners.kinematics import ArmKinematics, joint_speeds, point_jacobian

HessianKind = Literal["bfgs", "gauss_newton"]
HESSIANS: tuple[str, ...] = ("bfgs", "gauss_newton")


@dataclass(frozen=True)
class NMPCConfig:
    """NMPC-MP parameters (Table 4.2 defaults for the weights and horizons).

    Attributes:
        q_pos: stage weight on the position error (1/m²).
        q_quat: stage weight on the quaternion-vector error.
        pf_pos: terminal weight on the position error.
        pf_quat: terminal weight on the quaternion-vector error.
        r: input weight (s²/rad²).
        ph: prediction horizon (steps).
        ch: control horizon (steps), ``1 ≤ ch ≤ ph``.
        ts: time step of the model and of the control loop (s). The thesis predicts 4 s with
            ph = 20, so 0.2 s.
        max_iter: SQP iteration cap per call.
        safety_distance: minimum signed distance to every obstacle (m).
        max_joint_speed: joint-speed bound (rad/s), a scalar or one value per joint.
        hessian: ``"bfgs"`` (thesis) or ``"gauss_newton"``.
        warm_start: shift the previous solution (True) or start every call from U = 0.
        time_budget_s: stop iterating once a call has used this much time (s); None for no
            budget.
        step_tol: converged when the QP step's largest entry is below this (rad/s).
        merit_rtol: converged when an iteration lowers the merit by less than this fraction.
        activation_distance: pairs farther than safety + this (m) are left out of the QP (they
            still count in the merit function and the feasibility checks).
        joint_limit_margin: distance kept from joint-position limits (rad).
        restoration_iters: iterations of the feasibility-restoration solve.
        restoration_tol: the restoration runs when a constraint of the warm start is violated
            by more than this (m or rad); smaller violations are left to the SQP.
    """

    q_pos: float = 5.0
    q_quat: float = 0.1
    pf_pos: float = 50.0
    pf_quat: float = 10.0
    r: float = 2.0
    ph: int = 20
    ch: int = 10
    ts: float = 0.2
    max_iter: int = 20
    safety_distance: float = 0.03
    max_joint_speed: float | tuple[float, ...] = 0.6
    hessian: HessianKind = "gauss_newton"
    warm_start: bool = True
    time_budget_s: float | None = None
    step_tol: float = 1e-4
    merit_rtol: float = 1e-6
    activation_distance: float = 0.1
    joint_limit_margin: float = 0.01
    restoration_iters: int = 10
    restoration_tol: float = 1e-4

    def __post_init__(self) -> None:
        nonnegative = (
            "q_pos", "q_quat", "pf_pos", "pf_quat", "safety_distance", "step_tol", "merit_rtol",
            "activation_distance", "joint_limit_margin", "restoration_tol",
        )  # fmt: skip
        for name in nonnegative:
            check_finite(name, getattr(self, name), minimum=0.0)
        check_positive("r", self.r)
        check_positive("ts", self.ts)
        check_int("ph", self.ph, minimum=1)
        check_int("ch", self.ch, minimum=1)
        if not (1 <= self.ch <= self.ph):
            raise InvalidParameterError(f"need 1 <= ch <= ph, got ch={self.ch}, ph={self.ph}")
        check_int("max_iter", self.max_iter, minimum=1)
        check_int("restoration_iters", self.restoration_iters, minimum=0)
        if self.time_budget_s is not None:
            check_positive("time_budget_s", self.time_budget_s)
        if not isinstance(self.warm_start, bool | np.bool_):
            raise InvalidParameterError(
                f"warm_start must be True or False, got {self.warm_start!r}"
            )
        if self.hessian not in HESSIANS:
            raise InvalidParameterError(f"hessian must be one of {HESSIANS}, got {self.hessian!r}")
        joint_speeds(self.max_joint_speed)  # the count is checked against the arm's


@dataclass
class NMPCResult:
    """Outcome of one NMPC-MP call.

    Attributes:
        u: the input to execute now, (n,) in rad/s.
        U: the optimised inputs, (ch, n) in rad/s.
        q_pred: predicted configurations q_0…q_ph, (ph + 1, n) in rad.
        ee_pred: predicted end-effector positions, (ph + 1, 3) in m.
        cost: cost f(U).
        iterations: SQP iterations used.
        converged: the SQP met its tolerance before the cap or the time budget.
        feasible: every predicted signed distance ≥ safety distance (within 0.1 mm).
        min_distance: smallest predicted signed distance over steps 1…ph (m; inf with no
            obstacles).
        restoration_iterations: iterations of the warm start's feasibility restoration.
        solve_time_s: wall time of the call (s).
        status: ``"converged"``, ``"iteration_cap"``, ``"time_budget"``, ``"line_search"`` (no
            decrease of the merit function along the step) or ``"qp_failed"``.
    """

    u: np.ndarray
    U: np.ndarray
    q_pred: np.ndarray
    ee_pred: np.ndarray
    cost: float
    iterations: int
    converged: bool
    feasible: bool
    min_distance: float
    restoration_iterations: int
    solve_time_s: float
    status: str


def quat_error_matrix(goal_quat: np.ndarray) -> np.ndarray:
    """Π_d of Eq. 4.46: ``Π_d ξ`` is the vector part of ``conj(ξ_d) ⊗ ξ`` (3×4)."""
    w, x, y, z = goal_quat
    return np.array([[-x, w, z, -y], [-y, -z, w, x], [-z, y, -x, w]])


def quat_jacobian(quat: np.ndarray, jac_rot: np.ndarray) -> np.ndarray:
    """Jacobian of the quaternion (w, x, y, z) from the world-frame rotational Jacobian.

    With MuJoCo's convention ``ξ̇ = ½ ω ⊗ ξ`` (ω in the world frame), so
    ``J_ξ = ½ [−pᵀ; w I − p×] J_ω`` (the world-frame form of Eq. 4.41). Broadcasts over
    leading axes: quat (..., 4), jac_rot (..., 3, n) → (..., 4, n).
    """
    w = quat[..., 0]
    p = quat[..., 1:]
    # w I − p× = w I + (p×)ᵀ, whose rows are p × e_k
    lower = w[..., None, None] * np.eye(3) + np.cross(p[..., None, :], np.eye(3))
    top = -p[..., None, :]
    Mq = np.concatenate([top, lower], axis=-2)  # (..., 4, 3)
    return 0.5 * Mq @ jac_rot


def horizon_matrix(ph: int, ch: int) -> np.ndarray:
    """M of Eq. 4.48, (ph + 1, ch): q_i = q_0 + t_s Σ_j M[i, j] u_j, last input held."""
    i = np.arange(ph + 1)[:, None]
    held = np.maximum(0, i - (ch - 1))  # steps the last input is held for
    return np.hstack([(np.arange(ch - 1)[None, :] < i).astype(float), held])


@dataclass
class _Eval:
    """Everything evaluated at one U."""

    U: np.ndarray
    Q: np.ndarray
    f: float
    grad: np.ndarray
    Jr: np.ndarray
    ee_pos: np.ndarray
    sd: np.ndarray  # (P,) flattened over (ph, K, L)
    dsd: np.ndarray  # (P, nU)
    lin_slack: np.ndarray  # (nlin,) ≥ 0 when the linear joint-limit rows hold


@dataclass
class _Problem:
    """One NMPC problem: current state, goal and obstacles."""

    q0: np.ndarray
    goal_pos: np.ndarray
    goal_quat: np.ndarray
    obstacles: Sequence[Obstacle]
    ee0: np.ndarray
    Pi: np.ndarray  # Π_d of the goal


class NMPCPlanner:
    """NMPC-MP for one arm (see the module docstring).

    Args:
        kin: the arm's kinematics (joints, end-effector site, collision capsules).
        config: parameters; Table 4.2 defaults.

    Raises:
        InvalidParameterError: ``max_joint_speed`` has neither one value nor one per joint, or
            ``joint_limit_margin`` leaves a limited joint no room (more than half its range).
    """

    def __init__(self, kin: ArmKinematics, config: NMPCConfig | None = None) -> None:
        config = config or NMPCConfig()
        n = kin.n
        speed = joint_speeds(config.max_joint_speed, n)
        m = config.joint_limit_margin
        width = kin.upper - kin.lower  # inf for joints without a limit
        bad = np.flatnonzero(width < 2.0 * m)
        if bad.size:
            j = int(bad[0])
            raise InvalidParameterError(
                f"joint_limit_margin {m!r} is more than half the range of joint "
                f"{kin.joint_names[j]!r} ([{kin.lower[j]:g}, {kin.upper[j]:g}] rad): "
                "no configuration keeps that margin from both limits"
            )
        self.kin = kin
        self.config = c = config
        self.n = n
        self.nU = n * c.ch
        self.u_max = speed
        self.M = horizon_matrix(c.ph, c.ch)
        self.TsM = c.ts * self.M[1:]  # (ph, ch) rows for q_1..q_ph
        self.step_times = c.ts * np.arange(1, c.ph + 1)  # (s) of predicted steps 1..ph
        # Residual weights: stages 1..ph−1 use Q, stage ph uses P_f.
        w = np.empty((c.ph, 6))
        w[:, :3] = np.sqrt(c.q_pos)
        w[:, 3:] = np.sqrt(c.q_quat)
        w[-1, :3] = np.sqrt(c.pf_pos)
        w[-1, 3:] = np.sqrt(c.pf_quat)
        self.w = w
        rbar = np.full(c.ch, c.r)
        rbar[-1] = c.r * (c.ph - c.ch + 1)
        self.sqrt_rbar = np.repeat(np.sqrt(rbar), n)
        self.lim = np.flatnonzero(np.isfinite(kin.lower) | np.isfinite(kin.upper))
        # Linear rows for joint-position limits: A_lin U gives ts Σ_j M[i,j] u_j[lim].
        self.A_lin = np.kron(self.TsM, np.eye(n)[self.lim])
        self._U_prev: np.ndarray | None = None

    # ----------------------------------------------------------------- public API
    def reset(self) -> None:
        """Forget the warm start."""
        self._U_prev = None

    def plan(
        self,
        q0: np.ndarray,
        goal_pos: np.ndarray,
        goal_quat: np.ndarray,
        obstacles: Sequence[Obstacle] = (),
    ) -> NMPCResult:
        """Solve one NMPC problem from configuration ``q0``.

        Args:
            q0: current joint positions (n,) in rad.
            goal_pos: goal end-effector position (3,) in m.
            goal_quat: goal orientation quaternion (w, x, y, z); normalised here.
            obstacles: obstacles at their current poses; one with a nonzero ``velocity`` is
                predicted to move at that velocity over the horizon (zero velocity: held
                still over the horizon, as in the thesis).

        Returns:
            An :class:`NMPCResult`; its ``u`` is the input to apply for ``ts`` seconds.

        Raises:
            InvalidParameterError: a NaN/inf or wrongly shaped input.
        """
        t_start = time.perf_counter()
        c = self.config
        prob = self._problem(q0, goal_pos, goal_quat, obstacles)
        lo, hi = self._limit_bounds(prob.q0)

        if c.warm_start and self._U_prev is not None:
            U0 = np.concatenate([self._U_prev[self.n :], self._U_prev[-self.n :]])
        else:
            U0 = np.zeros(self.nU)
        U0 = np.clip(U0, -np.tile(self.u_max, c.ch), np.tile(self.u_max, c.ch))
        ev = self._evaluate(prob, U0, lo, hi)
        ev, n_rest = self._restore(prob, ev, lo, hi)

        ev, iters, status = self._sqp(prob, ev, lo, hi, t_start)
        self._U_prev = ev.U.copy()
        sd_min = float(ev.sd.min()) if ev.sd.size else float("inf")
        return NMPCResult(
            u=ev.U[: self.n].copy(),
            U=ev.U.reshape(c.ch, self.n).copy(),
            q_pred=ev.Q.copy(),
            ee_pred=ev.ee_pos.copy(),
            cost=ev.f,
            iterations=iters,
            converged=status == "converged",
            feasible=bool(sd_min >= c.safety_distance - 1e-4),
            min_distance=sd_min,
            restoration_iterations=n_rest,
            solve_time_s=time.perf_counter() - t_start,
            status=status,
        )

    def _problem(self, q0, goal_pos, goal_quat, obstacles) -> _Problem:
        """The validated problem (``goal_quat`` normalised)."""
        flat = lambda v: np.ravel(v) if isinstance(v, np.ndarray) else v  # noqa: E731  (n, 1) too
        q0 = check_array("q0", flat(q0), (self.n,))
        goal_pos = check_array("goal_pos", flat(goal_pos), (3,))
        goal_quat = check_quat("goal_quat", flat(goal_quat))
        goal_quat = goal_quat / np.linalg.norm(goal_quat)
        obstacles = check_obstacles(obstacles)
        ee0 = self.kin.forward(q0).ee_pos[0]
        return _Problem(q0, goal_pos, goal_quat, obstacles, ee0, quat_error_matrix(goal_quat))

    # ----------------------------------------------------- evaluation (f, ∇f, g, ∇g)
    def _limit_bounds(self, q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-joint position bounds for the limited joints, relaxed to include q0."""
        m = self.config.joint_limit_margin
        lo = self.kin.lower[self.lim] + m
        hi = self.kin.upper[self.lim] - m
        q = q0[self.lim]
        return np.minimum(lo, q), np.maximum(hi, q)

    def _lin_rhs(self, q0: np.ndarray, lo: np.ndarray, hi: np.ndarray, U: np.ndarray):
        """(upper slack, lower slack) of the joint-limit rows at U; both ≥ 0 when feasible."""
        if not len(self.lim):
            return np.zeros(0), np.zeros(0)
        qi = np.tile(q0[self.lim], self.config.ph) + self.A_lin @ U
        return np.tile(hi, self.config.ph) - qi, qi - np.tile(lo, self.config.ph)

    def _evaluate(
        self, prob: _Problem, U: np.ndarray, lo: np.ndarray, hi: np.ndarray, grad: bool = True
    ) -> _Eval:
        """f, sd and the linear slacks at U; with ``grad`` also ∇f, the residual Jacobian and
        ∂sd/∂U (line-search trials skip them)."""
        c, n = self.config, self.n
        Uc = U.reshape(c.ch, n)
        Q = prob.q0[None, :] + self.config.ts * self.M @ Uc  # (ph+1, n)
        st = self.kin.forward_many(Q[1:], jacobians=grad)
        # --- cost residuals
        quat = st.ee_quat
        sign = np.where(quat @ prob.goal_quat >= 0.0, 1.0, -1.0)
        quat = quat * sign[:, None]
        e = np.empty((c.ph, 6))
        e[:, :3] = prob.goal_pos - st.ee_pos
        e[:, 3:] = quat @ prob.Pi.T
        r_track = (self.w * e).reshape(-1)
        r = np.concatenate([r_track, self.sqrt_rbar * U])
        f = float(r @ r)
        if grad:
            Jq = quat_jacobian(quat, st.jac_rot)  # linear in ξ, so already for the signed ξ
            de = np.empty((c.ph, 6, n))
            de[:, :3] = -st.jac_pos
            de[:, 3:] = prob.Pi @ Jq
            E = self.w[:, :, None] * de
            J_track = np.einsum("ij,ian->iajn", self.TsM, E).reshape(6 * c.ph, self.nU)
            Jr = np.vstack([J_track, np.diag(self.sqrt_rbar)])
            gradf = 2.0 * Jr.T @ r
        else:
            Jr = np.zeros((0, self.nU))
            gradf = np.zeros(0)
        # --- collision constraints
        if prob.obstacles and self.kin.num_capsules:
            dist = capsule_obstacle_distances(
                st.seg_a, st.seg_b, st.radius, prob.obstacles, times=self.step_times
            )
            sd = dist.sd.reshape(-1)
        else:
            sd = np.zeros(0)
        if grad and sd.size:
            PJ = point_jacobian(
                st.body_pos[:, :, None, :],
                st.body_jacp[:, :, None],
                st.body_jacr[:, :, None],
                dist.point_robot,
            )  # (ph, K, L, 3, n)
            G = np.einsum("tkla,tklan->tkln", dist.normal, PJ)
            dsd = np.einsum("tj,tkln->tkljn", self.TsM, G).reshape(-1, self.nU)
        else:
            dsd = np.zeros((0, self.nU))
        up, low = self._lin_rhs(prob.q0, lo, hi, U)
        return _Eval(
            U=U,
            Q=Q,
            f=f,
            grad=gradf,
            Jr=Jr,
            ee_pos=np.vstack([prob.ee0[None, :], st.ee_pos]),
            sd=sd,
            dsd=dsd,
            lin_slack=np.concatenate([up, low]),
        )

    def cost_and_constraints(
        self,
        q0: np.ndarray,
        goal_pos: np.ndarray,
        goal_quat: np.ndarray,
        obstacles: Sequence[Obstacle],
        U: np.ndarray,
    ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """f(U), ∇f(U), the signed distances sd(U) (flattened over steps 1…ph, capsules,
        obstacles; m) and their Jacobian ∂sd/∂U. For tests and diagnostics.

        Raises:
            InvalidParameterError: as :meth:`plan`, or ``U`` is not ``ch·n`` finite numbers.
        """
        prob = self._problem(q0, goal_pos, goal_quat, obstacles)
        U = check_array("U", U, (self.nU,))
        lo, hi = self._limit_bounds(prob.q0)
        ev = self._evaluate(prob, U, lo, hi)
        return ev.f, ev.grad, ev.sd, ev.dsd

    # ------------------------------------------------------------------- QP solve
    def _solve_qp(
        self, H: np.ndarray, g: np.ndarray, ev: _Eval, rows: np.ndarray, elastic: bool = False
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Solve the QP subproblem, again in elastic mode when that fails (e.g. infeasible
        linearised constraints); returns (d, multipliers of the selected sd rows), or None."""
        c = self.config
        umax = np.tile(self.u_max, c.ch)
        lb, ub = -umax - ev.U, umax - ev.U
        Gc = -ev.dsd[rows]
        hc = ev.sd[rows] - c.safety_distance
        nl = self.A_lin.shape[0]
        G_parts = [Gc]
        h_parts = [hc]
        if nl:
            G_parts += [self.A_lin, -self.A_lin]
            h_parts += [ev.lin_slack[:nl], ev.lin_slack[nl:]]
        G = np.vstack(G_parts)
        h = np.concatenate(h_parts)
        m = len(rows)
        if elastic and m:
            # One shared slack s ≥ 0 on the distance rows (ℓ∞ elastic mode):
            # −∇sd d − s ≤ sd − TH, extra cost ρ s + ½ s². Always feasible (d = −U, s large).
            H = block_diag(H, 1.0)
            g = np.append(g, 1e3)  # ρ
            slack = np.zeros((G.shape[0], 1))
            slack[:m] = -1.0
            G = np.hstack([G, slack])
            lb, ub = np.append(lb, 0.0), np.append(ub, 1e6)
        if G.shape[0] == 0:
            G, h = None, None
        problem = qpsolvers.Problem(H, g, G, h, lb=lb, ub=ub)
        sol = qpsolvers.solve_problem(
            problem, solver="proxqp", backend="dense", eps_abs=1e-7, eps_rel=0.0, max_iter=2000
        )
        if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
            return None if elastic else self._solve_qp(H, g, ev, rows, elastic=True)
        lam = np.zeros(m) if sol.z is None else np.maximum(np.asarray(sol.z[:m]), 0.0)
        return sol.x[: self.nU], lam

    def _rows(self, ev: _Eval) -> np.ndarray:
        c = self.config
        return np.flatnonzero(ev.sd < c.safety_distance + c.activation_distance)

    # -------------------------------------------------------------- restoration
    def _restore(self, prob: _Problem, ev: _Eval, lo: np.ndarray, hi: np.ndarray):
        """Feasibility restoration of the warm start (Eq. 4.70)."""
        c = self.config
        its = 0
        H = np.eye(self.nU)
        g0 = np.zeros(self.nU)
        for its in range(1, c.restoration_iters + 1):
            viol = self._violation(ev)
            if self._max_violation(ev) <= c.restoration_tol:
                return ev, its - 1
            rows = self._rows(ev)
            out = self._solve_qp(H, g0, ev, rows)
            if out is None:
                break
            d, _ = out
            # Backtrack on the total violation.
            alpha = 1.0
            for _ in range(8):
                trial = self._evaluate(prob, ev.U + alpha * d, lo, hi, grad=False)
                if self._violation(trial) < viol:
                    ev = self._evaluate(prob, trial.U, lo, hi)
                    break
                alpha *= 0.5
            else:
                break
        return ev, its

    def _max_violation(self, ev: _Eval) -> float:
        v = np.maximum(self.config.safety_distance - ev.sd, 0.0)
        lin = np.maximum(-ev.lin_slack, 0.0)
        return float(max(v.max(initial=0.0), lin.max(initial=0.0)))

    def _violation(self, ev: _Eval) -> float:
        v = np.maximum(self.config.safety_distance - ev.sd, 0.0).sum()
        return float(v + np.maximum(-ev.lin_slack, 0.0).sum())

    # ---------------------------------------------------------------------- SQP
    def _merit(self, ev: _Eval, mu: np.ndarray) -> float:
        return ev.f + float(mu @ np.maximum(self.config.safety_distance - ev.sd, 0.0))

    def _sqp(
        self, prob: _Problem, ev: _Eval, lo: np.ndarray, hi: np.ndarray, t_start: float
    ) -> tuple[_Eval, int, str]:
        c = self.config
        P = ev.sd.size
        mu = np.zeros(P)
        # BFGS starts every call from the exact Hessian of the input term 2R̄ (carrying the
        # previous call's matrix over, shifted, takes more iterations).
        B = np.diag(2.0 * self.sqrt_rbar**2) if c.hessian == "bfgs" else None
        status = "iteration_cap"
        k = 0
        while k < c.max_iter:
            k += 1
            H = B if c.hessian == "bfgs" else 2.0 * ev.Jr.T @ ev.Jr + 1e-9 * np.eye(self.nU)
            rows = self._rows(ev)
            out = self._solve_qp(H, ev.grad, ev, rows)
            if out is None:
                status = "qp_failed"
                break
            d, lam_rows = out
            lam = np.zeros(P)
            lam[rows] = lam_rows
            if np.max(np.abs(d)) < c.step_tol:
                status = "converged"
                break
            mu = np.maximum(0.5 * (mu + lam), lam)
            phi0 = self._merit(ev, mu)
            viol0 = np.maximum(c.safety_distance - ev.sd, 0.0)
            dphi = float(ev.grad @ d - mu @ viol0)
            alpha = 1.0
            new = None
            for _ in range(12):
                trial = self._evaluate(prob, ev.U + alpha * d, lo, hi, grad=False)
                if self._merit(trial, mu) <= phi0 + 1e-4 * alpha * min(dphi, 0.0):
                    new = self._evaluate(prob, trial.U, lo, hi)
                    break
                alpha *= 0.5
            if new is None:
                status = "line_search"
                break
            if c.hessian == "bfgs":
                B = self._bfgs(B, alpha * d, new, ev, lam)
            phi1 = self._merit(new, mu)
            ev = new
            small = phi0 - phi1 <= c.merit_rtol * max(abs(phi0), 1e-12)
            if small and self._max_violation(ev) <= c.restoration_tol:
                status = "converged"
                break
            if c.time_budget_s is not None and time.perf_counter() - t_start > c.time_budget_s:
                status = "time_budget"
                break
        return ev, k, status

    @staticmethod
    def _bfgs(B: np.ndarray, s: np.ndarray, new: _Eval, old: _Eval, lam: np.ndarray) -> np.ndarray:
        """Damped BFGS update of the Lagrangian Hessian (Eq. 4.66–4.68)."""
        # ∇L = ∇f + Σ λ_i ∇g_i with g = TH − sd, so ∇g = −∇sd.
        gl_new = new.grad - new.dsd.T @ lam if lam.size else new.grad
        gl_old = old.grad - old.dsd.T @ lam if lam.size else old.grad
        delta = gl_new - gl_old
        Bs = B @ s
        sBs = float(s @ Bs)
        if sBs <= 1e-16:
            return B
        sd_ = float(s @ delta)
        theta = 1.0 if sd_ >= 0.2 * sBs else 0.8 * sBs / (sBs - sd_)
        q = theta * delta + (1.0 - theta) * Bs
        return B + np.outer(q, q) / float(q @ s) - np.outer(Bs, Bs) / sBs
