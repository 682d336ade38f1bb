"""Exception hierarchy. Every error is a ``ValueError`` so callers can catch bad input uniformly."""

from __future__ import annotations

import numbers
from collections.abc import Iterable

import numpy as np


class PourbenchError(ValueError):
    """Base class of all pourbench input errors."""


class UnknownNameError(PourbenchError):
    """A name (liquid, container, robot, planner, …) that is not in its registry."""

    def __init__(self, kind: str, name: object, known: Iterable[str]) -> None:
        self.kind = kind
        self.name = name
        self.known = sorted(known)
        super().__init__(f"unknown {kind} {name!r}; known {kind}s: {', '.join(self.known)}")


class InvalidParameterError(PourbenchError):
    """A numeric parameter that is NaN, infinite, or out of its allowed range."""


class ProfileFileError(PourbenchError):
    """A malformed data file (TOML): names the file and the offending key."""

    def __init__(self, path: object, key: str, problem: str) -> None:
        self.path = str(path)
        self.key = key
        super().__init__(f"{self.path}: key {key!r}: {problem}")


class CapacityError(PourbenchError):
    """More liquid than a container can hold."""


def check_finite(name: str, value: float, *, minimum: float | None = None) -> float:
    """Return ``value`` as float, raising :class:`InvalidParameterError` if NaN/inf or < minimum."""
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"{name} must be a number, got {value!r}") from exc
    if v != v or v in (float("inf"), float("-inf")):
        raise InvalidParameterError(f"{name} must be finite, got {value!r}")
    if minimum is not None and v < minimum:
        raise InvalidParameterError(f"{name} must be >= {minimum}, got {value!r}")
    return v


def check_int(name: str, value: object, *, minimum: int | None = None) -> int:
    """Return ``value`` as int, raising :class:`InvalidParameterError` unless it is an integer
    (not a bool, not a float such as 2.5 or 2.0) at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidParameterError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise InvalidParameterError(f"{name} must be >= {minimum}, got {value!r}")
    return v


def check_index(name: str, value: object, size: int) -> int:
    """Return ``value`` as an index into ``size`` items (no negative wrap-around)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidParameterError(f"{name} must be an integer index, got {value!r}")
    v = int(value)
    if not 0 <= v < size:
        raise InvalidParameterError(f"{name} {value!r} not in [0, {size})")
    return v


def check_array(name: str, value: object, shape: tuple[int | None, ...]) -> np.ndarray:
    """Return ``value`` as a finite float64 array of ``shape`` (``None``: any length there),
    raising :class:`InvalidParameterError` that names ``name`` and the shape it got."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"{name} must be numbers, got {value!r}") from exc
    want = "(" + ", ".join("n" if s is None else str(s) for s in shape)
    want += ",)" if len(shape) == 1 else ")"
    if arr.ndim != len(shape) or any(
        s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
    ):
        raise InvalidParameterError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidParameterError(f"{name} must be finite")
    return arr


def check_poses(name: str, value: object, count: int) -> np.ndarray:
    """``count`` poses (x, y, z, qx, qy, qz, qw) as a (count, 7) array; each quaternion must be
    unit length within 1e-3 (it is used as given, not normalised)."""
    arr = check_array(name, value, (count, 7))
    norms = np.linalg.norm(arr[:, 3:], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-3)
    if bad.size:
        raise InvalidParameterError(
            f"{name}: the quaternion of row {int(bad[0])} has norm {norms[bad[0]]:.6g}, not 1"
        )
    return arr
