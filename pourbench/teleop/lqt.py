"""Discrete finite-horizon linear quadratic tracking on a double integrator (thesis §2.6.2).

Written by hand in numpy: the backward Riccati recursion of Eq. 2.48-2.49 and the control law
of Eq. 2.47. The state is ``xi = [x, x_dot]`` (D positions and D velocities), the input is the
acceleration, and

    xi_{t+1} = A xi_t + B u_t,  A = [[I, dt I], [0, I]],  B = [[dt^2 / 2 I], [dt I]]   (2.46)

minimises ``sum_t (xi_t - mu_t)^T Q_t (xi_t - mu_t) + u_t^T R u_t`` for a sequence of
step-wise Gaussians ``N(mu_t, Sigma_t)`` with ``Q_t = Sigma_t^{-1}`` (2.45). With the tracking
error ``e_t = xi_t - mu_t`` the value function is ``e^T P_t e + 2 e^T d_t + const``:

    P_t = Q_t + A^T P_{t+1} A - A^T P_{t+1} B (R + B^T P_{t+1} B)^{-1} B^T P_{t+1} A,  P_T = Q_T
    d_t = (A - B K_t)^T (P_{t+1} (A mu_t - mu_{t+1}) + d_{t+1}),                    d_T = 0
    u_t = -K_t e_t - (R + B^T P_{t+1} B)^{-1} B^T (P_{t+1} (A mu_t - mu_{t+1}) + d_{t+1})

with ``K_t = (R + B^T P_{t+1} B)^{-1} B^T P_{t+1} A`` (the thesis writes the same recursion with
its indices shifted by one). Units: whatever ``mu`` is in; ``dt`` is one step unless given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_int, check_positive

__all__ = ["LQTResult", "double_integrator", "lqt_track"]


def double_integrator(dim: int, dt: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of Eq. 2.46 for ``dim`` positions, time step ``dt``.

    Raises:
        InvalidParameterError: ``dim`` not an integer >= 1 or ``dt`` not finite and > 0.
    """
    dim = check_int("dim", dim, minimum=1)
    dt = check_positive("dt", dt)
    eye = np.eye(dim)
    zero = np.zeros((dim, dim))
    A = np.block([[eye, dt * eye], [zero, eye]])
    B = np.vstack([0.5 * dt**2 * eye, dt * eye])
    return A, B


@dataclass(frozen=True)
class LQTResult:
    """A reproduced trajectory.

    Attributes:
        states: (T, 2D) ``[x, x_dot]`` along the horizon.
        controls: (T - 1, D) accelerations.
        gains: (T - 1, D, 2D) feedback gains ``K_t`` (``u = -K_t e_t + ff_t``).
        feedforward: (T - 1, D) feedforward terms.
    """

    states: np.ndarray
    controls: np.ndarray
    gains: np.ndarray
    feedforward: np.ndarray

    @property
    def positions(self) -> np.ndarray:
        """(T, D) positions."""
        return self.states[:, : self.controls.shape[1]]


def _first_not_cholesky(sigma: np.ndarray) -> int:
    """Index of the first matrix of ``sigma`` (T, n, n) whose Cholesky factorisation fails."""
    for t in range(sigma.shape[0]):
        try:
            np.linalg.cholesky(sigma[t])
        except np.linalg.LinAlgError:
            return t
    return 0  # unreachable: the batched factorisation failed on one of them


def lqt_track(
    mu: np.ndarray,
    sigma: np.ndarray,
    *,
    r: float = 1e-3,
    dt: float = 1.0,
    x0: np.ndarray | None = None,
) -> LQTResult:
    """Track step-wise Gaussians with the discrete finite-horizon LQT.

    Args:
        mu: (T, 2D) desired ``[position, velocity]`` per step.
        sigma: (T, 2D, 2D) covariances; ``Q_t = inv(sigma_t)``.
        r: control weight, ``R = r I`` (units of Q times (step^2 / position)^2).
        dt: step duration of the double integrator.
        x0: (2D,) initial state (defaults to ``mu[0]``).

    Raises:
        InvalidParameterError: malformed or non-finite ``mu`` / ``sigma`` / ``x0``, a
            ``sigma_t`` that is not symmetric (to a relative 1e-9) or not positive definite
            as Cholesky sees it (singular, numerically singular or indefinite: ``Q_t`` must
            be its inverse and a valid cost weight), or ``r`` / ``dt`` not finite and > 0.
    """
    mu = np.asarray(mu, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    if mu.ndim != 2 or mu.shape[0] < 2 or mu.shape[1] < 2 or mu.shape[1] % 2:
        raise InvalidParameterError(f"mu must be (T >= 2, 2D), got {mu.shape}")
    T, n = mu.shape
    if sigma.shape != (T, n, n):
        raise InvalidParameterError(f"sigma must be {(T, n, n)}, got {sigma.shape}")
    if not (np.all(np.isfinite(mu)) and np.all(np.isfinite(sigma))):
        raise InvalidParameterError("mu/sigma contain NaN or infinite values")
    r = check_positive("r", r)
    # a covariance is symmetric (Cholesky would read only its lower triangle)
    asym = np.abs(sigma - sigma.transpose(0, 2, 1)).max(axis=(1, 2))
    scale = np.abs(sigma).max(axis=(1, 2))
    if np.any(asym > 1e-9 * scale):
        bad = int(np.argmax(asym > 1e-9 * scale))
        raise InvalidParameterError(
            f"sigma[{bad}] is not symmetric (largest |sigma - sigma^T| {asym[bad]:.3g})"
        )
    try:
        np.linalg.cholesky(sigma)
    except np.linalg.LinAlgError:
        raise InvalidParameterError(
            f"sigma[{_first_not_cholesky(sigma)}] is not positive definite (singular, "
            f"numerically singular or indefinite covariance)"
        ) from None
    D = n // 2
    A, B = double_integrator(D, dt)
    R = r * np.eye(D)
    Q = np.linalg.inv(sigma)
    P = Q[-1].copy()
    d = np.zeros(n)
    gains = np.empty((T - 1, D, n))
    ff = np.empty((T - 1, D))
    for t in range(T - 2, -1, -1):
        S = R + B.T @ P @ B
        K = np.linalg.solve(S, B.T @ P @ A)
        c = A @ mu[t] - mu[t + 1]
        v = P @ c + d
        gains[t] = K
        ff[t] = -np.linalg.solve(S, B.T @ v)
        d = (A - B @ K).T @ v
        P = Q[t] + A.T @ P @ A - A.T @ P @ B @ K
        P = 0.5 * (P + P.T)
    x = mu[0].copy() if x0 is None else np.asarray(x0, dtype=float).copy()
    if x.shape != (n,) or not np.all(np.isfinite(x)):
        raise InvalidParameterError(f"x0 must be a finite vector of length {n}")
    states = np.empty((T, n))
    controls = np.empty((T - 1, D))
    states[0] = x
    for t in range(T - 1):
        u = -gains[t] @ (x - mu[t]) + ff[t]
        x = A @ x + B @ u
        controls[t] = u
        states[t + 1] = x
    return LQTResult(states, controls, gains, ff)
