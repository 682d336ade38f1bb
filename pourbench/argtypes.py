"""Value types for the console script's options: a NaN, infinite, zero or negative number, or a
policy that is neither known nor a file, is refused while the arguments are parsed, with the
option's name, before any work starts."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

BUILTIN_POLICIES: tuple[str, ...] = ("pd", "random")
"""Policies ``pourbench eval`` knows by name (the rest are paths of saved models)."""


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
    """A built-in policy ("pd", "random") or the path of an existing saved model."""
    if text in BUILTIN_POLICIES or Path(text).is_file():
        return text
    raise argparse.ArgumentTypeError(
        f"{text!r} is neither a policy {list(BUILTIN_POLICIES)} nor a saved model file"
    )
