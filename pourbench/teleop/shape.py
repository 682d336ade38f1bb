"""Shape recognition: a partial trajectory's step directions against a skill's mean path.

Our addition; the thesis recognises with the HSMM's forward likelihood
(:mod:`~pourbench.teleop.hsmm`). Written by hand: no library matches a partial path against a
template under a bounded rotation and scale.

**Model of a skill.** Its demonstrations, each parametrised by arc length and moved to start
at the origin, are averaged into a mean path (:attr:`ShapeModel.path`, metres). Each
demonstration's own Δd-sampled steps, matched against that mean (below), give the spread of
the step direction at each arc length of the mean path: ``σ(a)``, radians, per bin of
``2 Δd``, shrunk toward :data:`SIGMA_PRIOR` by :data:`PRIOR_STEPS` pseudo-steps (ten
demonstrations give a few steps a bin), widened to the largest of the neighbouring bins
(a corner may land a bin early or late) and at least :data:`SIGMA_FLOOR`. The skill's own
reproduction, when given, is a second template with the same spread at the same share of its
length: an operator who follows the skill as the library reproduces it (rounded corners,
a shorter path) is explained by it, one who writes like the demonstrations by the mean.

**Matching a partial trajectory.** The operator's Δd-sampled points ``x_0 .. x_n`` give unit
step directions ``u_i`` and cumulative arc lengths ``a_i``. For a scale ``s`` the operator's
step ``i`` is the mean path's chord from arc ``a_i / s`` to ``a_{i+1} / s`` (its direction
``v_i``); for a rotation ``φ`` about the vertical axis (the first two coordinates) the angle
``e_i`` between ``u_i`` and ``R(φ) v_i`` has the density

``p(e) = (1 - ε) N(e; 0, σ(a)) + ε / π``   (:data:`OUTLIER_SHARE` ``ε``),

so a step that lands a little off at a corner costs a bounded amount. The score is the largest
``sum_i log p(e_i)`` (nats) over scales on a log grid (ratio at most :data:`SCALE_STEP`
between neighbours) within ``[1 / max_scale, max_scale]``, each at the rotation that maximises
the ``σ⁻²``-weighted cosine sum (closed form), clipped to ``±max_rotation``, and over the
templates. Both operator and
skill start where the stroke starts, so no search over where the operator is along the skill is
needed; a translation changes no direction. Without invariance the scale is 1 and the
rotation 0.

The match also reports its fit, ``-1/2 sum_i min(e_i / σ_i, 7)²`` at the best scale and
rotation (nats; :data:`FIT_CAP`): how far the operator is from the skill in units of the
skill's own spread, which the fit gate of :mod:`~pourbench.teleop.confidence` compares with
a calibrated rate per step to tell a known skill from none of the library's.

Units: points in metres, angles in radians, log-densities in nats per step (of an angle,
so comparable between skills of a library and with a calibrated per-step rate, not with
the HSMM's feature densities).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d

from pourbench.errors import InvalidParameterError, check_positive

__all__ = [
    "FIT_CAP",
    "OUTLIER_SHARE",
    "PRIOR_STEPS",
    "SCALE_STEP",
    "SIGMA_FLOOR",
    "SIGMA_PRIOR",
    "ShapeMatch",
    "ShapeModel",
    "match_shape",
]

OUTLIER_SHARE = 0.05
"""``ε``: share of steps explained by a uniform angle instead of the spread ``σ(a)``."""
SIGMA_PRIOR = 0.03
"""Step-direction spread a bin is shrunk toward, rad."""
PRIOR_STEPS = 5.0
"""Weight of :data:`SIGMA_PRIOR`, in steps."""
SIGMA_FLOOR = 0.02
"""Smallest step-direction spread, rad."""
SCALE_STEP = 1.02
"""Largest ratio between neighbouring scales of the search grid."""
FIT_CAP = 7.0
"""Largest misfit a step adds to :attr:`ShapeMatch.fit`, in spreads (``|e| / σ``): one step
across a sharp corner, a sample's length off the template's, does not veto a prefix."""
_GRID_PER_DELTA = 6  # mean-path samples per Δd
_BINS_PER_DELTA = 0.5  # spread bins per Δd (one bin every 2 Δd)


def _arc(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length at each point, starting at 0."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def _by_arc(points: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The polyline ``points`` sampled at arc lengths ``at``."""
    a = _arc(points)
    return np.stack([np.interp(at, a, points[:, d]) for d in range(points.shape[1])], axis=1)


