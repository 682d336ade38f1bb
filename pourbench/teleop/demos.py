"""Synthetic demonstrations: 26 single-stroke letters (2-D) and spoon feeding (3-D).

The thesis used a public 2-D letter set that no package ships, so pourbench generates its
own. Every letter is one pen-down stroke defined below in a unit cell (x right, y up, cap
height 1) by line segments (``("L", x, y)``) and circular arcs
(``("A", cx, cy, r, deg_from, deg_to)``, counter-clockwise when ``deg_to > deg_from``). The
stroke is densely resampled, its corners rounded by a Gaussian filter along the arc length,
centred on its bounding box and scaled to a path length of :data:`LETTER_LENGTH_M`, so that at
:data:`LETTER_DURATION_S` and the Δd = 0.6 cm sampling rule a letter has about 160 samples
(thesis Table 5.2). The feeding skill carries a spoon from a bowl to one of three containers
and back (3-D, path length :data:`FEEDING_LENGTH_M`, 30 s, about 200 samples at Δd = 1 cm).

A demonstration adds human-like variability to the template, all from one
``numpy.random.Generator`` seeded by ``(seed, skill index, demo index)`` so every demo is
reproducible on its own:

* a small random similarity (rotation ~N(0, 2°), scale ~N(1, 2 %), shift ~N(0, 0.5 cm));
* smooth spatial noise: a random low-frequency (4 harmonics) displacement along the path,
  about 0.6 cm RMS for letters and 1 cm for feeding;
* timing: total duration ~N(T, 5 %) and a random monotone time warp (speed varies between
  about 0.6x and 1.4x of the mean along the stroke).

Positions are metres, sampled every :data:`DT_S` = 33 ms (the teleoperation packet period).
"""

from __future__ import annotations

import string
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from pourbench.errors import InvalidParameterError, UnknownNameError, check_int, check_positive

__all__ = [
    "DT_S",
    "FEEDING_DURATION_S",
    "FEEDING_LENGTH_M",
    "FEEDING_TARGETS",
    "LETTERS",
    "LETTER_DURATION_S",
    "LETTER_LENGTH_M",
    "Demo",
    "delta_sample",
    "feeding_demos",
    "feeding_template",
    "letter_demos",
    "letter_template",
]

DT_S = 0.033
LETTER_LENGTH_M = 1.10
LETTER_DURATION_S = 20.0
FEEDING_LENGTH_M = 2.0
FEEDING_DURATION_S = 30.0
LETTERS: tuple[str, ...] = tuple(string.ascii_uppercase)
FEEDING_TARGETS: tuple[str, ...] = ("left", "centre", "right")

_Seg = tuple[object, ...]

