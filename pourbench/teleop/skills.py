"""A library of learnt skills: one HSMM per skill, its LQT reproduction, and recognition.

Each skill (a letter, a feeding target) is learnt from its demonstrations, Δd-sampled
(thesis §5.3.4.1) and turned into :func:`~pourbench.teleop.hsmm.trajectory_features`. The
skill trajectory ``xi_a`` is the discrete LQT (:func:`~pourbench.teleop.lqt.lqt_track`)
tracking the HSMM's step-wise Gaussians (activation-weighted means, covariance of the most
active state), shifted to the demonstrations' mean start point. As the HSMM is learnt from
Δd-sampled demonstrations, one step of the skill corresponds to one Δd sample of the operator.
Recognition compares the partial forward likelihoods of all skills. Its confidence is the
open-set posterior of :mod:`~pourbench.teleop.confidence`: the probability of the best skill
against the other skills and a "none of these" hypothesis whose per-sample log-density is
learnt by :meth:`SkillLibrary.calibrate` from held-out demonstrations. Before calibration (or
for a recognition mode that was not calibrated) the confidence is the closed-set posterior
over the skills, and :attr:`Recognition.calibrated` is False. Optionally
(``invariant=True``, our addition) each skill first aligns the operator's trajectory to itself
with rigid CPD, so a rotated or scaled operator is still recognised; such scores differ from
the plain ones, so each mode has its own calibration. Results are cached per trajectory, so
the same partial trajectory asked twice costs nothing the second time.

A second recognizer (``recognizer="shape"``, our addition) scores the operator's step
directions against each skill's mean path instead (:mod:`~pourbench.teleop.shape`), invariant
to translation always and, with ``invariant=True``, to a rotation and a scale within the same
limits, searched exhaustively rather than by CPD. Its "none of these" hypothesis explains the
whole trajectory (``W = None``); docs/teleop.md measures both recognizers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pourbench.errors import (
    InvalidParameterError,
    UnknownNameError,
    check_finite,
    check_int,
    check_positive,
)
from pourbench.teleop.confidence import (
    WINDOWS,
    CalibrationExample,
    NoneModel,
    fit_none_model,
    open_set_posterior,
)
from pourbench.teleop.cpd import RigidResult, register_rigid
from pourbench.teleop.demos import delta_sample
from pourbench.teleop.hsmm import HSMM, Progress, trajectory_features
from pourbench.teleop.lqt import lqt_track
from pourbench.teleop.shape import ShapeMatch, ShapeModel, match_shape

__all__ = ["RECOGNIZERS", "Recognition", "Skill", "SkillLibrary"]

RECOGNIZERS: tuple[str, ...] = ("hsmm", "shape")
"""How :meth:`SkillLibrary.recognize` scores a partial trajectory: the HSMM's partial
likelihood (the thesis) or the step directions against the mean path (ours)."""

# how each recognizer's "none of these" meets its skills (pourbench.teleop.confidence.GATES)
GATE = {"hsmm": "filler", "shape": "fit"}


@dataclass(frozen=True)
class Skill:
    """One learnt skill.

    Attributes:
        label: skill name.
        model: the fitted HSMM.
        trajectory: (M, D) LQT reproduction, one point per HSMM step, metres (``xi_a``),
            starting at the demonstrations' mean start point.
        shape: the demonstrations' mean path and step-direction spread, for the shape
            recognizer (``None`` for one-dimensional skills, which have no rotation).
    """

    label: str
    model: HSMM
    trajectory: np.ndarray
    shape: ShapeModel | None = field(default=None, repr=False, compare=False)


@dataclass(frozen=True)
class Recognition:
    """Result of recognising a partial trajectory.

    Attributes:
        label: most likely skill.
        confidence: its probability against the other skills and "none of these" when
            ``calibrated``, else its posterior among the library's skills alone.
        fraction: estimated progress along it, in [0, 1].
        logliks: partial log-likelihood per skill, nats.
        calibrated: whether the library was calibrated for this recognition mode.
        none: probability of "none of these" (0.0 when not ``calibrated``).
        alignment: invariant mode: the similarity that maps the best skill's trajectory onto
            the points (a warm start for the registration): the HSMM recognizer's rigid CPD
            of its first ``n + 10`` steps, or the shape recognizer's scale and rotation about
            the operator's start point; else ``None``.
    """

    label: str
    confidence: float
    fraction: float
    logliks: dict[str, float]
    calibrated: bool = False
    none: float = 0.0
    alignment: RigidResult | None = field(default=None, repr=False, compare=False)


@dataclass(frozen=True)
class _Scores:
    """Every skill's score of one partial trajectory in one recognition mode.

    Attributes:
        names: the skills, in the library's order.
        logliks: (K,) scores, nats (``-inf``: a skill that rejected the trajectory).
        before: (K, windows) scores without each window's last samples, nats.
        fractions: (K,) estimated progress along each skill.
        terms: how many per-sample terms a score sums (the "none" hypothesis' ``n``).
        alignments: label -> similarity onto the points, where the mode made one.
        fits: (K,) goodness of fit, nats (the shape recognizer's, for the fit gate), or
            ``None``.
    """

    names: list[str]
    logliks: np.ndarray
    before: np.ndarray
    fractions: np.ndarray
    terms: int
    alignments: dict[str, RigidResult]
    fits: np.ndarray | None = None


class SkillLibrary:
    """HSMM-encoded skills with LQT reproductions.

    Args:
        delta_d: Δd sampling distance, metres (0.006 letters, 0.01 feeding).
        n_states: HSMM states K (thesis: 5).
        lqt_r: LQT control weight (see :func:`~pourbench.teleop.lqt.lqt_track`).
        reg: covariance regulariser of the HSMM, feature units squared.

    Raises:
        InvalidParameterError: ``delta_d``, ``lqt_r`` or ``reg`` not finite and > 0, or
            ``n_states`` not an integer >= 1.
    """

    def __init__(
        self,
        delta_d: float,
        *,
        n_states: int = 5,
        lqt_r: float = 1e-3,
        reg: float = 1e-6,
    ) -> None:
        self.delta_d = check_positive("delta_d", delta_d)
        self.n_states = check_int("n_states", n_states, minimum=1)
        self.lqt_r = check_positive("lqt_r", lqt_r)
        self.reg = check_positive("reg", reg)
        self.skills: dict[str, Skill] = {}
        self._cache: dict[tuple[object, ...], Recognition] = {}
        self._none: dict[tuple[object, ...], NoneModel] = {}  # calibration per mode

    @property
    def labels(self) -> list[str]:
        """Names of the learnt skills."""
        return list(self.skills)

    def fit(self, demos: Mapping[str, Sequence[np.ndarray]]) -> SkillLibrary:
        """Learn every skill from raw demonstrations.

        Skills already in the library and not named in ``demos`` are kept; the named ones
        are (re)learnt. The update is atomic: every skill is learnt first, and the library
        (its recognition cache, and its calibrations, which are then dropped) changes only
        when all of them succeeded.

        Args:
            demos: skill label -> list of (n, D) raw trajectories (metres, any sampling rate).

        Raises:
            InvalidParameterError: ``demos`` is empty or not a mapping, a skill has no
                demonstrations, a demonstration is malformed or too short (after Δd
                sampling it needs more than ``n_states`` points), or the skills (new and
                kept) do not all have the same dimension D. The library is then unchanged.
        """
        prepared = _check_demos(demos)
        dims: dict[str, int] = {k: sk.trajectory.shape[1] for k, sk in self.skills.items()}
        dims.update({label: arrs[0].shape[1] for label, arrs in prepared.items()})
        if len(set(dims.values())) > 1:
            raise InvalidParameterError(
                f"all skills must have the same dimension, got {dict(sorted(dims.items()))}"
            )
        learnt: dict[str, Skill] = {}
        for label, arrs in prepared.items():
            try:
                learnt[label] = self._learn(label, arrs)
            except InvalidParameterError as exc:
                raise InvalidParameterError(f"skill {label!r}: {exc}") from exc
        self.skills.update(learnt)
        self._cache.clear()
        self._none.clear()  # the scores changed: every calibration is stale
        return self

    def _learn(self, label: str, trajs: list[np.ndarray]) -> Skill:
        """One skill from its (validated) raw demonstrations; touches no state."""
        paths = [delta_sample(t, self.delta_d) for t in trajs]
        model = HSMM(self.n_states, reg=self.reg).fit([trajectory_features(p) for p in paths])
        origin = np.mean([p[0] for p in paths], axis=0)
        act = model.state_sequence()
        mu = act @ model.mu
        sigma = model.sigma[np.argmax(act, axis=1)]
        # start where the demonstrations start (relative position 0), at state 0's velocity
        D = origin.size
        x0 = np.concatenate([np.zeros(D), model.mu[0, D:]])
        rep = lqt_track(mu, sigma, r=self.lqt_r, x0=x0)
        trajectory = rep.positions + origin
        shape = ShapeModel(trajs, paths, self.delta_d, reproduction=trajectory) if D >= 2 else None
        return Skill(label, model, trajectory, shape)

    def skill(self, label: str) -> Skill:
        """The skill named ``label``."""
        if label not in self.skills:
            raise UnknownNameError("skill", label, self.skills)
        return self.skills[label]

    def _check_points(self, points: object) -> np.ndarray:
        if not self.skills:
            raise InvalidParameterError("the skill library is empty: call fit() first")
        pts = np.asarray(points, dtype=float)
        dim = next(iter(self.skills.values())).trajectory.shape[1]
        if pts.ndim != 2 or pts.shape[1] != dim:
            raise InvalidParameterError(
                f"points must be (n, {dim}) like the skills, got shape {pts.shape}"
            )
        return pts

    def _mode(
        self, invariant: bool, max_rotation_deg: float, max_scale: float, recognizer: str
    ) -> tuple[object, ...]:
        """Key of a recognition mode (the alignment limits matter only when invariant)."""
        if not isinstance(recognizer, str) or recognizer not in RECOGNIZERS:
            raise InvalidParameterError(
                f"recognizer must be one of {list(RECOGNIZERS)}, got {recognizer!r}"
            )
        if not isinstance(invariant, bool | np.bool_):
            raise InvalidParameterError(f"invariant must be True or False, got {invariant!r}")
        check_finite("max_rotation_deg", max_rotation_deg, minimum=0.0)
        check_finite("max_scale", max_scale, minimum=1.0)
        if recognizer == "shape" and any(sk.shape is None for sk in self.skills.values()):
            raise InvalidParameterError(
                "the shape recognizer needs skills of at least two dimensions (it rotates the "
                "first two coordinates); use recognizer='hsmm'"
            )
        if invariant:
            return (recognizer, True, float(max_rotation_deg), float(max_scale))
        return (recognizer, False)

    def _scores(
        self, pts: np.ndarray, mode: tuple[object, ...], windows: tuple[int | None, ...]
    ) -> _Scores:
        """Every skill's score of validated points in a recognition mode, with the scores
        without each window's last samples (the "none" hypothesis' ``before``)."""
        names = list(self.skills)
        if mode[0] == "hsmm":
            lookbacks = tuple(w for w in windows if w is not None)
            prog, aligns = self._progress(pts, mode, lookbacks)
            return _Scores(
                names,
                np.array([prog[k].loglik for k in names]),
                np.array([prog[k].before for k in names]).reshape(len(names), len(lookbacks)),
                np.array([prog[k].fraction for k in names]),
                pts.shape[0],
                aligns,
            )
        if mode[1]:
            _, _, max_rotation_deg, max_scale = mode
            assert isinstance(max_rotation_deg, float) and isinstance(max_scale, float)
            limits = {"max_rotation": np.radians(max_rotation_deg), "max_scale": max_scale}
        else:
            limits = {}
        # _mode refused the shape recognizer unless every skill has a shape; the filter only
        # narrows the type
        shapes = {k: sk.shape for k, sk in self.skills.items() if sk.shape is not None}
        matches = {k: match_shape(pts, m, **limits) for k, m in shapes.items()}
        before = np.zeros((len(names), len(windows)))
        for col, w in enumerate(windows):
            if w is not None and pts.shape[0] - w >= 2:
                head = pts[: pts.shape[0] - w]
                before[:, col] = [match_shape(head, shapes[k], **limits).loglik for k in names]
        ll = np.array([matches[k].loglik for k in names])
        best = names[int(np.argmax(ll))]
        return _Scores(
            names,
            ll,
            before,
            np.array([matches[k].fraction for k in names]),
            pts.shape[0] - 1,  # one term a step
            {best: self._shape_alignment(pts, self.skills[best], matches[best])},
            np.array([matches[k].fit for k in names]),
        )

    def _shape_alignment(self, pts: np.ndarray, skill: Skill, m: ShapeMatch) -> RigidResult:
        """The shape match as the similarity that maps the skill's trajectory onto ``pts``:
        its start onto the operator's start, turned by the rotation and scaled; ``sigma2`` is
        the mean squared distance from the operator's points to that image per dimension (at
        least (Δd / 2)², so that the registration's EM starts wide enough to move)."""
        D = pts.shape[1]
        R = np.eye(D)
        c, s = np.cos(m.rotation), np.sin(m.rotation)
        R[:2, :2] = [[c, -s], [s, c]]
        traj = skill.trajectory
        t = pts[0] - m.scale * R @ traj[0]
        image = m.scale * traj @ R.T + t
        d2 = np.min(((pts[:, None, :] - image[None, :, :]) ** 2).sum(-1), axis=1)
        sigma2 = max(float(d2.mean()) / D, 0.25 * self.delta_d**2)
        return RigidResult(image, R, t, m.scale, sigma2, 0)

    def _progress(
        self, pts: np.ndarray, mode: tuple[object, ...], lookbacks: tuple[int, ...] = ()
    ) -> tuple[dict[str, Progress], dict[str, RigidResult]]:
        """Partial HSMM scores of every skill for validated points, and the alignments."""
        if not mode[1]:
            f = trajectory_features(pts)
            return {k: sk.model.partial(f, lookbacks) for k, sk in self.skills.items()}, {}
        trajectory_features(pts)  # same checks (>= 2 finite points) as the plain mode
        if not np.any(pts != pts[0]):
            raise InvalidParameterError(
                "points are all identical: an invariant alignment needs a spread of points"
            )
        _, _, max_rotation_deg, max_scale = mode
        assert isinstance(max_rotation_deg, float) and isinstance(max_scale, float)
        prog, aligns = {}, {}
        for k, sk in self.skills.items():
            m = min(sk.trajectory.shape[0], pts.shape[0] + 10)
            rig = register_rigid(pts, sk.trajectory[:m], w=0.1, tol=1e-3, max_iter=60)
            ang = np.degrees(np.arccos(np.clip((np.trace(rig.R) - (pts.shape[1] - 2)) / 2, -1, 1)))
            ok = ang <= max_rotation_deg and 1.0 / max_scale <= rig.s <= max_scale
            aligned = (pts - rig.t) @ rig.R / rig.s
            p = sk.model.partial(trajectory_features(aligned), lookbacks)
            if not ok:
                rejected = tuple(-np.inf for _ in lookbacks)
                p = Progress(-np.inf, p.state, p.fraction, p.step, rejected)
            prog[k], aligns[k] = p, rig
        return prog, aligns

    def recognize(
        self,
        points: np.ndarray,
        *,
        invariant: bool = False,
        max_rotation_deg: float = 45.0,
        max_scale: float = 1.5,
        recognizer: str = "hsmm",
    ) -> Recognition:
        """Recognise a partial, Δd-sampled trajectory (n >= 2, metres).

        Args:
            points: (n, D) operator trajectory so far.
            invariant: recognise a rotated or scaled operator too. The HSMM recognizer first
                aligns the trajectory to each skill with rigid CPD (rotation, scale,
                translation; template = the skill's first ``n + 10`` steps, n = number of
                operator samples) and scores the aligned trajectory, rejecting alignments
                that rotate by more than ``max_rotation_deg`` or scale by more than
                ``max_scale`` (or less than its inverse); the shape recognizer searches
                every rotation and scale within those limits.
            max_rotation_deg: largest accepted rotation, degrees (finite, >= 0).
            max_scale: largest accepted scale factor (finite, >= 1).
            recognizer: ``"hsmm"`` (the thesis: the HSMMs' partial likelihood) or
                ``"shape"`` (the step directions against the mean path,
                :mod:`~pourbench.teleop.shape`); one of :data:`RECOGNIZERS`.

        Returns:
            The most likely skill; its confidence is calibrated (open set) when
            :meth:`calibrate` was run for this mode (the same ``recognizer``, ``invariant``
            and, when invariant, the same limits), else the closed-set posterior.

        Raises:
            InvalidParameterError: the library is empty, ``points`` is not a finite (n >= 2,
                D) array with the skills' D (a moving one, for an invariant or shape
                recognition), ``recognizer`` is unknown, or ``max_rotation_deg`` /
                ``max_scale`` is out of its range.
        """
        pts = self._check_points(points)
        mode = self._mode(invariant, max_rotation_deg, max_scale, recognizer)
        key = (pts.tobytes(), pts.shape, mode)
        if key in self._cache:
            return self._cache[key]
        model = self._none.get(mode)
        sc = self._scores(pts, mode, (model.window,) if model else ())
        ll = sc.logliks
        post = open_set_posterior(ll, sc.before[:, 0] if model else None, sc.terms, model, sc.fits)
        best = int(np.argmax(ll)) if np.any(np.isfinite(ll)) else 0
        label = sc.names[best]
        out = Recognition(
            label,
            float(post[best]),
            float(sc.fractions[best]) if np.isfinite(ll[best]) else 0.0,
            {k: float(v) for k, v in zip(sc.names, ll, strict=True)},
            calibrated=model is not None,
            none=float(post[-1]) if model is not None else 0.0,
            alignment=sc.alignments.get(label),
        )
        if len(self._cache) > 64:
            self._cache.clear()
        self._cache[key] = out
        return out

    def calibrate(
        self,
        demos: Mapping[str, Sequence[np.ndarray]],
        *,
        fractions: Sequence[float] = (0.4, 0.5, 0.6),
        invariant: bool = False,
        max_rotation_deg: float = 45.0,
        max_scale: float = 1.5,
        recognizer: str = "hsmm",
    ) -> NoneModel:
        """Learn the "none of these" hypothesis from held-out demonstrations.

        See :mod:`~pourbench.teleop.confidence` for the model and the fit. Every
        demonstration is Δd-sampled and scored at each prefix ``fractions`` of its length
        (at least 2 samples), with the same recognition mode as :meth:`recognize`
        (``recognizer``, ``invariant`` and its limits); later recognitions in that mode
        return the calibrated confidence. Refitting skills drops every calibration. The
        HSMM recognizer's "none" is a filler whose window ``W`` is chosen among
        :data:`~pourbench.teleop.confidence.WINDOWS`; the shape recognizer's is the fit
        gate (each skill's misfit in units of its own spread, over the whole trajectory).

        Args:
            demos: skill label -> list of (n, D) raw trajectories of that skill (metres),
                none of them used in :meth:`fit`; at least two skills of the library in
                all (for the leave-one-skill-out "none" examples), no unknown label.
            fractions: prefix lengths as fractions of each demonstration, each in (0, 1]
                (default: 40-60 %, where the benchmark's network drops fall).
            invariant, max_rotation_deg, max_scale, recognizer: the recognition mode
                calibrated.

        Returns:
            The fitted hypothesis (window ``W`` and log-density ``tau``).

        Raises:
            InvalidParameterError: an empty or uncalibratable library (fewer than two
                skills), malformed demonstrations (as :meth:`fit`), a demonstration with
                fewer than 2 Δd samples, bad ``fractions``, alignment limits or
                ``recognizer``, or no demonstration scored finitely by its own skill. The
                library is then unchanged.
            UnknownNameError: a label that is not a skill of the library.
        """
        if len(self.skills) < 2:
            raise InvalidParameterError(
                f"calibration needs a library of at least two skills, it has {len(self.skills)}"
            )
        prepared = _check_demos(demos)
        for label in prepared:
            self.skill(label)  # UnknownNameError for a label that is not a skill
        try:
            fr = [check_finite("fractions", f, minimum=0.0) for f in fractions]
        except TypeError as exc:
            raise InvalidParameterError(f"fractions must be numbers, got {fractions!r}") from exc
        if not fr or any(not 0.0 < f <= 1.0 for f in fr):
            raise InvalidParameterError(f"fractions must be in (0, 1], got {fractions!r}")
        mode = self._mode(invariant, max_rotation_deg, max_scale, recognizer)
        windows: tuple[int | None, ...] = WINDOWS if recognizer == "hsmm" else (None,)
        names = list(self.skills)
        examples = []
        for label, arrs in prepared.items():
            for i, a in enumerate(arrs):
                pts = delta_sample(self._check_points(a), self.delta_d)
                if pts.shape[0] < 2:
                    raise InvalidParameterError(
                        f"skill {label!r}: demonstration {i} has fewer than 2 samples Δd apart"
                    )
                for f in fr:
                    n = max(2, round(f * pts.shape[0]))
                    sc = self._scores(pts[:n], mode, windows)
                    examples.append(
                        CalibrationExample(
                            sc.logliks, sc.before, sc.terms, names.index(label), sc.fits
                        )
                    )
        model = fit_none_model(examples, windows, gate=GATE[recognizer])
        self._none[mode] = model
        self._cache.clear()
        return model

    def calibration(
        self,
        *,
        invariant: bool = False,
        max_rotation_deg: float = 45.0,
        max_scale: float = 1.5,
        recognizer: str = "hsmm",
    ) -> NoneModel | None:
        """The calibrated "none" hypothesis of a recognition mode, or ``None``."""
        return self._none.get(self._mode(invariant, max_rotation_deg, max_scale, recognizer))


def _check_demos(demos: object) -> dict[str, list[np.ndarray]]:
    """Validated ``label -> list of (n, D) float arrays`` (same D within a skill)."""
    if not isinstance(demos, Mapping):
        raise InvalidParameterError(
            f"demos must be a mapping label -> demonstrations, got {type(demos).__name__}"
        )
    if not demos:
        raise InvalidParameterError("demos is empty: need at least one skill")
    prepared: dict[str, list[np.ndarray]] = {}
    for label, trajs in demos.items():
        if isinstance(trajs, np.ndarray):
            raise InvalidParameterError(
                f"skill {label!r}: demonstrations must be a list of (n, D) arrays, "
                f"got one array of shape {trajs.shape}"
            )
        if not trajs:
            raise InvalidParameterError(f"skill {label!r} has no demonstrations")
        arrs: list[np.ndarray] = []
        for i, t in enumerate(trajs):
            try:
                a = np.asarray(t, dtype=float)
            except (TypeError, ValueError) as exc:
                raise InvalidParameterError(
                    f"skill {label!r}: demonstration {i} must be numbers"
                ) from exc
            if a.ndim != 2 or a.shape[1] < 1:
                raise InvalidParameterError(
                    f"skill {label!r}: demonstration {i} must be (n, D), got {a.shape}"
                )
            if a.shape[1] != (arrs[0].shape[1] if arrs else a.shape[1]):
                raise InvalidParameterError(
                    f"skill {label!r}: demonstration {i} has {a.shape[1]} dims, "
                    f"demonstration 0 has {arrs[0].shape[1]}"
                )
            arrs.append(a)
        prepared[str(label)] = arrs
    return prepared
