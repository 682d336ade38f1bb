"""Coherent Point Drift (Myronenko & Song, 2010): rigid and non-rigid registration.

Written by hand in numpy/scipy: no maintained library in our dependency set provides CPD.
``Y`` (M x D, the template, e.g. a learned skill) is registered onto ``X`` (N x D, the data,
e.g. the operator's trajectory). ``Y`` are the centroids of an isotropic Gaussian mixture
with a uniform outlier component of weight ``w``; EM alternates

* E-step: ``P[m, n] = exp(-|x_n - T(y_m)|^2 / 2 s2) / (sum_k exp(...) + c)`` with
  ``c = (2 pi s2)^(D/2) w / (1 - w) M / N`` (thesis Eq. 2.68);
* M-step: the closed-form update of the transform and ``s2`` (rigid: Procrustes with scale,
  the rotation by SVD, or by its angle in 2-D; non-rigid: ``T(Y) = Y + G W`` with the
  motion-coherence regulariser ``lmbda`` and Gaussian kernel width ``beta``, thesis Eq. 5.8).

Two accelerations of the non-rigid path, usable separately, measured by
``pourbench bench teleop``:

* ``fgt=True``: the E-step sums are computed with the improved Fast Gauss Transform
  (:func:`gauss_transform`, Taylor expansion about farthest-point cluster centres). It falls
  back to the direct sum whenever its expansion would cost more than the direct O(MN) sum
  (always the case once ``s2`` is small compared with the point spacing).
* ``lowrank=True``: ``G`` is replaced by its leading eigenpairs ``Q diag(l) Q^T`` and the
  M-step system is solved with the Woodbury identity in O(M k^2); the EM only needs
  ``G W = Q z`` (``z`` the k-vector of the Woodbury solve), so ``W`` is formed once at the end.

Units are whatever the points are in (SI metres in pourbench); ``beta`` applies to the
normalised point sets (zero mean, unit RMS radius) when ``normalize=True``, as in the paper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from math import factorial, prod

import numpy as np
from scipy.linalg import cho_factor, cho_solve, eigh
from scipy.spatial.distance import cdist

from pourbench.errors import (
    InvalidParameterError,
    check_array,
    check_finite,
    check_int,
    check_positive,
)

__all__ = [
    "NonRigidResult",
    "RigidResult",
    "gauss_transform",
    "register_nonrigid",
    "register_rigid",
]

_S2_FLOOR = 1e-12  # relative to the data's squared scale: stop when the mixture collapses
_FIRST_RANK = 16  # eigenpairs tried first by the low-rank kernel


def _check_points(name: str, pts: object, dim: int | None = None) -> np.ndarray:
    a = np.asarray(pts, dtype=float)
    if a.ndim != 2:
        raise InvalidParameterError(f"{name} must be a 2-D array (points x dims), got {a.shape}")
    if a.shape[0] == 0:
        raise InvalidParameterError(f"{name} is empty (no points)")
    if a.shape[1] == 0:
        raise InvalidParameterError(f"{name} has no dimensions, got shape {a.shape}")
    if dim is not None and a.shape[1] != dim:
        raise InvalidParameterError(f"{name} has {a.shape[1]} dims, expected {dim}")
    if not np.all(np.isfinite(a)):
        raise InvalidParameterError(f"{name} contains NaN or infinite coordinates")
    return a


def _check_pair(
    X: object, Y: object, w: float, max_iter: object, tol: float
) -> tuple[np.ndarray, np.ndarray, float]:
    Xa = _check_points("X", X)
    Ya = _check_points("Y", Y, Xa.shape[1])
    w = check_finite("w", w, minimum=0.0)
    if w >= 1.0:
        raise InvalidParameterError(f"w (outlier weight) must be in [0, 1), got {w}")
    check_int("max_iter", max_iter, minimum=1)
    check_finite("tol", tol, minimum=0.0)
    _check_spread("X", Xa)
    return Xa, Ya, w


def _check_spread(name: str, pts: np.ndarray) -> None:
    """Refuse a degenerate point set: all points identical (zero variance)."""
    if not np.any(pts != pts[0]):
        raise InvalidParameterError(
            f"{name} is degenerate: all {pts.shape[0]} point(s) are identical (zero variance)"
        )


@dataclass(frozen=True)
class _Estep:
    P1: np.ndarray  # (M,) sum over data of the posteriors of each centroid
    Pt1: np.ndarray  # (N,) sum over centroids for each data point
    PX: np.ndarray  # (M, D) posterior-weighted data
    Np: float
    used_fgt: bool


def _sqdist(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(len(A), len(B)) squared Euclidean distances."""
    b2 = np.einsum("ij,ij->i", B, B)
    d2 = np.einsum("ij,ij->i", A, A)[:, None] + b2[None, :] - 2.0 * (A @ B.T)
    return np.maximum(d2, 0.0, out=d2)