# One pen-down stroke per letter (unit cell, cap height 1). Starts were chosen so that the
# letters differ early, as a writer's letters do; see the module docstring for the syntax.
_STROKES: dict[str, list[_Seg]] = {
    "A": [("L", 0, 0), ("L", 0.35, 1), ("L", 0.7, 0), ("L", 0.595, 0.3), ("L", 0.105, 0.3)],
    "B": [
        ("L", 0, 1),
        ("L", 0, 0),
        ("L", 0.4, 0),
        ("A", 0.4, 0.25, 0.25, -90, 90),
        ("L", 0.1, 0.5),
        ("L", 0.35, 0.5),
        ("A", 0.35, 0.75, 0.25, -90, 90),
        ("L", 0, 1),
    ],
    "C": [("A", 0.5, 0.5, 0.5, 45, 315)],
    "D": [("L", 0, 0), ("L", 0.25, 0), ("A", 0.25, 0.5, 0.5, -90, 90), ("L", 0, 1), ("L", 0, 0)],
    "E": [
        ("L", 0.7, 1),
        ("L", 0, 1),
        ("L", 0, 0.5),
        ("L", 0.5, 0.5),
        ("L", 0, 0.5),
        ("L", 0, 0),
        ("L", 0.7, 0),
    ],
    "F": [("L", 0, 0), ("L", 0, 0.5), ("L", 0.5, 0.5), ("L", 0, 0.5), ("L", 0, 1), ("L", 0.7, 1)],
    "G": [("L", 0.55, 0.5), ("L", 1.0, 0.5), ("A", 0.5, 0.5, 0.5, 0, -300)],
    "H": [("L", 0, 0), ("L", 0, 1), ("L", 0, 0.5), ("L", 0.6, 0.5), ("L", 0.6, 1), ("L", 0.6, 0)],
    "I": [("L", 0.5, 0), ("L", 0.1, 0), ("L", 0.3, 0), ("L", 0.3, 1), ("L", 0.1, 1), ("L", 0.5, 1)],
    "J": [("L", 0.8, 1), ("L", 0.5, 1), ("L", 0.5, 0.25), ("A", 0.25, 0.25, 0.25, 0, -180)],
    "K": [("L", 0, 1), ("L", 0, 0), ("L", 0, 0.4), ("L", 0.6, 1), ("L", 0.2, 0.6), ("L", 0.6, 0)],
    "L": [("L", 0.6, 0), ("L", 0, 0), ("L", 0, 1)],
    "M": [("L", 0.7, 0), ("L", 0.7, 1), ("L", 0.35, 0.35), ("L", 0, 1), ("L", 0, 0)],
    "N": [("L", 0, 0), ("L", 0, 1), ("L", 0.6, 0), ("L", 0.6, 1)],
    "O": [("E", 0.4, 0.5, 0.4, 0.5, 90, -280)],
    "P": [
        ("L", 0, 0.5),
        ("L", 0.35, 0.5),
        ("A", 0.35, 0.75, 0.25, -90, 90),
        ("L", 0, 1),
        ("L", 0, 0),
    ],
    "Q": [("E", 0.4, 0.5, 0.4, 0.5, -45, 300), ("L", 0.9, -0.1)],
    "R": [
        ("L", 0, 0),
        ("L", 0, 1),
        ("L", 0.35, 1),
        ("A", 0.35, 0.75, 0.25, 90, -90),
        ("L", 0, 0.5),
        ("L", 0.6, 0),
    ],
    "S": [("A", 0.3, 0.75, 0.25, 30, 270), ("A", 0.3, 0.25, 0.25, 90, -150)],
    "T": [("L", 0, 1), ("L", 0.7, 1), ("L", 0.35, 1), ("L", 0.35, 0)],
    "U": [("L", 0, 1), ("L", 0, 0.3), ("A", 0.3, 0.3, 0.3, 180, 360), ("L", 0.6, 1)],
    "V": [("L", 0, 1), ("L", 0.35, 0), ("L", 0.7, 1)],
    "W": [("L", 0, 1), ("L", 0.2, 0), ("L", 0.4, 0.7), ("L", 0.6, 0), ("L", 0.8, 1)],
    "X": [("L", 0, 1), ("L", 0.7, 0), ("L", 0.35, 0.5), ("L", 0.7, 1), ("L", 0, 0)],
    "Y": [("L", 0.35, 0), ("L", 0.35, 0.5), ("L", 0, 1), ("L", 0.35, 0.5), ("L", 0.7, 1)],
    "Z": [("L", 0, 1), ("L", 0.7, 1), ("L", 0, 0), ("L", 0.7, 0)],
}

# Feeding: bowl at the origin, three containers ahead (metres). Spoon path: dip into the
# bowl, lift, carry to the container, lower, tip (a small loop), lift, and come back.
_FEED_TARGET_XY = {"left": (0.25, 0.35), "centre": (0.45, 0.0), "right": (0.25, -0.35)}


