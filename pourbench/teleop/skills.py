"""A library of learnt skills: one HSMM per skill, its LQT reproduction, and recognition.

Each skill (a letter, a feeding target) is learnt from its demonstrations, Δd-sampled
(thesis §5.3.4.1) and turned into :func:`~pourbench.teleop.hsmm.trajectory_features`. The
skill trajectory ``xi_a`` is the discrete LQT (:func:`~pourbench.teleop.lqt.lqt_track`)
tracking the HSMM's step-wise Gaussians (activation-weighted means, covariance of the most
active state), shifted to the demonstrations' mean start point. As the HSMM is learnt from
Δd-sampled demonstrations, one step of the skill corresponds to one Δd sample of the operator.
Recognition compares the partial forward likelihoods of all skills; the confidence is the
posterior of the best skill under a uniform prior. Optionally (``invariant=True``, our
addition) each skill first aligns the operator's trajectory to itself with rigid CPD, so a
rotated or scaled operator is still recognised. Results are cached per trajectory, so the
same partial trajectory asked twice costs nothing the second time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pourbench.errors import (
    InvalidParameterError,
    UnknownNameError,
    check_finite,
    check_int,
    check_positive,
)
from pourbench.teleop.cpd import register_rigid
from pourbench.teleop.demos import delta_sample
from pourbench.teleop.hsmm import HSMM, Progress, trajectory_features
from pourbench.teleop.lqt import lqt_track

__all__ = ["Recognition", "Skill", "SkillLibrary"]


@dataclass(frozen=True)
class Skill:
    """One learnt skill.

    Attributes:
        label: skill name.
        model: the fitted HSMM.
        origin: (D,) mean start point of the demonstrations, metres.
        mean_path: (T, D) HSMM step-wise mean positions (absolute), metres.
        trajectory: (M, D) LQT reproduction, one point per HSMM step, metres (``xi_a``).
    """

    label: str
    model: HSMM
    origin: np.ndarray
    mean_path: np.ndarray
    trajectory: np.ndarray


@dataclass(frozen=True)
class Recognition:
    """Result of recognising a partial trajectory.

    Attributes:
        label: most likely skill.
        confidence: its posterior probability among the library's skills.
        fraction: estimated progress along it, in [0, 1].
        logliks: partial log-likelihood per skill.
    """

    label: str
    confidence: float
    fraction: float
    logliks: dict[str, float]


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

    @property
    def labels(self) -> list[str]:
        """Names of the learnt skills."""
        return list(self.skills)

    def fit(self, demos: Mapping[str, Sequence[np.ndarray]]) -> SkillLibrary:
        """Learn every skill from raw demonstrations.

        Skills already in the library and not named in ``demos`` are kept; the named ones
        are (re)learnt. The update is atomic: every skill is learnt first, and the library
        (and its recognition cache) changes only when all of them succeeded.

        Args:
            demos: skill label -> list of (n, D) raw trajectories (metres, any sampling rate).

        Raises:
            InvalidParameterError: ``demos`` is empty or not a mapping, a skill has no
                demonstrations, a demonstration is malformed or too short (after Δd
                sampling it needs more than ``n_states`` points), or the skills (new and
                kept) do not all have the same dimension D. The library is then unchanged.
        """
        if not isinstance(demos, Mapping):
            raise InvalidParameterError(
                f"demos must be a mapping label -> demonstrations, got {type(demos).__name__}"
            )
        if not demos:
            raise InvalidParameterError("demos is empty: need at least one skill")
        # validate everything before learning anything
        dims: dict[str, int] = {k: sk.trajectory.shape[1] for k, sk in self.skills.items()}
        prepared: dict[str, list[np.ndarray]] = {}
        for label, trajs in demos.items():
            if isinstance(trajs, np.ndarray):
                raise InvalidParameterError(
                    f"skill {label!r}: demonstrations must be a list of (n, D) arrays, "
                    f"got one array of shape {trajs.shape}"
                )
            if not trajs:
                raise InvalidParameterError(f"skill {label!r} has no demonstrations")
            arrs = []
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
            dims[str(label)] = arrs[0].shape[1]
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
        mean_path = mu[:, :D] + origin
        traj = rep.positions + origin
        return Skill(label, model, origin, mean_path, traj)

    def skill(self, label: str) -> Skill:
        """The skill named ``label``."""
        if label not in self.skills:
            raise UnknownNameError("skill", label, self.skills)
        return self.skills[label]

    def recognize(
        self,
        points: np.ndarray,
        *,
        invariant: bool = False,
        max_rotation_deg: float = 45.0,
        max_scale: float = 1.5,
    ) -> Recognition:
        """Recognise a partial, Δd-sampled trajectory (n >= 2, metres).

        Args:
            points: (n, D) operator trajectory so far.
            invariant: first align the trajectory to each skill with rigid CPD (rotation,
                scale, translation; template = the skill's first ``n + 10`` steps, n = number
                of operator samples) and score the aligned trajectory, so that a rotated or
                scaled operator is still recognised. Alignments rotating by more than
                ``max_rotation_deg`` or scaling by more than ``max_scale`` (or less than its
                inverse) are rejected.
            max_rotation_deg: largest accepted rotation, degrees (finite, >= 0).
            max_scale: largest accepted scale factor (finite, >= 1).

        Raises:
            InvalidParameterError: the library is empty, ``points`` is not a finite (n >= 2,
                D) array with the skills' D, or ``max_rotation_deg`` / ``max_scale`` is out
                of its range.
        """
        if not self.skills:
            raise InvalidParameterError("the skill library is empty: call fit() first")
        check_finite("max_rotation_deg", max_rotation_deg, minimum=0.0)
        check_finite("max_scale", max_scale, minimum=1.0)
        pts = np.asarray(points, dtype=float)
        dim = next(iter(self.skills.values())).trajectory.shape[1]
        if pts.ndim != 2 or pts.shape[1] != dim:
            raise InvalidParameterError(
                f"points must be (n, {dim}) like the skills, got shape {pts.shape}"
            )
        key = (pts.tobytes(), pts.shape, invariant, max_rotation_deg, max_scale)
        if key in self._cache:
            return self._cache[key]
        f = trajectory_features(pts)
        if invariant and not np.any(pts != pts[0]):
            raise InvalidParameterError(
                "points are all identical: an invariant alignment needs a spread of points"
            )
        if invariant:
            prog = {}
            for k, sk in self.skills.items():
                m = min(sk.trajectory.shape[0], pts.shape[0] + 10)
                rig = register_rigid(pts, sk.trajectory[:m], w=0.1, tol=1e-3, max_iter=60)
                ang = np.degrees(
                    np.arccos(np.clip((np.trace(rig.R) - (pts.shape[1] - 2)) / 2, -1, 1))
                )
                ok = ang <= max_rotation_deg and 1.0 / max_scale <= rig.s <= max_scale
                aligned = (pts - rig.t) @ rig.R / rig.s
                p = sk.model.partial(trajectory_features(aligned))
                prog[k] = p if ok else Progress(-np.inf, p.state, p.fraction, p.step)
        else:
            prog = {k: sk.model.partial(f) for k, sk in self.skills.items()}
        names = list(prog)
        ll = np.array([prog[k].loglik for k in names])
        if not np.any(np.isfinite(ll)):
            out = Recognition(
                names[0], 0.0, 0.0, {k: float(v) for k, v in zip(names, ll, strict=True)}
            )
        else:
            post = np.exp(ll - ll.max())
            post /= post.sum()
            best = int(np.argmax(ll))
            out = Recognition(
                names[best],
                float(post[best]),
                prog[names[best]].fraction,
                {k: float(v) for k, v in zip(names, ll, strict=True)},
            )
        if len(self._cache) > 64:
            self._cache.clear()
        self._cache[key] = out
        return out
