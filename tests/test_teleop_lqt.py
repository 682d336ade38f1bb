"""Discrete LQT (thesis Eq. 2.45-2.49): optimality, exact tracking, and skill reproduction."""

from __future__ import annotations

import numpy as np
import pytest

from pourbench.errors import InvalidParameterError
from pourbench.teleop import SkillLibrary, double_integrator, letter_demos, lqt_track


def _batch_solution(mu, sigma, r, x0, dt=1.0):
    """Minimise the LQT cost as one least-squares problem over all controls."""
    T, n = mu.shape
    D = n // 2
    A, B = double_integrator(D, dt)
    Sx = np.zeros((T * n, n))
    Su = np.zeros((T * n, (T - 1) * D))
    Ak = np.eye(n)
    for t in range(T):
        Sx[t * n : (t + 1) * n] = Ak
        Ak = A @ Ak
        for k in range(t):
            Su[t * n : (t + 1) * n, k * D : (k + 1) * D] = np.linalg.matrix_power(A, t - 1 - k) @ B
    Q = np.zeros((T * n, T * n))
    for t in range(T):
        Q[t * n : (t + 1) * n, t * n : (t + 1) * n] = np.linalg.inv(sigma[t])
    H = Su.T @ Q @ Su + r * np.eye((T - 1) * D)
    g = Su.T @ Q @ (mu.reshape(-1) - Sx @ x0)
    return np.linalg.solve(H, g).reshape(T - 1, D)


def test_double_integrator_matrices() -> None:
    A, B = double_integrator(2, 0.1)
    x = np.array([1.0, 2.0, 0.5, -0.5])
    u = np.array([2.0, 4.0])
    nxt = A @ x + B @ u
    np.testing.assert_allclose(nxt[:2], x[:2] + 0.1 * x[2:] + 0.5 * 0.01 * u)
    np.testing.assert_allclose(nxt[2:], x[2:] + 0.1 * u)


def test_riccati_recursion_equals_batch_optimum() -> None:
    rng = np.random.default_rng(0)
    T, D = 25, 2
    mu = np.cumsum(rng.normal(size=(T, 2 * D)) * 0.1, axis=0)
    L = rng.normal(size=(T, 2 * D, 2 * D)) * 0.3
    sigma = L @ np.transpose(L, (0, 2, 1)) + 0.05 * np.eye(2 * D)
    x0 = mu[0] + rng.normal(size=2 * D) * 0.2
    res = lqt_track(mu, sigma, r=0.05, x0=x0)
    u_batch = _batch_solution(mu, sigma, 0.05, x0)
    np.testing.assert_allclose(res.controls, u_batch, rtol=1e-6, atol=1e-8)


def test_feasible_reference_is_tracked_exactly() -> None:
    # constant-velocity straight line: feasible with zero acceleration, so zero cost
    T = 40
    v = np.array([0.006, -0.002])
    pos = np.arange(T)[:, None] * v
    mu = np.hstack([pos, np.tile(v, (T, 1))])
    sigma = np.tile(np.eye(4) * 1e-4, (T, 1, 1))
    res = lqt_track(mu, sigma, r=1e-3)
    assert np.max(np.abs(res.positions - pos)) < 1e-12
    assert np.max(np.abs(res.controls)) < 1e-10


def test_lqt_reproduces_letter_skill_close_to_mean_demonstration() -> None:
    """Stated bound for K = 5 states: every point of the reproduction lies within 5 cm of the
    mean demonstration path and within 2 cm on average; it starts on the mean start point and
    ends within 5 cm of the mean end point. (Over all 26 letters we measured at most 1.85 cm
    mean, 4.9 cm max and 4.8 cm at the end: five states cut the sharpest corners.)"""
    lib = SkillLibrary(0.006).fit({L: [d.points for d in letter_demos(L, 10)] for L in "ACSZ"})
    for L in "ACSZ":
        demos = [d.points for d in letter_demos(L, 10)]
        # mean demonstration: average of the demos resampled to the same number of points
        n = 400
        res = []
        for p in demos:
            s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
            u = np.linspace(0, s[-1], n)
            res.append(np.c_[np.interp(u, s, p[:, 0]), np.interp(u, s, p[:, 1])])
        mean_path = np.mean(res, axis=0)
        traj = lib.skill(L).trajectory
        d = np.linalg.norm(traj[:, None, :] - mean_path[None, :, :], axis=2).min(axis=1)
        assert d.mean() < 0.02, (L, d.mean())
        assert d.max() < 0.05, (L, d.max())
        assert np.linalg.norm(traj[-1] - mean_path[-1]) < 0.05, L
        assert np.linalg.norm(traj[0] - mean_path[0]) < 0.005, L


