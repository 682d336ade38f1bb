"""Curriculum of liquid-parameter ranges (thesis §6.5.6), read from a TOML file.

A lesson is a set of ranges for density (kg/m³), FleX's adhesion, cohesion and surface
tension, and the dynamic viscosity (Pa·s), plus the share of training steps it takes. Each
is drawn uniformly, the viscosity on a log scale (its range spans four decades). The default
file, ``pourbench/assets/curriculum.toml``, holds the thesis' three lessons. A liquid is
drawn from the current lesson alone (the thesis' schedule), or, rehearsing, from it and the
lessons before it (:func:`draw_liquid`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from pourbench.errors import ProfileFileError, check_finite, read_toml
from pourbench.fluids import LiquidProfile, liquid_profile

DEFAULT_CURRICULUM = Path(str(resources.files("pourbench") / "assets" / "curriculum.toml"))
RANDOMISED: tuple[str, ...] = (
    "density",
    "adhesion",
    "cohesion",
    "surface_tension",
    "viscosity_pa_s",
)
LOG_UNIFORM = frozenset({"viscosity_pa_s"})
"""Parameters drawn uniformly in their logarithm."""


@dataclass(frozen=True)
class Lesson:
    """One lesson: a range ``(low, high)`` per randomised liquid parameter.

    Attributes:
        name: lesson name.
        fraction: share of training steps spent in it.
        ranges: parameter name -> (low, high); density in kg/m³, viscosity_pa_s in Pa·s, the
            others FleX coefficients.
    """

    name: str
    fraction: float
    ranges: dict[str, tuple[float, float]]

    def sample(
        self, rng: np.random.Generator, base: str | LiquidProfile = "water"
    ) -> LiquidProfile:
        """A liquid with every randomised parameter drawn from its range (uniformly, or
        log-uniformly for :data:`LOG_UNIFORM`), named ``"lesson <lesson name>"`` (what an
        episode's ``info["liquid"]`` then says) rather than after ``base``, whose other
        attributes it keeps."""
        values = {}
        for k in RANDOMISED:
            lo, hi = self.ranges[k]
            if k in LOG_UNIFORM:
                values[k] = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
            else:
                values[k] = float(rng.uniform(lo, hi))
        return liquid_profile(base).replace(
            name=f"lesson {self.name}",
            viscosity_source=f"drawn from lesson {self.name}'s range",
            **values,
        )


def load_curriculum(path: str | Path | None = None) -> tuple[Lesson, ...]:
    """Read lessons from a TOML file (``[[lesson]]`` tables; the shipped file by default).

    Raises:
        ProfileFileError: naming the file, lesson and key: the file is not TOML, a lesson lacks a
            range or a fraction, a range is not ``[low, high]`` of finite numbers with
            low ≤ high, a density or viscosity is not > 0 or a FleX coefficient is negative,
            or the fractions are not ≥ 0 and do not sum to 1.
    """
    path = Path(path) if path is not None else DEFAULT_CURRICULUM
    data = read_toml(path)
    lessons = []
    for i, entry in enumerate(data.get("lesson", [])):
        ranges = {}
        for key in RANDOMISED:
            rng = entry.get(key)
            if not (
                isinstance(rng, list)
                and len(rng) == 2
                and all(isinstance(v, int | float) and math.isfinite(v) for v in rng)
                and rng[0] <= rng[1]
            ):
                raise ProfileFileError(
                    path,
                    f"lesson[{i}].{key}",
                    f"must be [low, high] of finite numbers with low <= high, got {rng!r}",
                )
            positive = key == "density" or key in LOG_UNIFORM
            if rng[0] < 0 or (positive and rng[0] == 0):
                least = "> 0" if positive else ">= 0"
                raise ProfileFileError(path, f"lesson[{i}].{key}", f"must be {least}, got {rng!r}")
            ranges[key] = (float(rng[0]), float(rng[1]))
        fraction = entry.get("fraction")
        if not (isinstance(fraction, int | float) and math.isfinite(fraction) and fraction >= 0):
            raise ProfileFileError(
                path, f"lesson[{i}].fraction", f"must be a number >= 0, got {fraction!r}"
            )
        lessons.append(Lesson(str(entry.get("name", f"lesson{i}")), float(fraction), ranges))
    if not lessons:
        raise ProfileFileError(path, "lesson", "no [[lesson]] tables")
    total = sum(lesson.fraction for lesson in lessons)
    if abs(total - 1.0) > 1e-6:
        raise ProfileFileError(path, "lesson", f"the fractions sum to {total}, not 1")
    return tuple(lessons)


def draw_liquid(
    lessons: tuple[Lesson, ...], k: int, rng: np.random.Generator, rehearse: bool = False
) -> LiquidProfile:
    """A liquid drawn from lesson ``k``; with ``rehearse``, from a lesson drawn uniformly
    among lessons 0…k first, so that the earlier lessons' liquids stay in training after
    their turn (why: docs/training.md)."""
    if rehearse:
        k = int(rng.integers(k + 1))
    return lessons[k].sample(rng)


def lesson_at(progress: float, lessons: tuple[Lesson, ...]) -> int:
    """Index of the lesson for a training progress in [0, 1] (fractions taken in order;
    progress past 1, as a last rollout may overshoot its budget, gives the last lesson).

    Raises:
        InvalidParameterError: ``progress`` is NaN, infinite or negative.
    """
    p = check_finite("progress", progress, minimum=0.0)
    edge = 0.0
    for k, lesson in enumerate(lessons):
        edge += lesson.fraction
        if p < edge:
            return k
    return len(lessons) - 1
