"""Coherent Point Drift: known transforms are recovered; bad input is refused."""

from __future__ import annotations

import numpy as np
import pytest

from pourbench.errors import InvalidParameterError
from pourbench.teleop import (
    gauss_transform,
    register_nonrigid,
    register_rigid,
)


def _rot2(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _rot3(ax: float, az: float) -> np.ndarray:
    rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    return rz @ rx


def _with_outliers(X: np.ndarray, frac: float, rng: np.random.Generator) -> np.ndarray:
    n = round(frac / (1.0 - frac) * X.shape[0])  # frac of the final set are outliers
    out = rng.uniform(X.min(axis=0), X.max(axis=0), size=(n, X.shape[1]))
    return rng.permutation(np.vstack([X, out]))


@pytest.mark.parametrize("dim", [2, 3])
def test_rigid_recovers_rotation_translation_scale_with_10pct_outliers(dim: int) -> None:
    rng = np.random.default_rng(7)
    Y = rng.uniform(-0.3, 0.3, size=(150, dim))
    R = _rot2(0.5) if dim == 2 else _rot3(0.3, -0.6)
    s, t = 1.25, rng.uniform(-0.1, 0.1, size=dim)
    X = _with_outliers(s * Y @ R.T + t, 0.10, rng)
    res = register_rigid(X, Y, w=0.1)
    assert np.max(np.abs(res.R - R)) < 1e-3
    assert np.max(np.abs(res.t - t)) < 1e-3
    assert abs(res.s - s) < 1e-3
    assert np.isclose(np.linalg.det(res.R), 1.0)
    np.testing.assert_allclose(res.transform(Y), res.points, atol=1e-12)


def test_rigid_transform_refuses_other_points() -> None:
    rng = np.random.default_rng(3)
    Y = rng.uniform(-0.3, 0.3, size=(40, 2))
    res = register_rigid(Y + 0.1, Y)
    with pytest.raises(InvalidParameterError, match="pts has 3 dims, expected 2"):
        res.transform(np.zeros((4, 3)))
    with pytest.raises(InvalidParameterError, match="pts contains NaN"):
        res.transform(np.full((4, 2), np.nan))


def test_rigid_without_scale_keeps_unit_scale() -> None:
    rng = np.random.default_rng(8)
    Y = rng.uniform(-0.3, 0.3, size=(100, 2))
    X = Y @ _rot2(-0.4).T + np.array([0.05, 0.02])
    res = register_rigid(X, Y, scale=False)
    assert res.s == 1.0
    assert np.max(np.abs(res.R - _rot2(-0.4))) < 1e-3


def _disk_and_deformation() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    r = np.sqrt(rng.uniform(0, 1, 150)) * 0.2
    a = rng.uniform(0, 2 * np.pi, 150)
    Y = np.c_[r * np.cos(a), r * np.sin(a)]
    X = Y + np.c_[0.03 * np.sin(Y[:, 1] / 0.1), 0.03 * np.cos(Y[:, 0] / 0.1)]
    return X, Y


def test_nonrigid_recovers_smooth_deformation_that_rigid_cannot() -> None:
    X, Y = _disk_and_deformation()  # deformation up to 4.2 cm
    exact = register_nonrigid(X, Y, beta=3.0, lmbda=3.0)
    assert np.max(np.linalg.norm(exact.points - X, axis=1)) < 1e-4
    low = register_nonrigid(X, Y, lowrank=True)
    assert low.rank < Y.shape[0]
    assert np.max(np.linalg.norm(low.points - X, axis=1)) < 1e-3
    fgt = register_nonrigid(X, Y, fgt=True)
    assert np.max(np.linalg.norm(fgt.points - exact.points, axis=1)) < 1e-4
    # a similarity cannot explain this deformation
    assert np.max(np.linalg.norm(register_rigid(X, Y).points - X, axis=1)) > 0.01


def test_nonrigid_field_transform_matches_points_and_moves_new_points_coherently() -> None:
    X, Y = _disk_and_deformation()
    res = register_nonrigid(X, Y)
    np.testing.assert_allclose(res.transform(Y), res.points, atol=1e-9)
    # a point near a template point moves like it
    z = Y[:1] + 1e-4
    moved = res.transform(z)
    assert np.linalg.norm((moved - z) - (res.points[:1] - Y[:1])) < 1e-3


def test_gauss_transform_matches_direct_sum_within_eps() -> None:
    rng = np.random.default_rng(1)
    S = rng.uniform(0, 1, (1500, 2))
    T = rng.uniform(0, 1, (1000, 2))
    q = rng.uniform(0, 1, (1500, 2))
    h = 2.0
    g = gauss_transform(S, T, q, h, eps=1e-6)
    assert g is not None
    d2 = np.sum((T[:, None, :] - S[None, :, :]) ** 2, axis=2)
    ref = np.exp(-d2 / h**2) @ q
    assert np.max(np.abs(g - ref)) <= 1e-6 * q.sum(axis=0).max()


def test_gauss_transform_declines_when_direct_is_cheaper() -> None:
    rng = np.random.default_rng(2)
    S = rng.uniform(0, 1, (50, 2))
    assert gauss_transform(S, S, np.ones((50, 1)), 0.01) is None


@pytest.mark.parametrize("fn", [register_rigid, register_nonrigid])
def test_malformed_input_raises_value_error(fn) -> None:
    Y = np.zeros((10, 2)) + np.arange(10)[:, None] * 0.01
    with pytest.raises(ValueError, match="X"):
        fn(np.zeros((0, 2)), Y)
    with pytest.raises(ValueError, match="Y"):
        fn(Y, np.zeros((10, 3)))
    bad = Y.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fn(Y, bad)
    with pytest.raises(ValueError, match="w"):
        fn(Y, Y, w=1.0)


_PTS = np.array([[0.0, 0.0], [1.0, 0.2], [0.3, 1.0], [0.8, 0.9], [0.1, 0.5]])


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: register_rigid(_PTS, np.ones((5, 2))), "Y is degenerate"),
        (lambda: register_rigid(np.zeros((1, 2)), np.zeros((1, 2))), "X is degenerate"),
        (lambda: register_nonrigid(np.ones((5, 2)), np.ones((5, 2))), "X is degenerate"),
        (lambda: register_rigid(_PTS, _PTS, max_iter=2.5), "max_iter must be an integer"),
        (lambda: register_rigid(_PTS, _PTS, tol=np.nan), "tol must be finite"),
        (lambda: register_rigid(np.zeros((5, 0)), np.zeros((3, 0))), "X has no dimensions"),
        (lambda: register_nonrigid(_PTS, _PTS, lowrank=True, max_rank=0), "max_rank"),
        (lambda: register_nonrigid(_PTS, _PTS, sigma2=0.0), "sigma2 must be > 0"),
        (lambda: register_nonrigid(_PTS, _PTS, lowrank=True, rank_tol=2), "rank_tol"),
        (lambda: register_nonrigid(_PTS, _PTS, lowrank=True, rank_tol=np.nan), "rank_tol"),
        (lambda: register_nonrigid(_PTS, _PTS, fgt=True, fgt_eps=0), "fgt_eps"),
        (lambda: register_nonrigid(_PTS, _PTS, fgt=True, fgt_eps=np.nan), "fgt_eps"),
        (lambda: gauss_transform(_PTS, _PTS, np.ones((5, 1)), 0.0), "h must be > 0"),
        (lambda: gauss_transform(_PTS, _PTS, np.ones((5, 1)), -1.0), "h must be > 0"),
        (lambda: gauss_transform(_PTS, _PTS, np.ones((5, 1)), 1.0, eps=2), "eps"),
        (lambda: gauss_transform(_PTS, _PTS, np.ones(5), 1.0), "weights must have shape"),
        (lambda: gauss_transform(_PTS * np.nan, _PTS, np.ones((5, 1)), 1.0), "sources"),
        (lambda: gauss_transform(_PTS, _PTS, np.ones((5, 1)), 1.0, max_order=2.5), "max_order"),
    ],
)
def test_bad_parameters_and_degenerate_sets_are_refused_clearly(call, match) -> None:
    with pytest.raises(InvalidParameterError, match=match):
        call()