def _polyline(segs: list[_Seg], step: float = 0.002) -> np.ndarray:
    """Densely sampled (n, 2) points of a stroke definition (unit-cell units)."""
    pts: list[np.ndarray] = []
    cur: np.ndarray | None = None
    for seg in segs:
        kind = seg[0]
        if kind == "L":
            p = np.array(seg[1:3], dtype=float)
            if cur is None:
                cur = p
                pts.append(p[None])
                continue
            n = max(2, int(np.ceil(np.linalg.norm(p - cur) / step)) + 1)
            pts.append(cur + np.linspace(0.0, 1.0, n)[1:, None] * (p - cur))
            cur = p
        elif kind in ("A", "E"):
            if kind == "A":
                cx, cy, r, a0, a1 = (float(v) for v in seg[1:6])  # type: ignore[arg-type]
                rx = ry = r
            else:
                cx, cy, rx, ry, a0, a1 = (float(v) for v in seg[1:7])  # type: ignore[arg-type]
            span = np.deg2rad(a1 - a0)
            n = max(3, int(np.ceil(abs(span) * max(rx, ry) / step)) + 1)
            a = np.deg2rad(a0) + np.linspace(0.0, 1.0, n) * span
            arc = np.c_[cx + rx * np.cos(a), cy + ry * np.sin(a)]
            if cur is not None and np.linalg.norm(arc[0] - cur) > 1e-9:
                m = max(2, int(np.ceil(np.linalg.norm(arc[0] - cur) / step)) + 1)
                pts.append(cur + np.linspace(0.0, 1.0, m)[1:, None] * (arc[0] - cur))
            pts.append(arc if cur is None else arc[1:])
            cur = arc[-1]
        else:  # pragma: no cover - definitions above are fixed
            raise InvalidParameterError(f"unknown stroke segment kind {kind!r}")
    return np.concatenate(pts, axis=0)


