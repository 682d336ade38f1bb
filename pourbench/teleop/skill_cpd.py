"""The Skill-CPD arbitration state machine (thesis Algorithms 2 and 3, §5.2-5.3.4).

Every packet period the robot receives the operator's position or nothing. The machine is in
one of four states:

* ``direct``: the robot follows the operator (``alpha = 1`` in ``u = alpha u_h +
  (1 - alpha) u_a``, Eq. 5.1). Executed positions are kept in ``xi_h*`` by the Δd rule.
* ``hold``: the deadline (50 ms) passed without a packet and the robot may not switch (mode
  ``"none"``, or recognition confidence below ``lambda_minconf``): it holds its last
  position for the rest of the outage. Before the deadline passes a missing packet leaves
  the state ``direct``, with the robot also held at its last position.
* ``skill``: deadline missed and the skill recognised with confidence >= ``lambda_minconf``
  (Eq. 5.2): the robot runs the registered skill ``xi_c`` (``alpha = 0``), advancing along
  it at the operator's mean speed measured before the drop (with ``takeover_step`` < 1 the
  robot's offset from the skill at the switch fades over several packets instead of
  jumping). The confidence is the library's
  calibrated open-set probability (:mod:`~pourbench.teleop.confidence`): an operator doing a
  skill the library does not hold gets a low one, and the robot then holds as in ``"none"``.
  Modes that may switch therefore need a library calibrated for their recognition mode:
  :class:`SkillCPD` refuses an uncalibrated one at construction, and a step that would
  switch on an uncalibrated recognition (the library refitted, which drops its
  calibrations) raises instead of switching.
* ``handback``: packets are back; ``alpha`` rises by 0.1 per packet (Eq. 5.10), or more
  slowly where ``handback_speed`` caps how fast the command closes the skill-operator gap,
  and the command is ``(1 - alpha) xi_c + alpha h_t``; at ``alpha = 1`` the state is
  ``direct``.

Registration (Algorithm 3, mode ``"skill_cpd"``). The rough disconnection index ``i0`` is
the operator's number of Δd samples (skill steps are one Δd sample of the demonstrations
apart). The skill prefix up to ``i0`` + 10 steps is registered rigidly (with scale) onto
``xi_h*`` and the transform applied to the whole skill; ``i0`` is then divided by the
recovered scale. With invariant HSMM recognition that same rigid CPD (same prefix, same
points) already ran, with a looser tolerance, to align the operator for the recognised skill:
the registration resumes its EM instead of starting again; the shape recognizer's scale and
rotation start it the same way. If the mean distance from ``xi_h*``
to the registered skill (as a polyline) is 0.1 cm or more, the rigidly registered prefix
is registered non-rigidly (``beta = 3``, ``lmbda = 3``) and CPD's displacement field, which
is defined everywhere, is applied to the whole skill. (The thesis registers the complete
skill; with a partial operator trajectory that pulls the unmatched rest of the skill onto
the operator's points, so the field is extrapolated instead.) The closest step to the
robot's position within ±10 steps of ``i0`` (Eq. 5.9) locates the start; the skill starts
at the robot's projection onto the segments next to that step, as it is followed
continuously by arc length.

Mode ``"standard"`` is standard shared autonomy: the same machine with the unregistered
skill. Mode ``"none"`` never switches (the robot holds still while disconnected and jumps
back to the operator on reconnection).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from pourbench.errors import InvalidParameterError, check_finite, check_int, check_positive
from pourbench.teleop.cpd import RigidResult, register_nonrigid, register_rigid
from pourbench.teleop.network import DeadlineDetector
from pourbench.teleop.skills import RECOGNIZERS, Recognition, SkillLibrary

__all__ = [
    "MODES",
    "Registration",
    "SkillCPD",
    "SkillCPDConfig",
    "closest_step",
    "register_skill",
]

MODES = ("none", "standard", "skill_cpd")


@dataclass(frozen=True)
class SkillCPDConfig:
    """Parameters of the arbitration (defaults: thesis Table 5.2, 2-D simulation).

    Attributes:
        mode: ``"none"``, ``"standard"`` or ``"skill_cpd"``.
        dt: packet period, s.
        deadline: lambda_deadline, s.
        min_confidence: lambda_minconf, compared with the library's calibrated confidence
            (a probability).
        delta_d: Δd sampling distance, m.
        rigid_error: rigid registration accepted below this mean distance, m (0.1 cm).
        window: closest-step search window, ± steps.
        alpha_step: alpha increment per packet during the hand-back (thesis: 0.1).
        takeover_step: fraction of the takeover offset removed per packet (1.0, the
            thesis: the robot jumps onto the registered skill). At the switch the robot is
            off the registered skill by the registration's residual at its position; the
            command keeps ``1 - j * takeover_step`` of that offset at the ``j``-th packet of
            the skill (the switch's packet is the first) while the skill advances.
        handback_speed: largest speed, m/s, at which the hand-back may close the gap between
            the skill and the operator (0, the thesis: no limit). Each packet the command
            moves by the rise of ``alpha`` times the gap on top of the skill's and the
            operator's own motion, so alpha then rises by ``min(alpha_step, handback_speed *
            dt / gap)`` and a gap of several centimetres closes without a jump, more slowly.
        cpd_w: CPD outlier weight.
        beta: non-rigid kernel width (normalised units).
        lmbda: non-rigid regularisation weight.
        fgt: use the Fast Gauss Transform in non-rigid CPD.
        lowrank: use the low-rank kernel in non-rigid CPD.
        invariant_recognition: recognise a rotated or scaled operator too (see
            :meth:`SkillLibrary.recognize`); off in the thesis.
        recognizer: how the library scores the operator's trajectory, one of
            :data:`~pourbench.teleop.skills.RECOGNIZERS`: ``"hsmm"`` (the thesis) or
            ``"shape"`` (ours: step directions against each skill's mean path).
        cpd_tol: CPD stops when sigma^2 changes by less than this fraction per iteration.
        cpd_max_iter: CPD iteration cap (rigid and non-rigid each).

    Raises:
        InvalidParameterError: at construction, for an unknown mode or recognizer; ``dt``,
            ``deadline``, ``delta_d``, ``alpha_step``, ``beta`` or ``lmbda`` not finite and > 0;
            ``takeover_step`` outside (0, 1]; ``handback_speed`` negative or not finite;
            ``min_confidence`` outside [0, 1]; ``rigid_error`` or ``cpd_tol`` negative or
            not finite; ``cpd_w`` outside [0, 1); ``window`` not an integer >= 0;
            ``cpd_max_iter`` not an integer >= 1.
    """

    mode: str = "skill_cpd"
    dt: float = 0.033
    deadline: float = 0.050
    min_confidence: float = 0.9
    delta_d: float = 0.006
    rigid_error: float = 0.001
    window: int = 10
    alpha_step: float = 0.1
    takeover_step: float = 1.0
    handback_speed: float = 0.0
    cpd_w: float = 0.1
    beta: float = 3.0
    lmbda: float = 3.0
    fgt: bool = False
    lowrank: bool = True
    invariant_recognition: bool = False
    recognizer: str = "hsmm"
    cpd_tol: float = 1e-4
    cpd_max_iter: int = 100

    def __post_init__(self) -> None:
        if not isinstance(self.mode, str) or self.mode not in MODES:
            raise InvalidParameterError(f"mode must be one of {MODES}, got {self.mode!r}")
        if not isinstance(self.recognizer, str) or self.recognizer not in RECOGNIZERS:
            raise InvalidParameterError(
                f"recognizer must be one of {list(RECOGNIZERS)}, got {self.recognizer!r}"
            )
        for name in ("dt", "deadline", "delta_d", "alpha_step", "beta", "lmbda"):
            check_positive(name, getattr(self, name))
        if check_positive("takeover_step", self.takeover_step) > 1.0:
            raise InvalidParameterError(
                f"takeover_step (a fraction of the offset per packet) must be in (0, 1], "
                f"got {self.takeover_step!r}"
            )
        conf = check_finite("min_confidence", self.min_confidence, minimum=0.0)
        if conf > 1.0:
            raise InvalidParameterError(
                f"min_confidence must be in [0, 1] (a posterior probability), "
                f"got {self.min_confidence!r}"
            )
        check_finite("rigid_error", self.rigid_error, minimum=0.0)
        check_finite("handback_speed", self.handback_speed, minimum=0.0)
        check_int("window", self.window, minimum=0)
        w = check_finite("cpd_w", self.cpd_w, minimum=0.0)
        if w >= 1.0:
            raise InvalidParameterError(f"cpd_w (outlier weight) must be in [0, 1), got {w!r}")
        check_finite("cpd_tol", self.cpd_tol, minimum=0.0)
        check_int("cpd_max_iter", self.cpd_max_iter, minimum=1)


@dataclass
class Registration:
    """What happened at a switch to the skill.

    Attributes:
        label: recognised skill.
        confidence: recognition confidence.
        kind: ``"rigid"``, ``"nonrigid"`` or ``"none"`` (standard shared autonomy).
        error: mean distance from ``xi_h*`` to the registered skill, m.
        step: index of the closest step where the skill starts.
        seconds: wall time of the registration and closest-step search (one core).
        recognition_seconds: wall time of the recognition.
        trajectory: (M, D) the registered skill ``xi_c``, m.
        nonrigid_template: (K, D) the template handed to non-rigid CPD (the rigidly
            registered prefix), or ``None`` when non-rigid CPD was not run.
        operator_points: (N, D) the operator's Δd-sampled trajectory ``xi_h*`` at the switch.
    """

    label: str
    confidence: float
    kind: str
    error: float
    step: int
    seconds: float
    recognition_seconds: float
    trajectory: np.ndarray = field(repr=False)
    nonrigid_template: np.ndarray | None = field(default=None, repr=False)
    operator_points: np.ndarray | None = field(default=None, repr=False)


def closest_step(point: np.ndarray, traj: np.ndarray, centre: int, window: int) -> int:
    """Index of the point of ``traj`` closest to ``point`` within ``centre ± window`` (Eq. 5.9).

    When ``centre ± window`` lies wholly outside ``traj`` (before its start or past its end),
    the ``window + 1`` points at that end are searched.

    Raises:
        InvalidParameterError: ``traj`` is not a non-empty finite (M, D) array, ``point``
            not a finite (D,) vector, ``centre`` not an integer or ``window`` not an
            integer >= 0.
    """
    traj = np.asarray(traj, dtype=float)
    if traj.ndim != 2 or traj.shape[0] == 0:
        raise InvalidParameterError(f"traj must be a non-empty (M, D) array, got {traj.shape}")
    if not np.isfinite(traj.sum()) and not np.all(np.isfinite(traj)):
        raise InvalidParameterError("traj contains NaN or infinite coordinates")
    point = np.asarray(point, dtype=float)
    if point.shape != (traj.shape[1],) or not np.all(np.isfinite(point)):
        raise InvalidParameterError(
            f"point must be a finite vector of length {traj.shape[1]}, got {point!r}"
        )
    check_int("centre", centre)
    check_int("window", window, minimum=0)
    lo = max(0, int(centre) - int(window))
    hi = min(traj.shape[0], int(centre) + int(window) + 1)
    if lo >= hi and centre < 0:
        lo, hi = 0, min(traj.shape[0], int(window) + 1)
    elif lo >= hi:
        lo, hi = max(0, traj.shape[0] - 1 - int(window)), traj.shape[0]
    d = np.linalg.norm(traj[lo:hi] - point, axis=1)
    return lo + int(np.argmin(d))


def _project_arc_length(point: np.ndarray, traj: np.ndarray, cum: np.ndarray, step: int) -> float:
    """Arc length (m) of the projection of ``point`` onto the two segments around ``step``.

    The skill is followed continuously by arc length, so it starts at the foot of the
    perpendicular from the robot rather than at the nearest vertex (steps are ~Δd apart).
    """
    best_d, best_s = np.inf, float(cum[step])
    for j in (step - 1, step):
        if j < 0 or j + 1 >= traj.shape[0]:
            continue
        seg = traj[j + 1] - traj[j]
        L2 = float(seg @ seg)
        u = 0.0 if L2 <= 0.0 else float(np.clip((point - traj[j]) @ seg / L2, 0.0, 1.0))
        d = float(np.linalg.norm(traj[j] + u * seg - point))
        if d < best_d:
            best_d, best_s = d, float(cum[j] + u * (cum[j + 1] - cum[j]))
    return best_s


def _mean_nn_distance(A: np.ndarray, B: np.ndarray) -> float:
    """Mean over points of A of the distance to the polyline B (nearest segment), m."""
    if B.shape[0] == 1:
        return float(np.mean(np.linalg.norm(A - B[0], axis=1)))
    p0, seg = B[:-1], np.diff(B, axis=0)  # (S, D)
    L2 = np.maximum(np.einsum("sd,sd->s", seg, seg), 1e-300)
    rel = A[:, None, :] - p0[None, :, :]  # (N, S, D)
    u = np.clip(np.einsum("nsd,sd->ns", rel, seg) / L2, 0.0, 1.0)
    d = np.linalg.norm(rel - u[:, :, None] * seg[None, :, :], axis=2)
    return float(np.mean(d.min(axis=1)))


def register_skill(
    X: np.ndarray,
    xi_a: np.ndarray,
    robot: np.ndarray,
    cfg: SkillCPDConfig,
    init: RigidResult | None = None,
) -> tuple[np.ndarray, str, float, int, np.ndarray | None]:
    """Algorithm 3: register the skill ``xi_a`` onto the operator's ``xi_h*`` = ``X``.

    Args:
        X: (N, D) operator trajectory so far, Δd-sampled, m.
        xi_a: (M, D) skill trajectory, m.
        robot: (D,) robot position where the skill must start, m.
        cfg: parameters (``mode="standard"`` skips the registration).
        init: a rigid CPD of the same prefix onto ``X`` to continue from (the invariant
            recognition's alignment, :attr:`Recognition.alignment`): the rigid EM resumes
            there, with the iterations it already ran deducted from ``cfg.cpd_max_iter``.

    Returns:
        ``(xi_c, kind, error, step, nonrigid_template)``: registered skill, ``"rigid"`` /
        ``"nonrigid"`` / ``"none"``, mean distance from X to ``xi_c`` (m), closest step, and
        the template given to non-rigid CPD (``None`` if it did not run).

    Raises:
        InvalidParameterError: ``X`` or ``xi_a`` has fewer than 2 points or a NaN or
            infinite coordinate, their dimensions differ, ``robot`` is not a finite point
            of that dimension, or (from CPD) a point set is degenerate (all points
            identical). In every mode.
    """
    X = np.asarray(X, dtype=float)
    xi_a = np.asarray(xi_a, dtype=float)
    if X.ndim != 2 or X.shape[0] < 2:
        raise InvalidParameterError(f"X must be (N >= 2, D) operator points, got {X.shape}")
    if xi_a.ndim != 2 or xi_a.shape[0] < 2 or xi_a.shape[1] != X.shape[1]:
        raise InvalidParameterError(
            f"xi_a must be (M >= 2, {X.shape[1]}) skill points, got {xi_a.shape}"
        )
    for name, pts in (("X", X), ("xi_a", xi_a)):
        if not np.all(np.isfinite(pts)):
            raise InvalidParameterError(f"{name} contains NaN or infinite coordinates")
    # rough disconnection index: skill steps and operator samples are both ~Δd apart
    i0 = min(X.shape[0] - 1, xi_a.shape[0] - 1)
    template = None
    if cfg.mode == "standard":
        xi_c, kind, err = xi_a, "none", _mean_nn_distance(X, xi_a)
    else:
        # the prefix reaches one window past the rough index, so that the part of the
        # skill the operator has drawn is inside it even when the rough index is short
        prefix = xi_a[: max(min(i0 + cfg.window, xi_a.shape[0] - 1) + 1, 2)]
        max_iter = cfg.cpd_max_iter - (init.iterations if init is not None else 0)
        rig = register_rigid(
            X, prefix, w=cfg.cpd_w, tol=cfg.cpd_tol, max_iter=max(max_iter, 1), init=init
        )
        i0 = min(round((X.shape[0] - 1) / max(rig.s, 1e-9)), xi_a.shape[0] - 1)
        xi_c = rig.transform(xi_a)
        err = _mean_nn_distance(X, xi_c)
        kind = "rigid"
        if err >= cfg.rigid_error:
            template = xi_c[: min(i0 + cfg.window, xi_a.shape[0] - 1) + 1]
            nr = register_nonrigid(
                X,
                template,
                beta=cfg.beta,
                lmbda=cfg.lmbda,
                w=cfg.cpd_w,
                fgt=cfg.fgt,
                lowrank=cfg.lowrank,
                tol=cfg.cpd_tol,
                max_iter=cfg.cpd_max_iter,
            )
            xi_c = nr.transform(xi_c)
            err = _mean_nn_distance(X, xi_c)
            kind = "nonrigid"
    step = closest_step(robot, xi_c, i0, cfg.window)
    return xi_c, kind, err, step, template


class SkillCPD:
    """Shared-autonomy arbitration between the operator and a learnt skill.

    Args:
        library: fitted :class:`~pourbench.teleop.skills.SkillLibrary`.

    Raises:
        InvalidParameterError: ``library`` has no skills (not fitted), or the mode may
            switch (``"standard"``, ``"skill_cpd"``) and the library is not calibrated
            (:meth:`~pourbench.teleop.skills.SkillLibrary.calibrate`) for the recognition
            mode of ``config`` (``recognizer``, ``invariant_recognition``). :meth:`step`
            raises the same
            if the library loses that calibration later (it is refitted).
    """

    def __init__(self, library: SkillLibrary, config: SkillCPDConfig | None = None) -> None:
        if not library.skills:
            raise InvalidParameterError("library has no skills: call library.fit() first")
        self.library = library
        self.config = config or SkillCPDConfig()
        cfg = self.config
        if cfg.mode != "none" and (
            library.calibration(invariant=cfg.invariant_recognition, recognizer=cfg.recognizer)
            is None
        ):
            raise InvalidParameterError(
                f"the library is not calibrated for recognizer={cfg.recognizer!r}, "
                f"invariant_recognition={cfg.invariant_recognition}: without calibration its "
                f"confidence is a closed-set posterior (about 1 for any input) and cannot gate "
                f"the switch; call library.calibrate(held_out_demos, "
                f"invariant={cfg.invariant_recognition}, recognizer={cfg.recognizer!r})"
            )
        self.detector = DeadlineDetector(self.config.deadline)
        self.state = "direct"
        self.alpha = 1.0
        self.position: np.ndarray | None = None
        self.history: list[np.ndarray] = []  # xi_h*: executed positions, Δd-sampled
        self.registrations: list[Registration] = []
        self.recognitions: list[tuple[float, Recognition]] = []  # (time, result) per attempt
        self.transitions: list[tuple[float, str, str]] = []
        self._skill: np.ndarray | None = None
        self._cum: np.ndarray | None = None
        self._s = 0.0  # arc length along the skill, m
        self._offset: np.ndarray | None = None  # robot minus the skill's start at the switch, m
        self._offset_weight = 0.0  # fraction of that offset still in the command
        self._path_len = 0.0  # operator path length between consecutive direct packets, m
        self._path_time = 0.0  # and the time it took, s
        self._last_packet: np.ndarray | None = None
        self._last_packet_t: float | None = None
        self._last_t: float | None = None  # time of the last completed step, s

    # ------------------------------------------------------------------ helpers
    def _set_state(self, t: float, new: str) -> None:
        if new != self.state:
            self.transitions.append((float(t), self.state, new))
            self.state = new

    def _record(self, p: np.ndarray) -> None:
        if not self.history or np.linalg.norm(p - self.history[-1]) >= self.config.delta_d:
            self.history.append(p.copy())

    def _speed(self) -> float:
        """Operator's mean speed over the consecutive packets received in ``direct``, m/s."""
        return self._path_len / self._path_time if self._path_time > 0 else 0.0

    def _on_skill(self) -> np.ndarray:
        """The registered skill's point at arc length ``_s``."""
        assert self._skill is not None and self._cum is not None
        s = min(self._s, float(self._cum[-1]))
        return np.array(
            [np.interp(s, self._cum, self._skill[:, d]) for d in range(self._skill.shape[1])]
        )

    def _skill_point(self) -> np.ndarray:
        """The skill's command: its point at arc length ``_s`` plus the fading takeover offset."""
        assert self._offset is not None  # set with the skill by _register
        return self._on_skill() + self._offset_weight * self._offset

    def _advance(self) -> None:
        """One packet along the skill: the arc length at the operator's speed, the offset fades."""
        self._s += self._speed() * self.config.dt
        self._offset_weight = max(0.0, self._offset_weight - self.config.takeover_step)

    def _alpha_step(self, skill_point: np.ndarray, operator: np.ndarray) -> float:
        """This packet's rise of alpha in the hand-back: ``alpha_step``, capped so that the
        command closes the skill-operator gap at no more than ``handback_speed``."""
        cfg = self.config
        gap = float(np.linalg.norm(operator - skill_point))
        if cfg.handback_speed <= 0.0 or gap <= 0.0:
            return cfg.alpha_step
        return min(cfg.alpha_step, cfg.handback_speed * cfg.dt / gap)

    def _register(self, t: float) -> bool:
        """Recognise and register (Algorithm 3); False when the skill may not be used.

        Raises InvalidParameterError, having changed nothing, when the recognition is not
        calibrated (the library was refitted after this machine was built).
        """
        cfg = self.config
        if cfg.mode == "none" or len(self.history) < 2:
            return False
        X = np.array(self.history)
        t0 = time.perf_counter()
        rec = self.library.recognize(
            X, invariant=cfg.invariant_recognition, recognizer=cfg.recognizer
        )
        t1 = time.perf_counter()
        if not rec.calibrated:  # a closed-set confidence is about 1 for any input
            raise InvalidParameterError(
                f"recognised skill {rec.label!r} with confidence {rec.confidence:.3g} from a "
                f"library no longer calibrated for recognizer={cfg.recognizer!r}, "
                f"invariant_recognition={cfg.invariant_recognition} (refitting drops "
                f"calibrations): the switch cannot be gated; call "
                f"library.calibrate(held_out_demos, invariant={cfg.invariant_recognition}, "
                f"recognizer={cfg.recognizer!r})"
            )
        self.recognitions.append((float(t), rec))
        if rec.confidence < cfg.min_confidence:
            return False
        xi_a = self.library.skill(rec.label).trajectory
        robot = self.position if self.position is not None else X[-1]
        xi_c, kind, err, step, template = register_skill(X, xi_a, robot, cfg, rec.alignment)
        t2 = time.perf_counter()
        self._skill = xi_c
        seg = np.linalg.norm(np.diff(xi_c, axis=0), axis=1)
        self._cum = np.concatenate([[0.0], np.cumsum(seg)])
        self._s = _project_arc_length(robot, xi_c, self._cum, step)
        self._offset = robot - self._on_skill()
        self._offset_weight = 1.0 - cfg.takeover_step  # the switch's packet is the first
        self.registrations.append(
            Registration(
                rec.label, rec.confidence, kind, err, step, t2 - t1, t1 - t0, xi_c, template, X
            )
        )
        return True

    # ------------------------------------------------------------------ main step
    def step(self, t: float, packet: np.ndarray | None) -> np.ndarray:
        """Advance one packet period.

        Args:
            t: time, s (finite, not earlier than the previous step's; equal is allowed).
            packet: the operator's position (D,), metres, or ``None`` when nothing arrived.

        Returns:
            The robot's commanded position (D,), metres.

        Raises:
            InvalidParameterError: ``t`` is not finite or earlier than the previous
                step's, ``packet`` is not a finite, non-empty 1-D position with the skills'
                (then the robot's) dimension, ``packet`` is ``None`` before any packet
                arrived, or the switch would use an uncalibrated recognition (see the
                class). A refused call changes nothing.
        """
        cfg = self.config
        t = check_finite("t", t)
        if self._last_t is not None and t < self._last_t:
            # a clock stepping back would inflate the operator's measured speed
            raise InvalidParameterError(
                f"t must not go back: {t!r} s is earlier than the previous step's "
                f"{self._last_t!r} s"
            )
        if packet is not None:
            h = np.asarray(packet, dtype=float)
            if h.ndim != 1 or h.shape[0] == 0 or not np.all(np.isfinite(h)):
                raise InvalidParameterError(
                    f"packet must be a finite, non-empty 1-D position, got {packet!r}"
                )
            if self.position is not None and h.shape != self.position.shape:
                raise InvalidParameterError(
                    f"packet has {h.shape[0]} dims, the robot has {self.position.shape[0]}"
                )
            if self.position is None:
                dim = next(iter(self.library.skills.values())).trajectory.shape[1]
                if h.shape[0] != dim:
                    raise InvalidParameterError(
                        f"packet has {h.shape[0]} dims, the skills have {dim}"
                    )
            if self.state in ("direct", "hold"):
                consecutive = (
                    self._last_packet_t is not None and t - self._last_packet_t <= cfg.deadline
                )
                if self.state == "direct" and consecutive and self._last_packet is not None:
                    self._path_len += float(np.linalg.norm(h - self._last_packet))
                    self._path_time += float(t - self._last_packet_t)
                self._set_state(t, "direct")
                self.alpha = 1.0
                self.position = h.copy()
            else:  # skill or handback: reverse takeover
                if self.state == "skill":
                    self._set_state(t, "handback")
                    self.alpha = 0.0
                self._advance()
                skill_point = self._skill_point()
                self.alpha = min(1.0, self.alpha + self._alpha_step(skill_point, h))
                if self.alpha >= 1.0 - 1e-9:
                    self.alpha = 1.0
                    self.position = h.copy()
                    self._set_state(t, "direct")
                else:
                    self.position = (1.0 - self.alpha) * skill_point + self.alpha * h
            self.detector.packet(t)
            self._last_packet = h.copy()
            self._last_packet_t = float(t)
        elif self.position is None:
            raise InvalidParameterError("no packet has arrived yet: the robot has no position")
        elif self.state == "direct" and self.detector.disconnected(t):
            if self._register(t):
                self._set_state(t, "skill")
                self.alpha = 0.0
                self.position = self._skill_point()
            else:
                self._set_state(t, "hold")
        elif self.state in ("skill", "handback"):
            self._set_state(t, "skill")
            self.alpha = 0.0
            self._advance()
            self.position = self._skill_point()
        self._record(self.position)
        self._last_t = t
        return self.position.copy()