def test_lqt_rejects_bad_input() -> None:
    mu = np.zeros((5, 4))
    sigma = np.tile(np.eye(4), (5, 1, 1))
    with pytest.raises(ValueError, match="mu"):
        lqt_track(np.zeros((1, 4)), sigma[:1])
    with pytest.raises(ValueError, match="sigma"):
        lqt_track(mu, sigma[:4])
    bad = mu.copy()
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        lqt_track(bad, sigma)
    with pytest.raises(ValueError, match="r"):
        lqt_track(mu, sigma, r=-1.0)


def test_lqt_refuses_covariances_that_are_not_positive_definite() -> None:
    mu = np.zeros((10, 4))
    with pytest.raises(InvalidParameterError, match=r"sigma\[0\] is not positive definite"):
        lqt_track(mu, np.zeros((10, 4, 4)))
    with pytest.raises(InvalidParameterError, match="not positive definite"):
        lqt_track(mu + 1.0, -np.tile(np.eye(4), (10, 1, 1)))
    one = np.tile(np.eye(4), (10, 1, 1))
    one[3] = np.diag([1.0, 1.0, 1.0, 0.0])
    with pytest.raises(InvalidParameterError, match=r"sigma\[3\]"):
        lqt_track(mu, one)


# symmetric, every eigenvalue (eigvalsh) > 0, yet numerically singular: Cholesky fails
_NEARLY_SINGULAR = np.array(
    [
        [0.6822680730813434, -0.1246108247674704, -0.3393252684562553, -0.29344310193472756],
        [-0.1246108247674704, 0.9511290609042113, -0.1330794861468312, -0.11508502563474765],
        [-0.3393252684562553, -0.1330794861468312, 0.637613887500869, -0.31338575353848425],
        [-0.29344310193472756, -0.11508502563474765, -0.31338575353848425, 0.7289889785135759],
    ]
)


def test_lqt_refuses_numerically_singular_covariance_clearly() -> None:
    """Not positive definite as Cholesky sees it, though eigvalsh finds no eigenvalue <= 0:
    the same InvalidParameterError naming the step, not a bare StopIteration."""
    with pytest.raises(np.linalg.LinAlgError):  # the premise of the case
        np.linalg.cholesky(_NEARLY_SINGULAR)
    sigma = np.tile(np.eye(4), (3, 1, 1))
    sigma[1] = _NEARLY_SINGULAR
    with pytest.raises(InvalidParameterError, match=r"sigma\[1\] is not positive definite"):
        lqt_track(np.zeros((3, 4)), sigma)


def test_lqt_refuses_non_symmetric_covariance() -> None:
    """Cholesky reads one triangle only: [[1, 10], [0, 1]] would pass as the identity,
    though its quadratic form is indefinite."""
    sigma = np.tile(np.eye(2), (5, 1, 1))
    sigma[2] = [[1.0, 10.0], [0.0, 1.0]]
    assert np.linalg.eigvalsh(0.5 * (sigma[2] + sigma[2].T)).min() < 0
    with pytest.raises(InvalidParameterError, match=r"sigma\[2\] is not symmetric"):
        lqt_track(np.zeros((5, 2)), sigma)
    sigma[2] = [[1.0, 1e-3], [0.0, 1.0]]  # positive definite, still not a covariance
    with pytest.raises(InvalidParameterError, match=r"sigma\[2\] is not symmetric"):
        lqt_track(np.zeros((5, 2)), sigma)


@pytest.mark.parametrize("dim", [2.5, True, "2", 0])
def test_double_integrator_refuses_non_integer_dim(dim) -> None:
    with pytest.raises(InvalidParameterError, match="dim must be"):
        double_integrator(dim)