def _arc_resample(pts: np.ndarray, n: int) -> np.ndarray:
    """``n`` points equally spaced along the polyline ``pts``."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    u = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(u, s, pts[:, d]) for d in range(pts.shape[1])], axis=1)


def _finish(
    raw: np.ndarray, length: float, corner: float = 0.012, centre: bool = True
) -> np.ndarray:
    """Round corners (Gaussian along arc length), centre on the bbox (if ``centre``), scale
    to ``length`` m."""
    dense = _arc_resample(raw, 2000)
    sig = corner * 2000
    sm = gaussian_filter1d(dense, sig, axis=0, mode="nearest")
    sm = _arc_resample(sm, 2000)
    if centre:
        sm -= 0.5 * (sm.min(axis=0) + sm.max(axis=0))
    total = float(np.sum(np.linalg.norm(np.diff(sm, axis=0), axis=1)))
    return sm * (length / total)


def letter_template(letter: str) -> np.ndarray:
    """(2000, 2) noise-free stroke of ``letter`` in metres, bbox-centred, path length 1.1 m."""
    key = str(letter).upper()
    if key not in _STROKES:
        raise UnknownNameError("letter", letter, LETTERS)
    return _finish(_polyline(_STROKES[key]), LETTER_LENGTH_M)


def feeding_template(target: str) -> np.ndarray:
    """(2000, 3) noise-free spoon path to container ``target`` and back, metres."""
    if target not in _FEED_TARGET_XY:
        raise UnknownNameError("feeding target", target, FEEDING_TARGETS)
    tx, ty = _FEED_TARGET_XY[target]
    way = [
        (0.0, 0.0, 0.10),
        (0.0, 0.0, 0.02),  # dip into the bowl
        (0.04, 0.0, 0.03),
        (0.05, 0.0, 0.20),  # lift
        (0.5 * tx, 0.5 * ty, 0.30),
        (tx, ty, 0.22),  # above the container
        (tx, ty, 0.12),  # lower
        (tx + 0.04, ty, 0.10),
        (tx + 0.04, ty + 0.04, 0.14),  # tip
        (tx, ty, 0.20),
        (0.6 * tx, 0.6 * ty + 0.05, 0.32),  # return over an arc
        (0.0, 0.05, 0.25),
        (0.0, 0.0, 0.12),
    ]
    return _finish(np.array(way, dtype=float), FEEDING_LENGTH_M, corner=0.01, centre=False)


@dataclass(frozen=True)
class Demo:
    """One demonstration: ``points[k]`` (metres) at time ``t[k]`` (seconds)."""

    label: str
    t: np.ndarray
    points: np.ndarray


def _smooth_noise(rng: np.random.Generator, u: np.ndarray, dim: int, rms: float) -> np.ndarray:
    """Low-frequency random displacement (len(u), dim) with about ``rms`` metres RMS."""
    out = np.zeros((u.size, dim))
    for k in range(1, 5):
        a = rng.normal(size=dim) / k
        b = rng.normal(size=dim) / k
        out += np.sin(k * np.pi * u)[:, None] * a + np.cos(k * np.pi * u)[:, None] * b
    norm = float(np.sqrt(np.mean(np.sum(out**2, axis=1)))) or 1.0
    return out * (rms / norm)


def _rotation(dim: int, rng: np.random.Generator, sd_rad: float) -> np.ndarray:
    a = rng.normal(0.0, sd_rad)  # in 3-D about the vertical axis only (the table stays level)
    if dim == 2:
        return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])


def _demo(
    template: np.ndarray,
    label: str,
    duration: float,
    noise_rms: float,
    rng: np.random.Generator,
) -> Demo:
    dim = template.shape[1]
    T = duration * (1.0 + rng.normal(0.0, 0.05))
    t = np.arange(0.0, T + 1e-9, DT_S)
    tau = t / t[-1]
    c = rng.uniform(-0.13, 0.13, size=3)
    phase = tau + sum(c[k] * np.sin((k + 1) * np.pi * tau) / ((k + 1) * np.pi) for k in range(3))
    phase = np.clip(phase, 0.0, 1.0)
    s_tpl = np.linspace(0.0, 1.0, template.shape[0])
    path = np.stack([np.interp(phase, s_tpl, template[:, d]) for d in range(dim)], axis=1)
    path += _smooth_noise(rng, phase, dim, noise_rms)
    centre = template.mean(axis=0)
    R = _rotation(dim, rng, np.deg2rad(2.0))
    scale = 1.0 + rng.normal(0.0, 0.02)
    shift = rng.normal(0.0, 0.005, size=dim)
    if dim == 3:
        shift[2] *= 0.4
    pts = (path - centre) @ R.T * scale + centre + shift
    return Demo(label, t, pts)


def _check_counts(n: object, seed: object, start: object) -> tuple[int, int, int]:
    return (
        check_int("n", n, minimum=0),
        check_int("seed", seed, minimum=0),
        check_int("start", start, minimum=0),
    )


def _rng(seed: int, skill: int, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(skill), int(index)]))


def letter_demos(letter: str, n: int = 10, *, seed: int = 0, start: int = 0) -> list[Demo]:
    """``n`` demonstrations of ``letter`` (indices ``start`` .. ``start + n - 1``).

    Args:
        letter: "A" .. "Z".
        n: number of demonstrations.
        seed: dataset seed; demo ``i`` depends only on (seed, letter, i).
        start: index of the first demo (use e.g. ``start=10`` for held-out demos).

    Raises:
        InvalidParameterError: ``n``, ``seed`` or ``start`` is not an integer >= 0.
        UnknownNameError: ``letter`` is not a letter.
    """
    n, seed, start = _check_counts(n, seed, start)
    tpl = letter_template(letter)
    k = LETTERS.index(str(letter).upper())
    return [
        _demo(tpl, str(letter).upper(), LETTER_DURATION_S, 0.006, _rng(seed, k, i))
        for i in range(start, start + int(n))
    ]


def feeding_demos(target: str, n: int = 5, *, seed: int = 0, start: int = 0) -> list[Demo]:
    """``n`` 3-D spoon-feeding demonstrations toward ``target`` (see :func:`letter_demos`)."""
    n, seed, start = _check_counts(n, seed, start)
    tpl = feeding_template(target)
    k = 100 + FEEDING_TARGETS.index(target)
    return [
        _demo(tpl, target, FEEDING_DURATION_S, 0.01, _rng(seed, k, i))
        for i in range(start, start + int(n))
    ]


def delta_sample(points: np.ndarray, delta_d: float) -> np.ndarray:
    """Keep a point when it is at least ``delta_d`` (m) from the last kept one (thesis §5.3.4.1).

    Args:
        points: (n, D) trajectory, metres.
        delta_d: distance threshold Δd, metres (0.006 for letters, 0.01 for feeding).

    Returns:
        (m, D) kept points; the first point is always kept.

    Raises:
        InvalidParameterError: ``points`` is not a non-empty finite (n, D) array, or
            ``delta_d`` is not a finite number > 0.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[0] == 0:
        raise InvalidParameterError(f"points must be a non-empty (n, D) array, got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise InvalidParameterError("points contain NaN or infinite coordinates")
    delta_d = check_positive("delta_d", delta_d)
    keep = [0]
    last = pts[0]
    for i in range(1, pts.shape[0]):
        if np.linalg.norm(pts[i] - last) >= delta_d:
            keep.append(i)
            last = pts[i]
    return pts[keep]
