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

The fit gate (``NoneModel.gate == "fit"``, the shape recognizer's). A recognizer whose skills
also report a goodness of fit ``f_k`` (nats, at most 0: the shape recognizer's
``-1/2 sum_i min(e_i / σ_i, 7)²``, each step's misfit in units of the skill's own spread) asks
whether the prefix is a sample of the skill at all, apart from which skill explains it best.
With ``pi_k = exp(ll_k) / sum_j exp(ll_j)`` and ``a_k = sigmoid(f_k - n tau)``,

``c_k = pi_k a_k`` and ``c_none = sum_k pi_k (1 - a_k)``:

the operator is doing skill ``k`` if ``k`` explains the prefix and the prefix fits it; the
misfit of a prefix that ``k`` explains best but does not fit is "none of these". A density
``ll_k`` falls with the width of the skill's spread whatever the fit, so a constant filler
rate rejects the typical prefixes of a loosely written letter first; ``f_k`` does not (a
typical prefix scores about ``-n / 2`` in any skill).

Calibration. ``W`` (samples) and ``tau`` are learnt by maximum likelihood from held-out
demonstrations of the library's skills (never used to fit the HSMMs), scored at several
prefix lengths. Each scored prefix gives two labelled examples:

* with the whole library, the target is its own skill (an operator doing a known skill);
* with its own skill left out of the library, the target is "none" (an operator doing a skill
  the library does not hold): leave-one-skill-out, so no demonstration outside the library is
  needed, and the "none" examples are exactly the nearest impostors of the library.

For each candidate window ``W`` (:data:`WINDOWS` by default; ``None`` is the whole
trajectory) the summed log-probability of the targets is a
concave function of ``tau`` (each term is linear minus a log-sum-exp of terms linear in
``tau``); it is evaluated on a uniform grid over the bracket from the smallest to the largest
per-sample log-likelihood rate of the examples' windows, widened by 1 nat per sample, and
``tau`` is its posterior mean under a uniform prior on that bracket: the maximum-likelihood
value when the held-out data pin ``tau`` down, and the middle of the gap when they separate
known from "none" perfectly (the likelihood is then flat across the gap). The window with the
largest evidence (the likelihood integrated over the bracket) wins, the smaller on a tie.

The fit gate is calibrated on the same prefixes. A prefix's mean squared misfit a sample,
``-2 f / n``, is about 1 under its own skill and far larger under another; its logarithm is
near normal in each case. A normal is fitted to the log misfits of the held-out prefixes
under their own skill, another to those under the best other skill of the library (the
own skill left out, the best by likelihood: the nearest impostor), and ``tau`` is
``-1/2 exp(x)`` at the log misfit ``x`` between their means where the two densities are
equal (equal priors). Unlike a likelihood fitted to the targets, that boundary stays put
when own and impostor prefixes are far apart. All of it is deterministic. It needs at least
two skills.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from pourbench.errors import InvalidParameterError, check_int

__all__ = [
    "GATES",
    "WINDOWS",
    "CalibrationExample",
    "NoneModel",
    "fit_none_model",
    "open_set_posterior",
]

WINDOWS: tuple[int, ...] = (5, 10, 20, 40)
"""Candidate "none" windows ``W`` of the HSMM recognition, samples (Δd apart: 3-24 cm of path
for letters)."""

GATES: tuple[str, ...] = ("filler", "fit")
"""How "none of these" is compared with the skills: ``"filler"`` (a constant log-density per
sample, the HSMM recognizer's) or ``"fit"`` (each skill's goodness of fit, the shape
recognizer's); see the module docstring."""

_GRID = 4001  # tau grid points between the smallest and largest per-sample rate
_MIN_MISFIT = 1e-3  # the fit gate's smallest mean squared misfit a sample (a perfect fit)
_MIN_SPREAD = 0.05  # the fit gate's narrowest spread of log misfits


@dataclass(frozen=True)
class NoneModel:
    """The calibrated "none of these" hypothesis.

    Attributes:
        window: ``W``, samples (``None``: the whole trajectory).
        tau: log-density per sample, nats.
        loglik: held-out log-likelihood of the calibration targets at ``tau``, nats.
        examples: number of scored held-out prefixes it was fitted on.
        gate: one of :data:`GATES`; with ``"fit"``, ``window`` is ``None`` and ``tau`` is
            the fit per sample at which a prefix is as likely a sample of its best skill as
            of none of the library's, nats.
        own, other: the fit gate's ``(mean, sd)`` of ``log(-2 fit / n)`` (the mean squared
            misfit a sample, in spreads) of held-out prefixes under their own skill and
            under the best other skill; ``None`` for the filler.
    """

    window: int | None
    tau: float
    loglik: float
    examples: int
    gate: str = "filler"
    own: tuple[float, float] | None = None
    other: tuple[float, float] | None = None


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
        fits: (K,) every skill's goodness of fit of the prefix, nats (the ``"fit"`` gate's;
            ``None`` for the filler).
    """

    logliks: np.ndarray
    before: np.ndarray
    n: int
    target: int
    fits: np.ndarray | None = None


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


def _log_misfit(fits: np.ndarray, n: int) -> np.ndarray:
    """``log(-2 fit / n)``: the log of the mean squared misfit a sample, in spreads."""
    return np.log(np.maximum(-2.0 * np.asarray(fits, dtype=float) / n, _MIN_MISFIT))


def _normal_logpdf(x: np.ndarray, mean_sd: tuple[float, float]) -> np.ndarray:
    mean, sd = mean_sd
    return -0.5 * ((x - mean) / sd) ** 2 - np.log(sd * np.sqrt(2.0 * np.pi))


def _fit_gate(logliks: np.ndarray, fits: np.ndarray, n: int, tau: float) -> np.ndarray:
    """Log-probabilities of the fit gate, (K + 1,): skill ``k`` is ``pi_k a_k`` and "none"
    ``sum_k pi_k (1 - a_k)``, ``pi`` the closed-set posterior and
    ``a_k = sigmoid(fit_k - n tau)``."""
    pi = logliks - logsumexp(logliks)
    margin = np.asarray(fits, dtype=float) - n * tau
    keep = np.where(np.isfinite(pi), pi - np.logaddexp(0.0, -margin), -np.inf)
    drop = np.where(np.isfinite(pi), pi - np.logaddexp(0.0, margin), -np.inf)
    return np.append(keep, logsumexp(drop))


def open_set_posterior(
    logliks: np.ndarray,
    before: np.ndarray | None,
    n: int,
    model: NoneModel | None,
    fits: np.ndarray | None = None,
) -> np.ndarray:
    """Probabilities of the skills and, with a ``model``, of "none of these" (last entry).

    Args:
        logliks: (K,) partial log-likelihoods, nats (``-inf`` allowed).
        before: (K,) log-likelihoods without the last ``model.window`` samples (the filler
            gate's; ignored without a model or with the fit gate).
        n: samples in the scored trajectory.
        model: the calibrated "none" hypothesis, or ``None`` for the closed-set posterior
            over the skills alone.
        fits: (K,) the skills' goodness of fit, nats (the fit gate's; ignored otherwise).

    Returns:
        (K + 1,) probabilities with "none" last, or (K,) without a model; all zeros when
        every term is ``-inf``.

    Raises:
        InvalidParameterError: with a ``model``, its gate's input (``before`` or ``fits``)
            is missing or not K values, or ``n`` is not an integer >= 1.
    """
    ll = np.asarray(logliks, dtype=float)
    if model is None:
        z = ll
    elif model.gate == "fit":
        if fits is None or np.shape(fits) != ll.shape:
            raise InvalidParameterError(
                f"with a fit-gated model, fits must be {ll.size} goodness-of-fit scores, "
                f"got {fits!r}"
            )
        n = check_int("n", n, minimum=1)
        if not np.any(np.isfinite(ll)):
            return np.zeros(ll.size + 1)
        return np.exp(_fit_gate(ll, np.asarray(fits, dtype=float), n, model.tau))
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


def _fit_targets(examples: Sequence[CalibrationExample]) -> tuple[np.ndarray, np.ndarray]:
    """Log misfits of each example's own skill and of its best other skill (by likelihood)."""
    own, other = [], []
    for ex in examples:
        ll = np.asarray(ex.logliks, dtype=float)
        x = _log_misfit(np.asarray(ex.fits, dtype=float), ex.n)
        if np.isfinite(ll[ex.target]):
            own.append(x[ex.target])
        rest = np.delete(ll, ex.target)
        if np.any(np.isfinite(rest)):
            other.append(np.delete(x, ex.target)[int(np.argmax(rest))])
    return np.array(own), np.array(other)


