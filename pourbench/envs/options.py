"""The pouring tasks' ``reset(options=...)``, checked once at that boundary.

:meth:`ResetOptions.parse` turns the user's dict into typed fields, refusing unknown keys and
malformed values with a :class:`~pourbench.errors.PourbenchError` before any world changes.
What depends on the scene (whether the container is one of the task's, whether the amounts
fit it, whether the start is on the table) is checked by the env that knows it, still before
any state changes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from pourbench.errors import (
    InvalidParameterError,
    UnknownNameError,
    check_finite,
    check_positive,
)
from pourbench.fluids.params import LiquidProfile, liquid_names, liquid_profile


def known_liquid(liquid: str | LiquidProfile) -> LiquidProfile:
    """The profile for ``liquid``; an :class:`UnknownNameError` listing the known names
    otherwise, and an :class:`InvalidParameterError` for a profile without a physical viscosity
    (the observation's viscosity feature needs one)."""
    try:
        profile = liquid_profile(liquid)
    except UnknownNameError:
        raise
    except Exception as exc:  # e.g. a non-string
        raise UnknownNameError("liquid", liquid, liquid_names()) from exc
    if profile.viscosity_pa_s is None or profile.viscosity_pa_s <= 0.0:
        raise InvalidParameterError(
            f"liquid {profile.name!r} has no physical viscosity (viscosity_pa_s or "
            f"viscosity_cp, got {profile.viscosity_pa_s!r}); the pouring tasks observe it"
        )
    return profile


@dataclass(frozen=True)
class ResetOptions:
    """One episode's choices; each None is drawn from the env's config at reset.

    Attributes:
        liquid: the liquid, a profile or a name (made its profile); None: the config's
            liquid, or the curriculum's draw.
        container: the pouring container's name.
        target_g: the amount to pour (g, > 0).
        initial_g: the amount filled in (g, at least ``target_g``).
        start: the pouring container's base relative to the receiving container's (3,; m).
    """

    liquid: LiquidProfile | str | None = None
    container: str | None = None
    target_g: float | None = None
    initial_g: float | None = None
    start: np.ndarray | None = None

    KEYS: ClassVar[tuple[str, ...]] = ("container", "initial_g", "liquid", "start", "target_g")

    def __post_init__(self) -> None:
        """Check and convert the fields (a liquid name becomes its profile), so that every
        instance, however made, holds checked values; raises as :meth:`parse`."""
        liquid, container, start = self.liquid, self.container, self.start
        if container is not None and not isinstance(container, str):
            raise InvalidParameterError(f"container must be a name, got {container!r}")
        set_ = object.__setattr__
        set_(self, "liquid", None if liquid is None else known_liquid(liquid))
        if self.target_g is not None:
            set_(self, "target_g", check_positive("target_g", self.target_g))
        if self.initial_g is not None:
            set_(self, "initial_g", check_finite("initial_g", self.initial_g))
        set_(self, "start", None if start is None else _start(start))

    @classmethod
    def parse(cls, options: Mapping | ResetOptions | None) -> ResetOptions:
        """``options`` (a dict of :attr:`KEYS`) as checked fields.

        Raises:
            InvalidParameterError: not a mapping, an unknown key, or a malformed value.
            UnknownNameError: an unknown liquid.
        """
        if options is None or isinstance(options, ResetOptions):
            return options or cls()
        if not isinstance(options, Mapping):
            raise InvalidParameterError(
                f"reset options must be a dict such as {{'liquid': 'water'}}, got {options!r}"
            )
        unknown = sorted(set(options) - set(cls.KEYS))
        if unknown:
            raise InvalidParameterError(f"unknown reset options {unknown}; known: {list(cls.KEYS)}")
        return cls(**options)


def _start(value: object) -> np.ndarray:
    try:
        start = np.asarray(value)
    except (TypeError, ValueError):
        start = np.full(1, np.nan)  # refused just below
    if start.dtype.kind not in "fiu":  # strings, booleans: refused, not converted
        start = np.full(1, np.nan)
    start = start.astype(float)
    if start.shape != (3,) or not np.all(np.isfinite(start)):
        raise InvalidParameterError(
            f"start must be three finite numbers (x, y, height of the pouring container's "
            f"base relative to the receiving container's, m), got {value!r}"
        )
    return start
