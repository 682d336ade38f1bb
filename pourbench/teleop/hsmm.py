"""Hidden semi-Markov model with Gaussian state durations (thesis §2.6, §5.3.1).

Written by hand in numpy/scipy: no maintained library in our dependency set provides an
HSMM with an online forward variable. Parameters
``theta = {Pi_i, a_ij, mu_i, Sigma_i, mu_i^S, Sigma_i^S}`` for ``K`` states.

Training (the usual recipe for HSMMs learnt from a handful of demonstrations): the
transition structure, emissions and initial probabilities are learnt by EM (Baum-Welch on the
underlying HMM, scaled forward-backward), initialised from an equal-time split of every
demonstration; the Gaussian duration of each state is then estimated from the EM posteriors
(lengths of the runs of the most probable state). A left-right topology is used by default,
as the skills are single strokes.

Recognition uses the explicit-duration forward variable on a *partial* observation sequence
``f_1..f_t``: with ``F_t(i)`` the probability that a segment of state ``i`` ends at ``t``,

``F_t(i) = sum_d [Pi_i 1(d = t) + sum_j F_{t-d}(j) a_ji] p_i(d) prod_{s=t-d+1}^{t} N(f_s | i)``,

and the partial likelihood replaces the duration pmf ``p_i(d)`` of the last, unfinished
segment by its survival ``P(duration >= d)``. The same quantities give the posterior over the
current state and the time spent in it, hence the progress along the skill.

Observations are per-sample feature vectors; :func:`trajectory_features` builds them from a
Δd-sampled path as ``[x - x_0, x_t - x_{t-1}]`` (metres, metres per sample), which makes the
model independent of where the operator starts and of the drawing speed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from pourbench.errors import InvalidParameterError, check_finite, check_int, check_positive

__all__ = ["HSMM", "Progress", "trajectory_features"]

_LOG0 = -1e300


def trajectory_features(points: np.ndarray) -> np.ndarray:
    """Features ``[x - x_0, x_t - x_{t-1}]`` of a (n, D) Δd-sampled path (m, m/sample)."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[0] < 2:
        raise InvalidParameterError(f"trajectory needs at least 2 points (n, D), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise InvalidParameterError("trajectory contains NaN or infinite coordinates")
    vel = np.diff(pts, axis=0)
    vel = np.vstack([vel[:1], vel])
    return np.hstack([pts - pts[0], vel])


def _check_reg(reg: object, F: int | None = None) -> np.ndarray:
    """``reg`` as a finite, positive array (broadcast to length ``F`` when given)."""
    try:
        r = np.asarray(reg, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"reg must be numbers, got {reg!r}") from exc
    if r.ndim > 1 or r.size == 0 or not np.all(np.isfinite(r)) or not np.all(r > 0):
        raise InvalidParameterError(
            f"reg must be a finite scalar or vector with every entry > 0, got {reg!r}"
        )
    if F is None:
        return r
    if r.ndim == 1 and r.size not in (1, F):
        raise InvalidParameterError(f"reg has {r.size} entries, the features have F={F}")
    return np.broadcast_to(r, (F,))


def _log_gauss(X: np.ndarray, mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(n, K) log N(x_n | mu_k, Sigma_k)."""
    n, F = X.shape
    K = mu.shape[0]
    out = np.empty((n, K))
    for k in range(K):
        L = np.linalg.cholesky(sigma[k])
        z = np.linalg.solve(L, (X - mu[k]).T)
        out[:, k] = (
            -0.5 * np.sum(z**2, axis=0) - np.sum(np.log(np.diag(L))) - 0.5 * F * np.log(2.0 * np.pi)
        )
    return out


@dataclass(frozen=True)
class Progress:
    """Where a partial sequence is in the model.

    Attributes:
        loglik: log p(f_1..f_t) (partial likelihood).
        state: most probable current state.
        fraction: expected progress as a fraction of the expected total duration, in [0, 1].
        step: expected progress in samples.
        before: log p(f_1..f_{t-w}) for each requested lookback ``w`` (0.0, the empty
            sequence, when ``w >= t``), in the order asked.
    """

    loglik: float
    state: int
    fraction: float
    step: float
    before: tuple[float, ...] = ()


class HSMM:
    """Gaussian-emission HSMM with Gaussian durations.

    Args:
        n_states: number of states K (thesis: 5).
        left_right: restrict transitions to i -> i+1 and start in state 0.
        reg: diagonal added to each covariance (feature units squared); a scalar or a vector
            of length F, every entry finite and > 0 (it keeps the covariances invertible).
        min_duration_std: floor on the duration standard deviation, samples (finite, > 0:
            with one demonstration every observed duration spread is 0).

    Raises:
        InvalidParameterError: ``n_states`` not an integer >= 1, ``reg`` not finite and
            > 0 everywhere, or ``min_duration_std`` not finite and > 0.
    """

    def __init__(
        self,
        n_states: int = 5,
        *,
        left_right: bool = True,
        reg: float | np.ndarray = 1e-6,
        min_duration_std: float = 1.0,
    ) -> None:
        self.n_states = check_int("n_states", n_states, minimum=1)
        self.left_right = left_right
        self.reg = reg
        _check_reg(reg)
        self.min_duration_std = check_positive("min_duration_std", min_duration_std)
        self.priors = np.zeros(0)
        self.trans = np.zeros((0, 0))  # HMM transitions (with self loops), used in EM
        self.mu = np.zeros((0, 0))
        self.sigma = np.zeros((0, 0, 0))
        self.dur_mu = np.zeros(0)
        self.dur_sigma = np.zeros(0)

    # ----------------------------------------------------------------- training
    def fit(self, sequences: Sequence[np.ndarray], n_iter: int = 30, tol: float = 1e-4) -> HSMM:
        """Learn the parameters from demonstrations.

        The model changes only when the fit succeeds: on any error it keeps its previous
        parameters.

        Args:
            sequences: list of (T_n, F) feature sequences (same F >= 1), each with at least
                ``n_states`` samples; the equal-time initial split must give every state at
                least 2 samples in all (its covariance), e.g. one sequence of
                ``2 * n_states`` samples.
            n_iter: EM iteration cap (integer >= 1).
            tol: stop when the per-sample log-likelihood improves by less than this (>= 0).

        Raises:
            InvalidParameterError: malformed, non-finite or too short sequences, bad
                ``n_iter`` / ``tol`` / ``reg``, or EM that produced non-finite parameters
                (degenerate data).
        """
        n_iter = check_int("n_iter", n_iter, minimum=1)
        tol = check_finite("tol", tol, minimum=0.0)
        seqs = [np.asarray(s, dtype=float) for s in sequences]
        if not seqs:
            raise InvalidParameterError("sequences is empty: need at least one demonstration")
        F = seqs[0].shape[1] if seqs[0].ndim == 2 else -1
        K = self.n_states
        for i, s in enumerate(seqs):
            if s.ndim != 2 or s.shape[1] != F or F < 1:
                want = f"(T, {F})" if F >= 1 else "(T, F) with F >= 1"
                raise InvalidParameterError(f"sequences[{i}] has shape {s.shape}, expected {want}")
            if s.shape[0] < K:
                raise InvalidParameterError(
                    f"sequences[{i}] has {s.shape[0]} samples, fewer than n_states={K}"
                )
            if not np.all(np.isfinite(s)):
                raise InvalidParameterError(f"sequences[{i}] contains NaN or infinite values")
        per_state = np.zeros(K, dtype=int)
        for s in seqs:
            per_state += [len(part) for part in np.array_split(np.arange(s.shape[0]), K)]
        if per_state.min() < 2:
            raise InvalidParameterError(
                f"sequences too short for n_states={K}: the equal-time split gives state "
                f"{int(np.argmin(per_state))} only {int(per_state.min())} sample(s), need >= 2 "
                f"(e.g. one sequence of {2 * K} samples)"
            )
        reg = _check_reg(self.reg, F)
        saved = dict(self.__dict__)
        try:
            self._fit(seqs, reg, n_iter, tol)
            params = (self.priors, self.trans, self.mu, self.sigma, self.dur_mu, self.dur_sigma)
            if not all(np.all(np.isfinite(a)) for a in params):
                raise InvalidParameterError(
                    "EM produced non-finite parameters (degenerate sequences?)"
                )
        except np.linalg.LinAlgError as exc:
            self.__dict__.update(saved)
            raise InvalidParameterError(
                f"EM failed ({exc}): a covariance became singular; increase reg"
            ) from exc
        except BaseException:
            self.__dict__.update(saved)
            raise
        return self

    def _fit(self, seqs: list[np.ndarray], reg: np.ndarray, n_iter: int, tol: float) -> None:
        """EM on validated sequences (see :meth:`fit`); sets the parameters."""
        F = seqs[0].shape[1]
        K = self.n_states
        # initialisation: equal-time split
        buckets: list[list[np.ndarray]] = [[] for _ in range(K)]
        for s in seqs:
            for k, part in enumerate(np.array_split(s, K)):
                buckets[k].append(part)
        self.mu = np.array([np.concatenate(b).mean(axis=0) for b in buckets])
        self.sigma = np.array([np.cov(np.concatenate(b).T) + np.diag(reg) for b in buckets])
        mean_len = float(np.mean([s.shape[0] for s in seqs]))
        stay = max(0.0, 1.0 - K / mean_len)
        if self.left_right:
            A = stay * np.eye(K) + (1.0 - stay) * np.eye(K, k=1)
            A[-1, -1] = 1.0
            pri = np.eye(K)[0]  # start in state 0
        else:
            A = np.full((K, K), (1.0 - stay) / max(K - 1, 1))
            np.fill_diagonal(A, stay if K > 1 else 1.0)
            pri = np.full(K, 1.0 / K)
        self.trans, self.priors = A, pri
        total = sum(s.shape[0] for s in seqs)
        Tmax = max(s.shape[0] for s in seqs)
        mask = np.zeros((len(seqs), Tmax), dtype=bool)
        for n, sq in enumerate(seqs):
            mask[n, : sq.shape[0]] = True
        gammas: list[np.ndarray] = []
        prev = -np.inf
        for _ in range(n_iter):
            g_sum = np.zeros(K)
            g_x = np.zeros((K, F))
            g_xx = np.zeros((K, F, F))
            g0 = np.zeros(K)
            lB = np.zeros((len(seqs), Tmax, K))
            for n, sq in enumerate(seqs):
                lB[n, : sq.shape[0]] = _log_gauss(sq, self.mu, self.sigma)
            gam, xi_sum, ll = self._forward_backward(lB, mask)
            gammas = [gam[n, : sq.shape[0]] for n, sq in enumerate(seqs)]
            for sq, gamma in zip(seqs, gammas, strict=True):
                g_sum += gamma.sum(axis=0)
                g_x += gamma.T @ sq
                g_xx += np.einsum("tk,tf,tg->kfg", gamma, sq, sq)
                g0 += gamma[0]
            self.mu = g_x / g_sum[:, None]
            self.sigma = g_xx / g_sum[:, None, None] - np.einsum("kf,kg->kfg", self.mu, self.mu)
            self.sigma += np.diag(reg)[None]
            rows = xi_sum.sum(axis=1, keepdims=True)
            self.trans = np.where(rows > 0, xi_sum / np.where(rows > 0, rows, 1.0), A)
            if not self.left_right:
                self.priors = g0 / g0.sum()
            if ll / total - prev < tol:
                break
            prev = ll / total
        # Gaussian durations from the runs of the most probable state
        runs: list[list[int]] = [[] for _ in range(K)]
        for gamma in gammas:
            z = np.argmax(gamma, axis=1)
            start = 0
            for t in range(1, z.size + 1):
                if t == z.size or z[t] != z[start]:
                    runs[int(z[start])].append(t - start)
                    start = t
        mean_run = mean_len / K
        self.dur_mu = np.array([np.mean(r) if r else mean_run for r in runs])
        self.dur_sigma = np.array(
            [max(np.std(r) if len(r) > 1 else 0.0, self.min_duration_std) for r in runs]
        )

    def _forward_backward(
        self, lB: np.ndarray, mask: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Scaled forward-backward on a padded batch (n, T, K); padded samples emit 1."""
        lB = np.where(mask[:, :, None], lB, 0.0)
        shift = lB.max(axis=2, keepdims=True)
        Bm = np.exp(lB - shift)
        n, T, K = Bm.shape
        A = self.trans
        alpha = np.empty((n, T, K))
        scale = np.empty((n, T))
        a = self.priors[None, :] * Bm[:, 0]
        scale[:, 0] = a.sum(axis=1)
        alpha[:, 0] = a / scale[:, 0, None]
        for t in range(1, T):
            a = (alpha[:, t - 1] @ A) * Bm[:, t]
            scale[:, t] = a.sum(axis=1)
            alpha[:, t] = a / scale[:, t, None]
        beta = np.ones((n, T, K))
        for t in range(T - 2, -1, -1):
            beta[:, t] = ((Bm[:, t + 1] * beta[:, t + 1]) @ A.T) / scale[:, t + 1, None]
        gamma = alpha * beta
        gamma /= gamma.sum(axis=2, keepdims=True)
        valid = (mask[:, 1:] & mask[:, :-1]).astype(float)
        xi = np.einsum(
            "ntj,jk,ntk->jk",
            alpha[:, :-1] * valid[:, :, None],
            A,
            Bm[:, 1:] * beta[:, 1:] / scale[:, 1:, None],
        )
        ll = float(np.sum(np.log(scale)) + np.sum(shift[..., 0] * mask))
        return gamma, xi, ll

    # ----------------------------------------------------------------- HSMM quantities
    def _check_fitted(self) -> None:
        if self.mu.size == 0:
            raise InvalidParameterError("HSMM is not fitted: call fit() first")

    def _semi_trans(self) -> np.ndarray:
        """Transition matrix between different states (self loops removed, rows renormalised)."""
        A = self.trans.copy()
        np.fill_diagonal(A, 0.0)
        rows = A.sum(axis=1, keepdims=True)
        return np.where(rows > 0, A / np.where(rows > 0, rows, 1.0), 0.0)

    def _log_durations(self, dmax: int) -> tuple[np.ndarray, np.ndarray]:
        """(K, dmax) log pmf and log survival of durations 1..dmax."""
        # normalise over a long support (>= dmax) so truncation does not bias short prefixes
        big = np.arange(1, int(max(dmax, self.dur_mu.max() + 10 * self.dur_sigma.max())) + 1)
        lfull = -0.5 * ((big[None, :] - self.dur_mu[:, None]) / self.dur_sigma[:, None]) ** 2
        lfull = lfull - logsumexp(lfull, axis=1)[:, None]
        # survival S(d) = sum_{d' >= d} p(d')
        lsurv = np.flip(np.logaddexp.accumulate(np.flip(lfull, axis=1), axis=1), axis=1)
        return lfull[:, :dmax], lsurv[:, :dmax]

    def _is_chain(self) -> bool:
        """True when states can only be entered from the previous one (left-right chain)."""
        chain = np.eye(self.n_states, k=1)
        return bool(np.allclose(self._semi_trans()[:-1], chain[:-1]) and self.priors[0] == 1.0)

    def _segments(self, lB: np.ndarray, lp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Log ``incoming[s, i]`` (a segment of i starts at s) and ``C`` (cumulative emissions).

        ``lB`` is (T, K) log emission (zeros for the emission-free forward variable).
        """
        T, K = lB.shape
        C = np.vstack([np.zeros(K), np.cumsum(lB, axis=0)])  # C[t] = sum_{s < t} lB[s]
        with np.errstate(divide="ignore"):
            lA = np.log(self._semi_trans())
            lpi = np.log(self.priors)
        incoming = np.full((T, K), _LOG0)
        tt = np.arange(T)
        lag = tt[:, None] - tt[None, :]  # t - s
        lower = lag >= 0
        if self._is_chain():
            # state by state: the segment ends of state i feed the starts of state i + 1
            incoming[0, 0] = 0.0
            for i in range(K):
                a = incoming[:, i] - C[:T, i]
                M = np.where(lower, a[None, :] + lp[i, np.clip(lag, 0, T - 1)], -np.inf)
                fend = C[1:, i] + logsumexp(M, axis=1)
                if i + 1 < K:
                    incoming[1:, i + 1] = fend[:-1]
            return incoming, C
        incoming[0] = lpi
        for t in range(T):
            st = np.arange(t + 1)
            d = t - st + 1
            term = incoming[: t + 1] + C[t + 1][None, :] - C[st] + lp[:, d - 1].T
            fend = logsumexp(term, axis=0)
            if t + 1 < T:
                incoming[t + 1] = logsumexp(fend[:, None] + lA, axis=0)
        return incoming, C

    def partial(self, features: np.ndarray, lookbacks: Sequence[int] = ()) -> Progress:
        """Forward variable on a partial sequence: likelihood, current state, progress.

        Args:
            features: (t, F) features of the samples seen so far (t >= 1).
            lookbacks: also give the partial log-likelihood of the sequence without its last
                ``w`` samples, for each ``w`` (integers >= 1), from the same forward pass.
        """
        self._check_fitted()
        f = np.asarray(features, dtype=float)
        if f.ndim != 2 or f.shape[0] == 0 or f.shape[1] != self.mu.shape[1]:
            raise InvalidParameterError(
                f"features must be (t >= 1, {self.mu.shape[1]}), got {f.shape}"
            )
        if not np.all(np.isfinite(f)):
            raise InvalidParameterError("features contain NaN or infinite values")
        T = f.shape[0]
        lB = _log_gauss(f, self.mu, self.sigma)
        lp, lsurv = self._log_durations(T)
        incoming, C = self._segments(lB, lp)
        st = np.arange(T)
        d = T - st  # duration of the unfinished last segment
        G = incoming + C[T][None, :] - C[:T] + lsurv[:, d - 1].T  # (start, state)
        ll = float(logsumexp(G))
        before = []
        for w in lookbacks:
            L = T - check_int("lookback", w, minimum=1)
            if L <= 0:
                before.append(0.0)
                continue
            # segments starting before L only depend on the first L samples
            Gl = incoming[:L] + C[L][None, :] - C[:L] + lsurv[:, L - st[:L] - 1].T
            before.append(float(logsumexp(Gl)))
        post = np.exp(G - ll)
        offset = np.concatenate([[0.0], np.cumsum(self.dur_mu)[:-1]])
        # expected progress: samples before the state + time spent in it (capped at its mean)
        spent = np.minimum(d[:, None].astype(float), self.dur_mu[None, :])
        step = float(np.sum(post * (offset[None, :] + spent)))
        total = float(self.dur_mu.sum())
        state = int(np.argmax(post.sum(axis=0)))
        return Progress(ll, state, min(max(step / total, 0.0), 1.0), step, tuple(before))

    def state_sequence(self, n_steps: int | None = None) -> np.ndarray:
        """(n_steps, K) state activations over time from the durations alone (no observations).

        Uses the forward variable without emissions; ``n_steps`` defaults to the expected
        total duration.
        """
        self._check_fitted()
        K = self.n_states
        T = round(float(self.dur_mu.sum())) if n_steps is None else check_int("n_steps", n_steps)
        if T < 1:
            raise InvalidParameterError(f"n_steps must be >= 1, got {n_steps}")
        lp, lsurv = self._log_durations(T)
        incoming, _ = self._segments(np.zeros((T, K)), lp)
        tt = np.arange(T)
        lag = tt[:, None] - tt[None, :]
        occ = np.empty((T, K))
        for i in range(K):
            M = np.where(lag >= 0, incoming[None, :, i] + lsurv[i, np.clip(lag, 0, T - 1)], -np.inf)
            occ[:, i] = logsumexp(M, axis=1)
        return np.exp(occ - logsumexp(occ, axis=1, keepdims=True))