def _unit_steps(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(moving, u, lo, hi)`` of a path's steps: which steps move (a repeated point has no
    direction), the moving steps' unit directions, and the arc lengths they start and end
    at, metres."""
    d = np.diff(points, axis=0)
    length = np.linalg.norm(d, axis=1)
    moving = length > 0.0
    a = _arc(points)
    return moving, d[moving] / length[moving, None], a[:-1][moving], a[1:][moving]


def _check_path(name: str, points: object, dim: int | None = None) -> np.ndarray:
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] < 2:
        raise InvalidParameterError(
            f"{name} must be (n >= 2, D >= 2) points (shape recognition rotates the first two "
            f"coordinates), got shape {pts.shape}"
        )
    if dim is not None and pts.shape[1] != dim:
        raise InvalidParameterError(f"{name} must have {dim} coordinates, got {pts.shape[1]}")
    if not np.all(np.isfinite(pts)):
        raise InvalidParameterError(f"{name} contains NaN or infinite coordinates")
    if _arc(pts)[-1] <= 0.0:
        raise InvalidParameterError(f"{name} does not move: all its points are identical")
    return pts


@dataclass(frozen=True)
class ShapeMatch:
    """The best match of a partial trajectory against one :class:`ShapeModel`.

    Attributes:
        loglik: ``sum_i log p(e_i)`` over the trajectory's steps, nats.
        step_logliks: (n - 1,) the terms of that sum, nats.
        scale: ``s``: the operator's size over the template's.
        rotation: ``φ``, rad, counter-clockwise in the first two coordinates, from the
            template's directions to the operator's.
        fraction: the operator's arc length over ``s`` as a share of the template, in [0, 1].
        template: which template matched best: 0 the mean path, 1 the skill's reproduction.
        fit: ``-1/2 sum_i min(e_i / σ_i, FIT_CAP)²`` at that match, nats: the steps'
            misfit in units of the skill's own spread (the fit gate's score,
            :mod:`~pourbench.teleop.confidence`).
    """

    loglik: float
    step_logliks: np.ndarray
    scale: float
    rotation: float
    fraction: float
    template: int = 0
    fit: float = 0.0


class _Template:
    """A path resampled every ``grid`` metres of arc, starting at the origin."""

    def __init__(self, points: np.ndarray, grid: float) -> None:
        pts = points - points[0]
        self.grid = grid
        self.path = _by_arc(pts, np.arange(0.0, _arc(pts)[-1], grid))
        if self.path.shape[0] < 2:
            raise InvalidParameterError("a shape template is shorter than Δd / 6")
        self.length = float(grid * (self.path.shape[0] - 1))

    def chords(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Unit directions of the path's chords from arc ``lo`` to ``hi`` (same shape)."""
        last = self.path.shape[0] - 1
        i = np.clip(np.round(lo / self.grid).astype(int), 0, last - 1)
        j = np.clip(np.round(hi / self.grid).astype(int), 1, last)
        v = self.path[np.maximum(j, i + 1)] - self.path[i]
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