def test_nonrigid_still_accepts_a_single_template_point() -> None:
    res = register_nonrigid(_PTS, _PTS[:1])
    assert np.all(np.isfinite(res.points))


def test_rigid_warm_start_resumes_the_same_em() -> None:
    rng = np.random.default_rng(11)
    Y = np.cumsum(rng.normal(0, 0.01, size=(80, 2)), axis=0)
    X = 1.2 * Y[:60] @ _rot2(0.4).T + np.array([0.1, -0.05]) + rng.normal(0, 1e-3, (60, 2))
    cold = register_rigid(X, Y, w=0.1, tol=1e-8, max_iter=300)
    early = register_rigid(X, Y, w=0.1, tol=1e-2, max_iter=300)
    assert early.iterations < cold.iterations
    warm = register_rigid(X, Y, w=0.1, tol=1e-8, max_iter=300 - early.iterations, init=early)
    assert early.iterations + warm.iterations == cold.iterations
    np.testing.assert_allclose(warm.points, cold.points, atol=1e-12)
    with pytest.raises(InvalidParameterError, match="dimension"):
        register_rigid(np.c_[X, X[:, :1]], np.c_[Y, Y[:, :1]], init=early)


def test_lowrank_field_reproduces_the_registered_points() -> None:
    # the kernel weights W are formed after the EM loop: the displacement field they define
    # must give back the registered template
    rng = np.random.default_rng(12)
    t = np.linspace(0, 3, 90)
    Y = np.c_[t, np.sin(t)] * 0.1
    X = Y + 0.01 * np.c_[np.sin(2 * t), np.cos(3 * t)] + rng.normal(0, 5e-4, Y.shape)
    for lowrank in (False, True):
        res = register_nonrigid(X, Y, w=0.1, lowrank=lowrank, tol=1e-6)
        # low rank: the field uses the full kernel, the EM its leading eigenpairs (~0.1 um)
        np.testing.assert_allclose(res.transform(Y), res.points, atol=1e-6 if lowrank else 1e-10)
        assert np.max(np.abs(res.W)) > 0  # it did move
