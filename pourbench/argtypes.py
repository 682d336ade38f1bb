"""Value types for the console script's options: a NaN, infinite, zero or negative number, or a
policy that is neither known nor a file, is refused while the arguments are parsed, with the
option's name, before any work starts."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

BUILTIN_POLICIES: tuple[str, ...] = ("pd", "random")
"""Policies ``pourbench eval`` knows by name besides the shipped ones (the rest are paths of
saved models)."""

POLICY_DIR = Path(__file__).parent / "agents" / "policies"
"""Where shipped policies live: ``<name>.zip`` (the SB3 model) beside ``<name>.json``."""


def shipped_policies() -> list[str]:
    """Names of the shipped policies (a ``.zip`` with its ``.json`` in :data:`POLICY_DIR`)."""
    if not POLICY_DIR.is_dir():
        return []
    return sorted(p.stem for p in POLICY_DIR.glob("*.zip") if p.with_suffix(".json").is_file())


def policy_choices() -> str:
    """The policy names that exist, for messages: built-in, shipped (or that none ships)."""
    shipped = shipped_policies()
    names = ", ".join([*BUILTIN_POLICIES, *shipped])
    return names + ("" if shipped else " (no trained policy ships yet)")


def positive_float(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def _integer(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """A whole number >= 1."""
    return _integer(text, 1)


def nonnegative_int(text: str) -> int:
    """A whole number >= 0 (seeds)."""
    return _integer(text, 0)


def policy_name(text: str) -> str:
    """A built-in policy ("pd", "random"), a shipped one, or the path of an existing saved
    model."""
    if text in BUILTIN_POLICIES or text in shipped_policies() or Path(text).is_file():
        return text
    raise argparse.ArgumentTypeError(
        f"{text!r} is neither a policy ({policy_choices()}) nor a saved model file"
    )