class ShapeModel:
    """A skill's mean path and step-direction spread (see the module docstring).

    Args:
        demos: raw demonstrations, each (n, D) metres with D >= 2, any sampling.
        sampled: the same demonstrations Δd-sampled (the steps an operator gives).
        delta_d: the Δd of ``sampled``, metres.
        reproduction: the skill's own trajectory (its LQT reproduction), matched as a
            second template with the same spread at the same share of its length, so that
            an operator who follows the skill as the library reproduces it is recognised too
            (a 20-state reproduction rounds the demonstrations' corners); ``None``: the
            mean path alone.
        max_rotation: largest rotation when matching the demonstrations to learn the
            spread, rad.
        max_scale: largest scale factor for the same.

    Attributes:
        path: (m, D) the mean path, one point every Δd / 6 of arc, from the origin.
        length: its arc length, metres.
        sigma: the spread per bin of ``bin`` metres (2 Δd) of the mean path's arc, rad.
        templates: what a trajectory is matched against: the mean path, then the
            reproduction when given.

    Raises:
        InvalidParameterError: no demonstrations, ``demos`` and ``sampled`` of different
            lengths, a demonstration (or the reproduction) that is not a finite, moving
            (n >= 2, D >= 2) path, dimensions that differ, or ``delta_d`` not finite and > 0.
    """

    def __init__(
        self,
        demos: Sequence[np.ndarray],
        sampled: Sequence[np.ndarray],
        delta_d: float,
        *,
        reproduction: np.ndarray | None = None,
        max_rotation: float = np.pi / 4,
        max_scale: float = 1.5,
    ) -> None:
        if not demos or len(demos) != len(sampled):
            raise InvalidParameterError(
                f"need as many Δd-sampled demonstrations as raw ones (at least one), got "
                f"{len(demos)} and {len(sampled)}"
            )
        raw = [_check_path(f"demonstration {i}", d) for i, d in enumerate(demos)]
        dim = raw[0].shape[1]
        steps = [_check_path(f"sampled demonstration {i}", d, dim) for i, d in enumerate(sampled)]
        self.dim = dim
        grid = check_positive("delta_d", delta_d) / _GRID_PER_DELTA
        # each demonstration at the same fractions of its length, moved to start at 0
        n = max(2, round(np.mean([_arc(d)[-1] for d in raw]) / grid))
        means = [_by_arc(d, np.linspace(0.0, _arc(d)[-1], n)) for d in raw]
        mean = _Template(np.mean([m - m[0] for m in means], axis=0), grid)
        self.templates = [mean]  # the mean path (its spread is learnt) before the rest
        self.path, self.length = mean.path, mean.length
        self.bin = delta_d / _BINS_PER_DELTA
        bins = int(np.ceil(self.length / self.bin)) + 1
        self.sigma = np.full(bins, SIGMA_PRIOR)  # provisional spread, to match the demos
        sq, count = np.zeros(bins), np.zeros(bins)
        for pts in steps:
            m = match_shape(pts, self, max_rotation=max_rotation, max_scale=max_scale)
            _, u, lo, hi = _unit_steps(pts)
            lo, hi = lo / m.scale, hi / m.scale  # along the mean path
            e = _angles(u, mean.chords(lo, hi), np.array(m.rotation))
            at = self._bins(0.5 * (lo + hi))
            np.add.at(sq, at, e**2)
            np.add.at(count, at, 1.0)
        spread = np.sqrt((sq + PRIOR_STEPS * SIGMA_PRIOR**2) / (count + PRIOR_STEPS))
        self.sigma = np.maximum(maximum_filter1d(spread, 3, mode="nearest"), SIGMA_FLOOR)
        if reproduction is not None:
            rep = _check_path("reproduction", reproduction, dim)
            self.templates.append(_Template(rep, grid))

    def _bins(self, arc: np.ndarray) -> np.ndarray:
        """Spread bins of arc lengths along the mean path."""
        return np.clip((arc / self.bin).astype(int), 0, self.sigma.size - 1)


