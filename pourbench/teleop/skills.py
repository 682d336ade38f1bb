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

from pourbench.errors import InvalidParameterError, UnknownNameError
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
    """

    def __init__(
        self,
        delta_d: float,
        *,
        n_states: int = 5,
        lqt_r: float = 1e-3,
        reg: float = 1e-6,
    ) -> None:
        if not delta_d > 0:
            raise InvalidParameterError(f"delta_d must be > 0, got {delta_d}")
        self.delta_d = float(delta_d)
        self.n_states = int(n_states)
        self.lqt_r = float(lqt_r)
        self.reg = float(reg)
        self.skills: dict[str, Skill] = {}
        self._cache: dict[tuple[object, ...], Recognition] = {}

    @property
    def labels(self) -> list[str]:
        """Names of the learnt skills."""
        return list(self.skills)

    def fit(self, demos: Mapping[str, Sequence[np.ndarray]]) -> SkillLibrary:
        """Learn every skill from raw demonstrations.

        Args:
            demos: skill label -> list of (n, D) raw trajectories (metres, any sampling rate).
        """
        if not demos:
            raise InvalidParameterError("demos is empty: need at least one skill")
        for label, trajs in demos.items():
            if not trajs:
                raise InvalidParameterError(f"skill {label!r} has no demonstrations")
            paths = [delta_sample(np.asarray(t, dtype=float), self.delta_d) for t in trajs]
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
            self.skills[str(label)] = Skill(str(label), model, origin, mean_path, traj)
        self._cache.clear()
        return self

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
            max_rotation_deg: largest accepted rotation, degrees.
            max_scale: largest accepted scale factor.
        """
        if not self.skills:
            raise InvalidParameterError("the skill library is empty: call fit() first")
        pts = np.asarray(points, dtype=float)
        key = (pts.tobytes(), pts.shape, invariant, max_rotation_deg, max_scale)
        if key in self._cache:
            return self._cache[key]
        f = trajectory_features(pts)
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
