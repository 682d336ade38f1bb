"""Exception hierarchy. Every error is a ``ValueError`` so callers can catch bad input uniformly."""

from __future__ import annotations

from collections.abc import Iterable


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
