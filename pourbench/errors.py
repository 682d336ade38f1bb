"""Exception hierarchy, and the input checks that raise it (numbers, integers, arrays, poses,
quaternions, TOML data files). Every pourbench error is a :class:`PourbenchError`, itself a
``ValueError``, so callers catch bad input uniformly."""

from __future__ import annotations

import numbers
import os
import tomllib
from collections.abc import Iterable
from pathlib import Path

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

    def __reduce__(self) -> tuple:  # pickles (a vector env's worker sends it to the parent)
        return (type(self), (self.kind, self.name, self.known))


class InvalidParameterError(PourbenchError):
    """A numeric parameter that is NaN, infinite, or out of its allowed range."""


class ProfileFileError(PourbenchError):
    """A malformed data file (TOML): names the file and the offending key."""

    def __init__(self, path: object, key: str, problem: str) -> None:
        self.path = str(path)
        self.key = key
        self.problem = problem
        super().__init__(f"{self.path}: key {key!r}: {problem}")

    def __reduce__(self) -> tuple:  # pickles (a vector env's worker sends it to the parent)
        return (type(self), (self.path, self.key, self.problem))


def read_toml(path: str | os.PathLike[str]) -> dict:
    """The TOML document at ``path``; a :class:`ProfileFileError` naming the file when it
    cannot be read (missing, a folder, not UTF-8) or is not valid TOML."""
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ProfileFileError(path, "<file>", f"invalid TOML: {exc}") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise ProfileFileError(path, "<file>", f"cannot read: {exc}") from exc


class CapacityError(PourbenchError):
    """More liquid than a container can hold."""


def check_finite(name: str, value: float, *, minimum: float | None = None) -> float:
    """Return ``value`` as float, raising :class:`InvalidParameterError` if NaN/inf or < minimum,
    or not a number (a bool or a string such as ``"0.5"`` is refused, not converted)."""
    if isinstance(value, bool | np.bool_ | str | bytes):
        raise InvalidParameterError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"{name} must be a number, got {value!r}") from exc
    if v != v or v in (float("inf"), float("-inf")):
        raise InvalidParameterError(f"{name} must be finite, got {value!r}")
    if minimum is not None and v < minimum:
        raise InvalidParameterError(f"{name} must be >= {minimum}, got {value!r}")
    return v


def check_positive(name: str, value: float) -> float:
    """Return ``value`` as float, raising :class:`InvalidParameterError` unless finite and > 0."""
    v = check_finite(name, value)
    if v <= 0:
        raise InvalidParameterError(f"{name} must be > 0, got {value!r}")
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
    raising :class:`InvalidParameterError` that names ``name`` and the shape it got. Cheap on
    good input (the coupling checks every step's poses): one sum tests finiteness."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"{name} must be numbers, got {value!r}") from exc
    if arr.ndim != len(shape) or any(
        s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
    ):
        want = ", ".join("n" if s is None else str(s) for s in shape)
        want = f"({want},)" if len(shape) == 1 else f"({want})"
        raise InvalidParameterError(f"{name} must have shape {want}, got {arr.shape}")
    # a sum is finite when every entry is, unless finite entries overflow it: then look closer
    if not np.isfinite(arr.sum()) and not np.isfinite(arr).all():
        raise InvalidParameterError(f"{name} must be finite")
    return arr


def check_quat(name: str, value: object) -> np.ndarray:
    """``value`` as 4 finite numbers (w, x, y, z) of non-zero norm, as given (MuJoCo and the
    planners normalise it); an :class:`InvalidParameterError` naming ``name`` otherwise."""
    q = check_array(name, value, (4,))
    if not float(q @ q) > 1e-18:
        raise InvalidParameterError(f"{name} must not be zero, got {q.tolist()}")
    return q


_UNIT_NORM2 = ((1.0 - 1e-3) ** 2, (1.0 + 1e-3) ** 2)  # |q| within 1e-3 of 1, squared


def check_poses(name: str, value: object, count: int) -> np.ndarray:
    """``count`` poses (x, y, z, qw, qx, qy, qz) as a (count, 7) array; each quaternion must be
    unit length within 1e-3 (it is used as given, not normalised)."""
    arr = check_array(name, value, (count, 7))
    if count == 0:
        return arr
    norm2 = np.einsum("ij,ij->i", arr[:, 3:], arr[:, 3:])
    lo, hi = _UNIT_NORM2
    if not (lo <= norm2.min() and norm2.max() <= hi):
        row = int(np.flatnonzero((norm2 < lo) | (norm2 > hi))[0])
        raise InvalidParameterError(
            f"{name}: the quaternion of row {row} has norm {np.sqrt(norm2[row]):.6g}, not 1"
        )
    return arr