def _estep_direct(X: np.ndarray, TY: np.ndarray, s2: float, w: float) -> _Estep:
    N, D = X.shape
    M = TY.shape[0]
    K = cdist(TY, X, "sqeuclidean")  # (M, N); in place from here on
    K *= -0.5 / s2
    np.exp(K, out=K)
    c = (2.0 * np.pi * s2) ** (D / 2.0) * w / (1.0 - w) * M / N
    den = K.sum(axis=0)
    den += c
    np.maximum(den, np.finfo(float).tiny, out=den)
    K /= den
    P1 = K.sum(axis=1)
    return _Estep(P1, K.sum(axis=0), K @ X, float(P1.sum()), False)


def _estep_fgt(X: np.ndarray, TY: np.ndarray, s2: float, w: float, eps: float) -> _Estep:
    N, D = X.shape
    M = TY.shape[0]
    h = np.sqrt(2.0 * s2)
    den = gauss_transform(TY, X, np.ones((M, 1)), h, eps=eps)
    if den is None:
        return _estep_direct(X, TY, s2, w)
    c = (2.0 * np.pi * s2) ** (D / 2.0) * w / (1.0 - w) * M / N
    den = den[:, 0] + c
    den = np.where(den <= 0.0, np.finfo(float).tiny, den)
    inv = 1.0 / den
    q = np.concatenate([inv[:, None], X * inv[:, None]], axis=1)  # (N, 1 + D)
    out = gauss_transform(X, TY, q, h, eps=eps)
    if out is None:
        return _estep_direct(X, TY, s2, w)
    P1 = np.maximum(out[:, 0], 0.0)
    Pt1 = 1.0 - c * inv
    return _Estep(P1, Pt1, out[:, 1:], float(P1.sum()), True)


def _multi_indices(dim: int, p: int) -> np.ndarray:
    """All multi-indices alpha in N^dim with |alpha| < p, graded order."""
    out: list[tuple[int, ...]] = []

    def rec(prefix: tuple[int, ...], left: int) -> None:
        if len(prefix) == dim:
            out.append(prefix)
            return
        for k in range(left + 1):
            rec((*prefix, k), left - k)

    rec((), p - 1)
    return np.array(sorted(out, key=sum), dtype=int)


def _monomials(delta: np.ndarray, alphas: np.ndarray) -> np.ndarray:
    """(..., A) products prod_d delta[..., d] ** alpha[a, d]."""
    out = np.ones((*delta.shape[:-1], alphas.shape[0]))
    for d in range(delta.shape[-1]):
        out *= delta[..., d, None] ** alphas[:, d]
    return out


