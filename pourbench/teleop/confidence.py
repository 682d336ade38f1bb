"""Open-set recognition confidence: the library's skills plus a "none of these" hypothesis.

Contract. :meth:`~pourbench.teleop.skills.SkillLibrary.recognize` scores a partial, Δd-sampled
trajectory ``x_1..x_n`` by the partial HSMM log-likelihood ``ll_k = log p_k(x_1..x_n)`` of
every skill ``k`` of a library of ``K`` (nats; densities of the features ``[x - x_0,
x_t - x_{t-1}]`` in metres and metres per sample, see
:func:`~pourbench.teleop.hsmm.trajectory_features`). Beside the ``K`` skill hypotheses there is
one "none of these" hypothesis: the operator's last ``m = min(W, n)`` samples come from a skill
the library does not hold, explained by a constant log-density ``tau`` per sample (nats per
sample, same feature units; the filler model of keyword spotting), while the samples before
them are explained by the library (a uniform mixture of its skills: an unknown skill may
begin like a known one). With equal prior weights on the ``K + 1`` hypotheses the confidence
in skill ``k`` is

``c_k = exp(ll_k) / (sum_j exp(ll_j) + mean_j exp(ll_j^-) exp(m tau))``,

where ``ll_j^- = log p_j(x_1..x_{n-m})`` (0 for the empty sequence, so for ``W >= n`` the
"none" term is ``exp(n tau)``; a model calibrated with ``W = None`` always takes the whole
trajectory, ``m = n``). ``c_k`` is the probability that the operator is doing skill
``k``, rather than another skill of the library or one that it does not hold; it is what
thesis Eq. 5.2 compares with ``lambda_minconf``. Without a calibration only the closed-set
posterior ``exp(ll_k) / sum_j exp(ll_j)`` exists; it saturates at 1 for any input (the
log-likelihood gaps between skills are tens of nats), so it cannot gate anything.

Calibration. ``W`` (samples) and ``tau`` are learnt by maximum likelihood from held-out
demonstrations of the library's skills (never used to fit the HSMMs), scored at several
prefix lengths. Each scored prefix gives two labelled examples:

* with the whole library, the target is its own skill (an operator doing a known skill);
* with its own skill left out of the library, the target is "none" (an operator doing a skill
  the library does not hold): leave-one-skill-out, so no demonstration outside the library is
  needed, and the "none" examples are exactly the nearest impostors of the library.

For each candidate window ``W`` (:data:`WINDOWS` by default; ``None`` is the whole
trajectory, as the shape recognition uses) the summed log-probability of the targets is a
concave function of ``tau`` (each term is linear minus a log-sum-exp of terms linear in
``tau``); it is evaluated on a uniform grid over the bracket from the smallest to the largest
per-sample log-likelihood rate of the examples' windows, widened by 1 nat per sample, and
``tau`` is its posterior mean under a uniform prior on that bracket: the maximum-likelihood
value when the held-out data pin ``tau`` down, and the middle of the gap when they separate
known from "none" perfectly (the likelihood is then flat across the gap). The window with the
largest evidence (the likelihood integrated over the bracket) wins, the smaller on a tie. All
of it is deterministic. It needs at least two skills.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from pourbench.errors import InvalidParameterError, check_int

__all__ = [
    "WINDOWS",
    "CalibrationExample",
    "NoneModel",
    "fit_none_model",
    "open_set_posterior",
]

WINDOWS: tuple[int, ...] = (5, 10, 20, 40)
"""Candidate "none" windows ``W`` of the HSMM recognition, samples (Δd apart: 3-24 cm of path
for letters)."""

_GRID = 4001  # tau grid points between the smallest and largest per-sample rate


@dataclass(frozen=True)
class NoneModel:
    """The calibrated "none of these" hypothesis.

    Attributes:
        window: ``W``, samples (``None``: the whole trajectory).
        tau: log-density per sample, nats.
        loglik: held-out log-likelihood of the calibration targets at ``tau``, nats.
        examples: number of scored held-out prefixes it was fitted on.
    """

    window: int | None
    tau: float
    loglik: float
    examples: int


@dataclass(frozen=True)
class CalibrationExample:
    """One scored held-out prefix.

    Attributes:
        logliks: (K,) partial log-likelihood of every skill of the library, nats (``-inf``
            allowed: a skill that rejected the prefix).
        before: (K, len(windows)) log-likelihood of the prefix without its last ``W``
            samples, per skill and candidate window of the calibration, nats (0 when
            ``W >= n`` or ``W`` is ``None``).
        n: number of samples of the prefix (>= 1).
        target: index of the prefix's own skill in ``logliks``.
    """

    logliks: np.ndarray
    before: np.ndarray
    n: int
    target: int


def _span(window: int | None, n: int) -> int:
    """``m``: how many of the last samples the "none" hypothesis explains."""
    return n if window is None else min(window, n)


def _head(before: np.ndarray, window: int | None) -> np.ndarray:
    """The skills' log-likelihoods of what precedes the window: 0, the empty sequence's,
    for the whole trajectory whatever ``before`` holds."""
    before = np.asarray(before, dtype=float)
    return np.zeros(before.shape) if window is None else before


def _none_term(before: np.ndarray, m: int, tau: float) -> float:
    """log of ``mean_j exp(before_j) exp(m tau)``."""
    return float(logsumexp(before) - np.log(before.size) + m * tau)


def open_set_posterior(
    logliks: np.ndarray, before: np.ndarray | None, n: int, model: NoneModel | None
) -> np.ndarray:
    """Probabilities of the skills and, with a ``model``, of "none" (last entry).

    Args:
        logliks: (K,) partial log-likelihoods, nats (``-inf`` allowed).
        before: (K,) log-likelihoods without the last ``model.window`` samples (ignored
            without a model).
        n: samples in the scored trajectory.
        model: the calibrated "none" hypothesis, or ``None`` for the closed-set posterior
            over the skills alone.

    Returns:
        (K + 1,) probabilities with "none" last, or (K,) without a model; all zeros when
        every term is ``-inf``.

    Raises:
        InvalidParameterError: with a ``model``, ``before`` is missing or not K values, or
            ``n`` is not an integer >= 1.
    """
    ll = np.asarray(logliks, dtype=float)
    if model is None:
        z = ll
    else:
        if before is None or np.shape(before) != ll.shape:
            raise InvalidParameterError(
                f"with a calibrated model, before must be {ll.size} log-likelihoods "
                f"(without the last model.window samples), got {before!r}"
            )
        m = _span(model.window, check_int("n", n, minimum=1))
        z = np.append(ll, _none_term(_head(before, model.window), m, model.tau))
    if not np.any(np.isfinite(z)):
        return np.zeros(z.shape)
    return np.exp(z - logsumexp(z))


def _loglik_grid(
    window: int | None, col: int, examples: Sequence[CalibrationExample], taus: np.ndarray
) -> np.ndarray:
    """Log-likelihood of the calibration targets for ``window`` (column ``col`` of the
    examples' ``before``), per ``tau``."""
    total = np.zeros(taus.shape)
    for ex in examples:
        m = _span(window, ex.n)
        before = _head(ex.before[:, col], window)
        own = ex.logliks[ex.target]
        if np.isfinite(own):  # else its probability is 0 whatever tau is: no information
            none = _none_term(before, m, 0.0) + m * taus
            total += own - np.logaddexp(logsumexp(ex.logliks), none)
        rest = np.delete(before, ex.target)
        base = _none_term(rest, m, 0.0) if np.any(np.isfinite(rest)) else -np.inf
        if np.isfinite(base):  # else no skill left explains the start: no information
            none = base + m * taus
            total += none - np.logaddexp(logsumexp(np.delete(ex.logliks, ex.target)), none)
    return total


def fit_none_model(
    examples: Sequence[CalibrationExample], windows: Sequence[int | None] = WINDOWS
) -> NoneModel:
    """Calibrated ``W`` and ``tau`` from held-out examples (see the module docstring).

    Args:
        examples: the scored held-out prefixes, their ``before`` with one column per window.
        windows: the candidate windows ``W``, samples (integers >= 1, or ``None`` for the
            whole trajectory).

    Raises:
        InvalidParameterError: no examples or no windows, a window that is neither None nor
            an integer >= 1, fewer than two skills, a malformed example, or no example whose
            own skill gave a finite log-likelihood.
    """
    windows = tuple(windows)
    if not windows:
        raise InvalidParameterError("calibration needs at least one candidate window")
    for w in windows:
        if w is not None:
            check_int("window", w, minimum=1)
    if not examples:
        raise InvalidParameterError("calibration needs at least one held-out example")
    for i, ex in enumerate(examples):
        ll = np.asarray(ex.logliks, dtype=float)
        if ll.ndim != 1 or ll.size < 2:
            raise InvalidParameterError(
                f"calibration needs at least two skills (leave-one-skill-out), example {i} "
                f"has {ll.size}"
            )
        ok = (
            isinstance(ex.target, int | np.integer)
            and not isinstance(ex.target, bool)
            and 0 <= ex.target < ll.size
            and ex.n >= 1
            and np.shape(ex.before) == (ll.size, len(windows))
            and not np.any(np.isnan(ll))
            and not np.any(np.isnan(ex.before))
        )
        if not ok:
            raise InvalidParameterError(f"calibration example {i} is malformed: {ex!r}")
    if not any(np.isfinite(ex.logliks[ex.target]) for ex in examples):
        raise InvalidParameterError(
            "no held-out demonstration was scored finitely by its own skill: cannot calibrate"
        )
    best: NoneModel | None = None
    best_evidence = -np.inf
    for col, w in enumerate(windows):
        rates = []
        for ex in examples:
            with np.errstate(invalid="ignore"):  # -inf - -inf: a rejecting skill
                r = (ex.logliks - _head(ex.before[:, col], w)) / _span(w, ex.n)
            rates.extend(r[np.isfinite(r)])
        if not rates:
            continue
        taus = np.linspace(min(rates) - 1.0, max(rates) + 1.0, _GRID)
        logl = _loglik_grid(w, col, examples, taus)
        evidence = float(logsumexp(logl) + np.log(taus[1] - taus[0]))
        post = np.exp(logl - logl.max())
        tau = float(np.sum(taus * post) / np.sum(post))
        if evidence > best_evidence:
            best_evidence = evidence
            best = NoneModel(
                w, tau, float(_loglik_grid(w, col, examples, np.array([tau]))[0]), len(examples)
            )
    if best is None:
        raise InvalidParameterError("no finite held-out score: cannot calibrate")
    return best