def _planar(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``u · v`` and ``u × v`` in the first two coordinates, for unit vectors ``u`` (n, D) and
    ``v`` (..., n, D): ``u · R(φ) v`` is ``cos φ`` times the first plus ``sin φ`` times the
    second, plus the remaining coordinates' product."""
    dot = u[:, 0] * v[..., 0] + u[:, 1] * v[..., 1]
    cross = u[:, 1] * v[..., 0] - u[:, 0] * v[..., 1]
    return dot, cross


def _angles(u: np.ndarray, v: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Angles between unit vectors ``u`` (n, D) and ``v`` (..., n, D) rotated by
    ``rotation`` (...) in the first two coordinates, rad (..., n)."""
    dot, cross = _planar(u, v)
    rot = np.asarray(rotation)[..., None]
    cos = np.cos(rot) * dot + np.sin(rot) * cross + np.sum(u[:, 2:] * v[..., 2:], axis=-1)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def _scales(max_scale: float) -> np.ndarray:
    """The search grid over ``[1 / max_scale, max_scale]``, log-spaced, 1 included."""
    if max_scale <= 1.0:
        return np.ones(1)
    half = int(np.ceil(np.log(max_scale) / np.log(SCALE_STEP)))
    return np.exp(np.linspace(-np.log(max_scale), np.log(max_scale), 2 * half + 1))


def match_shape(
    points: np.ndarray, model: ShapeModel, *, max_rotation: float = 0.0, max_scale: float = 1.0
) -> ShapeMatch:
    """Best match of a partial, Δd-sampled trajectory against ``model``.

    Args:
        points: (n >= 2, D) operator trajectory from where the stroke starts, metres.
        model: the skill's shape.
        max_rotation: largest rotation searched, rad (0: none).
        max_scale: largest scale factor searched (1: none), >= 1.

    Raises:
        InvalidParameterError: ``points`` is not a finite, moving (n >= 2, D) path with the
            model's D, or the limits are negative / below 1.
    """
    pts = _check_path("points", points, model.dim)
    if not (np.isfinite(max_rotation) and max_rotation >= 0.0):
        raise InvalidParameterError(f"max_rotation must be finite and >= 0, got {max_rotation!r}")
    if not (np.isfinite(max_scale) and max_scale >= 1.0):
        raise InvalidParameterError(f"max_scale must be finite and >= 1, got {max_scale!r}")
    moving, u, lo, hi = _unit_steps(pts)  # a repeated point scores nothing
    length = float(hi[-1])  # the path's arc length: repeated points add none
    scales = _scales(max_scale)[:, None]
    best: ShapeMatch | None = None
    for k, template in enumerate(model.templates):
        v = template.chords(lo / scales, hi / scales)  # (S, m, D)
        # the spread at the same share of the mean path's length
        share = model.length / template.length
        sigma = model.sigma[model._bins(0.5 * (lo + hi) / scales * share)]  # (S, m)
        dot, cross = _planar(u, v)
        w = sigma**-2
        rotation = np.clip(
            np.arctan2(np.sum(w * cross, axis=1), np.sum(w * dot, axis=1)),
            -max_rotation,
            max_rotation,
        )
        e = _angles(u, v, rotation)
        inlier = (
            np.log1p(-OUTLIER_SHARE) - 0.5 * (e / sigma) ** 2 - np.log(np.sqrt(2 * np.pi) * sigma)
        )
        terms = np.logaddexp(inlier, np.log(OUTLIER_SHARE / np.pi))
        i = int(np.argmax(terms.sum(axis=1)))
        if best is not None and terms[i].sum() <= best.loglik:
            continue
        steps = np.zeros(moving.size)
        steps[moving] = terms[i]
        s = float(scales[i, 0])
        fraction = min(length / s / template.length, 1.0)
        fit = -0.5 * float(np.sum(np.minimum(e[i] / sigma[i], FIT_CAP) ** 2))
        best = ShapeMatch(float(steps.sum()), steps, s, float(rotation[i]), fraction, k, fit)
    assert best is not None
    return best