def gauss_transform(
    sources: np.ndarray,
    targets: np.ndarray,
    weights: np.ndarray,
    h: float,
    *,
    eps: float = 1e-6,
    max_order: int = 30,
    max_clusters: int = 16,
) -> np.ndarray | None:
    """Improved Fast Gauss Transform ``G[j] = sum_i q_i exp(-|t_j - s_i|^2 / h^2)``.

    Sources are grouped by farthest-point clustering; each cluster's Gaussians are expanded in
    a truncated multivariate Taylor series about its centre, so the cost is
    O((N + M) * clusters * terms) instead of O(N M).

    Args:
        sources: (N, D) source points.
        targets: (M, D) evaluation points.
        weights: (N, W) source weights (W weight vectors at once).
        h: bandwidth (same unit as the points), > 0.
        eps: requested absolute error per unit total |weight|.
        max_order: largest Taylor order tried.
        max_clusters: most cluster centres tried.

    Returns:
        (M, W) transform, or ``None`` when the expansion would cost more than the direct
        sum (the caller then sums directly).

    Raises:
        InvalidParameterError: ``sources`` / ``targets`` not non-empty finite (N, D) /
            (M, D) arrays, ``weights`` not a finite (N, W) array, ``h`` not finite and
            > 0, ``eps`` not in (0, 1), ``max_order`` or ``max_clusters`` not an integer
            >= 1.
    """
    sources = check_array("sources", sources, (None, None))
    N, D = sources.shape
    if N == 0 or D == 0:
        raise InvalidParameterError(f"sources must be non-empty (N, D), got {sources.shape}")
    targets = check_array("targets", targets, (None, D))
    if targets.shape[0] == 0:
        raise InvalidParameterError("targets is empty (no points)")
    weights = check_array("weights", weights, (N, None))
    h = check_positive("h", h)
    eps = _check_eps("eps", eps)
    max_order = check_int("max_order", max_order, minimum=1)
    max_clusters = check_int("max_clusters", max_clusters, minimum=1)
    M = targets.shape[0]
    log_eps = np.log(eps)

    def order(rx: float) -> int | None:
        """Smallest Taylor order whose error bound (2^p / p!) (rx ry)^p is below eps."""
        ry = rx + np.sqrt(-log_eps)
        for p in range(1, max_order + 1):
            if p * np.log(2.0 * rx * ry + 1e-300) - np.log(float(factorial(p))) < log_eps:
                return p
        return None

    def n_terms(p: int) -> int:
        return int(factorial(p - 1 + D) // (factorial(D) * factorial(p - 1)))

    # farthest-point clustering, grown one centre at a time while some cluster count could
    # still beat the direct sum; keep the cheapest (clusters, order) plan.
    centres = [0]
    dist = np.sum((sources - sources[0]) ** 2, axis=1)
    label = np.zeros(N, dtype=int)
    best: tuple[float, int, int, np.ndarray] | None = None
    direct = float(N * M)
    while True:
        k = len(centres)
        rx = float(np.sqrt(dist.max())) / h
        p = order(rx)
        if p is not None:
            cost = float((N + M) * k * n_terms(p))
            if cost < direct and (best is None or cost < best[0]):
                best = (cost, k, p, label.copy())
        if (N + M) * (k + 1) >= direct or k >= min(N, max_clusters) or dist.max() <= 0.0:
            break
        j = int(np.argmax(dist))
        centres.append(j)
        dj = np.sum((sources - sources[j]) ** 2, axis=1)
        label[dj < dist] = k
        dist = np.minimum(dist, dj)
    if best is None:
        return None
    _, nclu, p, label = best
    C = sources[centres[:nclu]]
    rx = float(np.sqrt(np.max(np.sum((sources - C[label]) ** 2, axis=1)))) / h
    ry = rx + np.sqrt(-log_eps)
    alphas = _multi_indices(D, p)
    A = alphas.shape[0]
    coef = np.array(
        [2.0 ** int(row.sum()) / float(prod(factorial(int(a)) for a in row)) for row in alphas]
    )
    dx = (sources - C[label]) / h
    ex = np.exp(-np.sum(dx**2, axis=1))
    mono = _monomials(dx, alphas) * ex[:, None]  # (N, A)
    Ck = np.zeros((nclu, A, weights.shape[1]))
    np.add.at(Ck, label, mono[:, :, None] * weights[:, None, :])
    Ck *= coef[None, :, None]
    dy = (targets[:, None, :] - C[None, :, :]) / h  # (M, K, D)
    r2 = np.sum(dy**2, axis=2)
    near = r2 <= ry**2
    ey = np.where(near, np.exp(-r2), 0.0)
    my = _monomials(dy, alphas) * ey[:, :, None]  # (M, K, A)
    return np.einsum("mka,kaw->mw", my, Ck)


def _check_eps(name: str, eps: float) -> float:
    v = check_finite(name, eps)
    if not 0.0 < v < 1.0:
        raise InvalidParameterError(f"{name} must be in (0, 1), got {eps!r}")
    return v


def _init_s2(X: np.ndarray, Y: np.ndarray) -> float:
    N, D = X.shape
    M = Y.shape[0]
    return float(
        (M * np.sum(X**2) + N * np.sum(Y**2) - 2.0 * np.sum(X.sum(0) * Y.sum(0))) / (M * N * D)
    )


@dataclass(frozen=True)
class RigidResult:
    """Similarity transform ``T(y) = s R y + t`` that maps ``Y`` onto ``X``.

    Attributes:
        points: (M, D) transformed ``Y``.
        R: (D, D) rotation (det +1).
        t: (D,) translation, unit of the points.
        s: scale factor.
        sigma2: final mixture variance, unit^2.
        iterations: EM iterations run.
    """

    points: np.ndarray
    R: np.ndarray
    t: np.ndarray
    s: float
    sigma2: float
    iterations: int

    def transform(self, pts: np.ndarray) -> np.ndarray:
        """Apply the transform to other (K, D) points (finite, the registration's D)."""
        return self.s * _check_points("pts", pts, self.R.shape[0]) @ self.R.T + self.t


@dataclass(frozen=True)
class NonRigidResult:
    """Displacement field ``T(Y) = Y + G W`` (in the normalised frame when normalised).

    Attributes:
        points: (M, D) transformed ``Y`` in the input unit.
        W: (M, D) kernel weights (normalised frame).
        sigma2: final mixture variance (normalised frame).
        iterations: EM iterations run.
        fgt_steps: E-steps done by the Fast Gauss Transform (the rest were direct).
        rank: kernel rank used (M when the full kernel was used).
    """

    points: np.ndarray
    W: np.ndarray
    sigma2: float
    iterations: int
    fgt_steps: int = 0
    rank: int = 0
    beta: float = 3.0
    centres: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    frames: tuple[np.ndarray, float, np.ndarray, float] | None = field(default=None, repr=False)

    def transform(self, pts: np.ndarray) -> np.ndarray:
        """Apply the displacement field ``v(z) = sum_m G(z, y_m) w_m`` to other (K, D) points.

        The field is defined everywhere, so template points that were not registered (e.g.
        the rest of a skill beyond the registered prefix) move coherently with their
        neighbours.
        """
        z = _check_points("pts", pts, self.W.shape[1])
        assert self.frames is not None
        cx, sx, cy, sy = self.frames
        zn = (z - cy) / sy
        Gz = np.exp(-_sqdist(zn, self.centres) / (2.0 * self.beta**2))
        return (zn + Gz @ self.W) * sx + cx


def register_rigid(
    X: np.ndarray,
    Y: np.ndarray,
    w: float = 0.0,
    *,
    scale: bool = True,
    max_iter: int = 200,
    tol: float = 1e-10,
    init: RigidResult | None = None,
) -> RigidResult:
    """Rigid CPD (rotation, translation and, by default, uniform scale) of ``Y`` onto ``X``.

    Args:
        X: (N, D) data points.
        Y: (M, D) template points (the set that moves).
        w: outlier weight in [0, 1).
        scale: estimate the scale (else s = 1).
        max_iter: EM iteration cap (integer >= 1).
        tol: stop when the relative change of sigma^2 falls below this (>= 0).
        init: warm start: EM continues from this result's transform and variance (e.g. an
            earlier registration of the same point sets with a looser ``tol``) instead of
            the identity and the data's spread. Its iterations are not counted again.

    Raises:
        InvalidParameterError: malformed or non-finite points, different dimensions, ``w``
            outside [0, 1), bad ``max_iter`` / ``tol``, a degenerate point set (all
            points identical: ``X`` always, ``Y`` when ``scale`` is estimated), or an
            ``init`` that is not finite or not of the same dimension.
    """
    X, Y, w = _check_pair(X, Y, w, max_iter, tol)
    if scale:
        _check_spread("Y", Y)
    D = X.shape[1]
    floor = _S2_FLOOR * max(float(np.var(X, axis=0).sum()), 1e-300)
    if init is None:
        s2 = _init_s2(X, Y)
        R, t, s = np.eye(D), np.zeros(D), 1.0
        TY = Y.copy()
    else:
        R, t, s, s2 = _check_init(init, D)
        s2 = max(s2, floor)
        TY = s * Y @ R.T + t
    x2 = np.einsum("ij,ij->i", X, X)
    y2 = np.einsum("ij,ij->i", Y, Y)
    Cm = np.eye(D)
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007
        e = _estep_direct(X, TY, s2, w)
        if e.Np <= 0.0:
            break
        mux = X.T @ e.Pt1 / e.Np
        muy = Y.T @ e.P1 / e.Np
        A = e.PX.T @ Y - e.Np * np.outer(mux, muy)  # = Xhat^T P^T Yhat
        if D == 2:  # the proper rotation maximising tr(A^T R), in closed form
            ang = math.atan2(float(A[1, 0] - A[0, 1]), float(A[0, 0] + A[1, 1]))
            R = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
        else:
            U, _, Vt = np.linalg.svd(A)
            Cm[-1, -1] = 1.0 if np.linalg.det(U @ Vt) >= 0.0 else -1.0
            R = U @ Cm @ Vt
        trAR = float(np.sum(A * R))
        yy = float(e.P1 @ y2 - e.Np * muy @ muy)
        xx = float(e.Pt1 @ x2 - e.Np * mux @ mux)
        s = trAR / yy if scale else 1.0
        t = mux - s * R @ muy
        new = (xx - s * trAR) / (e.Np * D) if scale else (xx - 2 * trAR + yy) / (e.Np * D)
        TY = s * Y @ R.T + t
        new = max(new, floor)
        done = abs(new - s2) <= tol * s2 or new <= floor
        s2 = new
        if done:
            break
    return RigidResult(TY, R, t, float(s), float(s2), it)


def _check_init(init: RigidResult, D: int) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(R, t, s, sigma2)`` of a warm start, checked."""
    R, t = np.asarray(init.R, dtype=float), np.asarray(init.t, dtype=float)
    if R.shape != (D, D) or t.shape != (D,):
        raise InvalidParameterError(
            f"init has dimension {t.shape[0] if t.ndim == 1 else t.shape}, the points have {D}"
        )
    vals = np.concatenate([R.ravel(), t, [init.s, init.sigma2]])
    if not np.all(np.isfinite(vals)) or init.sigma2 <= 0 or init.s <= 0:
        raise InvalidParameterError("init must have a finite transform, s > 0 and sigma2 > 0")
    return R, t, float(init.s), float(init.sigma2)


def _kernel(Y: np.ndarray, beta: float) -> np.ndarray:
    return np.exp(-_sqdist(Y, Y) / (2.0 * beta**2))


def register_nonrigid(
    X: np.ndarray,
    Y: np.ndarray,
    beta: float = 3.0,
    lmbda: float = 3.0,
    w: float = 0.0,
    *,
    fgt: bool = False,
    lowrank: bool = False,
    rank_tol: float = 1e-8,
    max_rank: int = 40,
    fgt_eps: float = 1e-6,
    normalize: bool = True,
    sigma2: float | None = None,
    max_iter: int = 150,
    tol: float = 1e-5,
) -> NonRigidResult:
    """Non-rigid CPD with motion-coherence regularisation.

    Args:
        X: (N, D) data points.
        Y: (M, D) template points.
        beta: Gaussian kernel width of the displacement field (normalised units).
        lmbda: regularisation weight (larger = smoother, more rigid-like motion).
        w: outlier weight in [0, 1).
        fgt: compute E-steps with the improved Fast Gauss Transform where it is cheaper.
        lowrank: use the leading eigenpairs of the kernel (eigenvalues above
            ``rank_tol`` times the largest).
        rank_tol: relative eigenvalue cut for ``lowrank``, in [0, 1).
        max_rank: at most this many eigenpairs are computed for ``lowrank`` (>= 1).
        fgt_eps: FGT error per unit weight, in (0, 1).
        normalize: register zero-mean, unit-RMS copies (then denormalise the result).
        sigma2: initial mixture variance in the input unit squared, > 0, used when it is
            below the one estimated from the data (e.g. the final variance of a rigid
            registration that already aligned ``Y``); default: the data's.
        max_iter: EM iteration cap (integer >= 1).
        tol: stop when the relative change of sigma^2 falls below this (>= 0).

    Raises:
        InvalidParameterError: as :func:`register_rigid` (``X`` must not be degenerate; a
            degenerate ``Y`` is allowed), or any of the ranges above violated.
    """
    X, Y, w = _check_pair(X, Y, w, max_iter, tol)
    beta = check_positive("beta", beta)
    lmbda = check_positive("lmbda", lmbda)
    rt = check_finite("rank_tol", rank_tol, minimum=0.0)
    if rt >= 1.0:
        raise InvalidParameterError(f"rank_tol must be in [0, 1), got {rank_tol!r}")
    check_int("max_rank", max_rank, minimum=1)
    _check_eps("fgt_eps", fgt_eps)
    if sigma2 is not None:
        check_positive("sigma2", sigma2)
    M, D = Y.shape
    if normalize:
        cx, cy = X.mean(0), Y.mean(0)
        sx = float(np.sqrt(np.sum((X - cx) ** 2) / X.shape[0])) or 1.0
        sy = float(np.sqrt(np.sum((Y - cy) ** 2) / M)) or 1.0
        Xn, Yn = (X - cx) / sx, (Y - cy) / sy
    else:
        cx, sx = np.zeros(D), 1.0
        cy, sy = np.zeros(D), 1.0
        Xn, Yn = X, Y
    G = _kernel(Yn, beta)
    if lowrank:
        # the kept rank is usually small: try a few eigenpairs, all of them only if needed
        top = min(M, max_rank, _FIRST_RANK)
        lam, Q = eigh(G, subset_by_index=[M - top, M - 1])
        if lam[0] > rank_tol * lam[-1] and top < min(M, max_rank):
            top = min(M, max_rank)
            lam, Q = eigh(G, subset_by_index=[M - top, M - 1])
        keep = lam > rank_tol * lam[-1]
        lam, Q = lam[keep], Q[:, keep]
        rank = int(lam.size)
    else:
        rank = M
    s2 = _init_s2(Xn, Yn)
    if sigma2 is not None:
        s2 = min(s2, check_finite("sigma2", sigma2) / sx**2)
    floor = _S2_FLOOR * max(float(np.var(Xn, axis=0).sum()), 1e-300)
    s2 = max(s2, floor)
    W = np.zeros((M, D))
    TY = Yn.copy()
    x2 = np.einsum("ij,ij->i", Xn, Xn)
    it = 0
    nfgt = 0
    inv_lam = np.diag(1.0 / lam) if lowrank else np.zeros((0, 0))
    last: tuple[np.ndarray, np.ndarray, np.ndarray, float] | None = None
    for it in range(1, max_iter + 1):  # noqa: B007
        e = _estep_fgt(Xn, TY, s2, w, fgt_eps) if fgt else _estep_direct(Xn, TY, s2, w)
        nfgt += int(e.used_fgt)
        if e.Np <= 0.0:
            break
        P1 = np.maximum(e.P1, 1e-300)
        rhs = e.PX - P1[:, None] * Yn  # (dP1 G + lmbda s2 I) W = PX - dP1 Y
        ls2 = lmbda * s2
        if lowrank:
            # Woodbury: W = (rhs - U z) / ls2 with z = inner^-1 Q^T rhs, and then
            # G W = Q diag(lam) Q^T W = Q z exactly; W itself is formed once, after the loop
            U = P1[:, None] * Q  # dP1 Q
            inner = ls2 * inv_lam + Q.T @ U
            z = np.linalg.solve(inner, Q.T @ rhs)
            last = (rhs, U, z, ls2)
            GW = Q @ z
        else:
            Amat = G + ls2 * np.diag(1.0 / P1)
            try:
                W = cho_solve(cho_factor(Amat), rhs / P1[:, None])
            except np.linalg.LinAlgError:
                W = np.linalg.solve(Amat, rhs / P1[:, None])
            GW = G @ W
        TY = Yn + GW
        xPx = float(e.Pt1 @ x2)
        trPXT = float(np.vdot(e.PX, TY))
        trTPT = float(e.P1 @ np.einsum("ij,ij->i", TY, TY))
        new = max((xPx - 2.0 * trPXT + trTPT) / (e.Np * D), floor)
        done = abs(new - s2) <= tol * s2 or new <= floor
        s2 = new
        if done:
            break
    if last is not None:
        rhs, U, z, ls2 = last
        W = (rhs - U @ z) / ls2
    pts = TY * sx + cx
    return NonRigidResult(pts, W, float(s2), it, nfgt, rank, beta, Yn, (cx, sx, cy, sy))