def _crossing(own: tuple[float, float], other: tuple[float, float]) -> float:
    """The log misfit between the two means where their normal densities are equal (a root
    of a quadratic), or the mean between them nearest to equal when they do not cross
    there."""
    (m1, s1), (m2, s2) = own, other
    lo, hi = min(m1, m2), max(m1, m2)
    # log N(x; m1, s1) - log N(x; m2, s2) = a x^2 + b x + c
    a = 0.5 / s2**2 - 0.5 / s1**2
    b = m1 / s1**2 - m2 / s2**2
    c = 0.5 * m2**2 / s2**2 - 0.5 * m1**2 / s1**2 + np.log(s2 / s1)
    if abs(a) > 1e-12:
        roots = np.roots([a, b, c])
    elif abs(b) > 1e-12:
        roots = np.array([-c / b])
    else:  # the same normal twice: equal everywhere
        return 0.5 * (lo + hi)
    inside = [r.real for r in np.atleast_1d(roots) if r.imag == 0.0 and lo <= r.real <= hi]
    if inside:
        return float(inside[0])

    def gap(x: float) -> float:
        return abs(float(_normal_logpdf(np.array(x), own) - _normal_logpdf(np.array(x), other)))

    return lo if gap(lo) < gap(hi) else hi


def fit_none_model(
    examples: Sequence[CalibrationExample],
    windows: Sequence[int | None] = WINDOWS,
    *,
    gate: str = "filler",
) -> NoneModel:
    """Calibrated ``W`` and ``tau`` from held-out examples (see the module docstring).

    Args:
        examples: the scored held-out prefixes, their ``before`` with one column per window
            (and their ``fits`` for the fit gate).
        windows: the candidate windows ``W``, samples (integers >= 1, or ``None`` for the
            whole trajectory); the fit gate takes the whole trajectory (``windows`` is
            ignored, ``before`` has one column).
        gate: one of :data:`GATES`.

    Raises:
        InvalidParameterError: no examples or no windows, a window that is neither None nor
            an integer >= 1, an unknown gate, fewer than two skills, a malformed example
            (for the fit gate, one without K fits), no example whose own skill gave a
            finite log-likelihood, or, for the fit gate, fewer than two examples scored by
            their own skill and two by another.
    """
    if gate not in GATES:
        raise InvalidParameterError(f"gate must be one of {GATES}, got {gate!r}")
    windows = (None,) if gate == "fit" else tuple(windows)
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
            and (
                gate == "filler"
                or (np.shape(ex.fits) == ll.shape and not np.any(np.isnan(ex.fits)))
            )
        )
        if not ok:
            raise InvalidParameterError(f"calibration example {i} is malformed: {ex!r}")
    if not any(np.isfinite(ex.logliks[ex.target]) for ex in examples):
        raise InvalidParameterError(
            "no held-out demonstration was scored finitely by its own skill: cannot calibrate"
        )
    if gate == "fit":
        own_x, other_x = _fit_targets(examples)
        if own_x.size < 2 or other_x.size < 2:
            raise InvalidParameterError(
                "the fit gate needs at least two held-out prefixes scored by their own skill "
                "and two by another"
            )
        own = (float(own_x.mean()), max(float(own_x.std()), _MIN_SPREAD))
        other = (float(other_x.mean()), max(float(other_x.std()), _MIN_SPREAD))
        tau = -0.5 * float(np.exp(_crossing(own, other)))
        loglik = 0.0
        for ex in examples:
            ll, fits = np.asarray(ex.logliks, dtype=float), np.asarray(ex.fits, dtype=float)
            if np.isfinite(ll[ex.target]):
                loglik += _fit_gate(ll, fits, ex.n, tau)[ex.target]
            rest = np.delete(ll, ex.target)
            if np.any(np.isfinite(rest)):
                loglik += _fit_gate(rest, np.delete(fits, ex.target), ex.n, tau)[-1]
        return NoneModel(None, tau, float(loglik), len(examples), gate, own, other)
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
