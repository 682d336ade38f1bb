"""Algorithm 4 of the thesis (PourNet's action handler), batched over worlds.

The policy outputs ``(ω, r)`` in [-1, 1]². The handler turns them into the pouring container's
next pose: while the container is not above the receiving one it translates toward it (straight
at it when at least ``2 × receiving height + 0.05 m`` above it, horizontally otherwise); once
above, it only rotates about the container's forward axis (world +y here, through the rim
centre), forward (ω ≥ 0) while the received weight is below ``target − tolerance`` and backward
(ω < 0) after. ``mode="free"`` applies both velocities directly: translation toward the
receiving container along the straight line, rotation of either sign, anywhere.

Coordinates: world z is up (the thesis' y), positions in m, tilt in rad, times in s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pourbench.errors import InvalidParameterError, check_finite, check_positive

ACTION_MODES: tuple[str, ...] = ("thesis", "free")


@dataclass(frozen=True)
class ActionLimits:
    """Action scaling and workspace bounds.

    Attributes:
        max_speed: translation speed at ``|r| = 1``, m/s.
        max_rate: rotation rate at ``|ω| = 1``, rad/s.
        max_tilt: largest tilt of the pouring container, rad (0 = upright).
        clearance_margin: the ``+ 0.05`` m of Algorithm 4's height clearance rule, m.
    """

    max_speed: float = 0.15
    max_rate: float = 0.8
    max_tilt: float = 2.4
    clearance_margin: float = 0.05

    def __post_init__(self) -> None:
        for name in ("max_speed", "max_rate", "max_tilt"):
            check_positive(f"limits.{name}", getattr(self, name))
        check_finite("limits.clearance_margin", self.clearance_margin, minimum=0.0)


def as_actions(actions: object, n: int | None = None) -> np.ndarray:
    """``actions`` as an (n, 2) float array of (tilt rate, approach rate) rows.

    Raises:
        InvalidParameterError: the actions do not hold two real numbers a world (``n`` worlds
            when given; booleans, strings and complex numbers are refused, not converted), or
            hold NaN or infinite values.
    """
    try:
        a = np.asarray(actions)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"actions must be numbers, got {actions!r}") from exc
    if a.dtype.kind not in "fiu":
        raise InvalidParameterError(f"actions must be real numbers, got {actions!r}")
    a = a.astype(float, copy=False)
    rows = a.size // 2 if n is None else n
    # n worlds' actions come as (n, 2); a flat (2 n,) vector is refused for n > 1, since
    # which numbers belong to which world would be a guess
    flat_batch = n is not None and n > 1 and a.ndim < 2
    if a.size != 2 * rows or a.size == 0 or (a.ndim > 1 and a.shape[-1] != 2) or flat_batch:
        want = "(2,) or (n, 2)" if n is None else ("(2,)" if n == 1 else f"({n}, 2)")
        raise InvalidParameterError(
            f"actions must have shape {want}: (tilt rate, approach rate) a world; "
            f"got shape {a.shape}"
        )
    a = a.reshape(rows, 2)
    if not np.all(np.isfinite(a)):
        raise InvalidParameterError(f"actions must be finite, got {a.tolist()}")
    return a


def allowed_rates(omega: np.ndarray, forward: np.ndarray | bool) -> np.ndarray:
    """The part of the tilt rates ``omega`` that Algorithm 4 applies: the forward part
    (ω ≥ 0) where ``forward`` (the received weight still below ``target − tolerance``), the
    backward part elsewhere."""
    return np.where(forward, np.maximum(omega, 0.0), np.minimum(omega, 0.0))


def handle_actions(
    actions: np.ndarray,
    base: np.ndarray,
    tilt: np.ndarray,
    target_pos: np.ndarray,
    above_half_extent: np.ndarray,
    receiving_height: float,
    weight_g: np.ndarray,
    target_g: np.ndarray,
    tolerance_g: float,
    dt: float,
    limits: ActionLimits = ActionLimits(),
    mode: str = "thesis",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Next pouring-container base positions and tilts for a batch of worlds.

    Args:
        actions: (n, 2) ``(ω, r)``, finite (:func:`as_actions` checks them); clipped to
            [-1, 1].
        base: (n, 3) pouring container's upright base point (rim centre minus the rim
            height), m. Only its horizontal part matters for "above".
        tilt: (n,) current tilt, rad.
        target_pos: (n, 3) receiving container's base point, m.
        above_half_extent: (n,) half-width of the square (in x and y) around the receiving
            container's axis inside which the pouring container counts as above it, m.
        receiving_height: receiving container's height (its y-extent in the thesis), m.
        weight_g: (n,) measured liquid weight in the receiving container, g.
        target_g: (n,) target, g.
        tolerance_g: Algorithm 4's ΔL_w, g.
        dt: control period, s.
        limits: scaling and bounds.
        mode: "thesis" (Algorithm 4) or "free".

    Returns:
        New base positions (n, 3), new tilts (n,), and whether each world was above the
        receiving container (n,) when the action was applied.
    """
    a = np.clip(actions, -1.0, 1.0)
    omega, r = a[:, 0] * limits.max_rate, a[:, 1] * limits.max_speed
    base = np.asarray(base, float)
    d_xy = target_pos[:, :2] - base[:, :2]
    above = np.all(np.abs(d_xy) <= above_half_extent[:, None], axis=1)
    if mode == "free":
        d = target_pos - base
        move = np.ones(len(a), bool)
        dtheta = omega * dt
    else:
        high = base[:, 2] - target_pos[:, 2] >= 2.0 * receiving_height + limits.clearance_margin
        d = np.where(high[:, None], target_pos - base, np.c_[d_xy, np.zeros(len(a))])
        move = ~above
        forward = weight_g < target_g - tolerance_g
        dtheta = allowed_rates(omega, forward) * dt
        dtheta = np.where(above, dtheta, 0.0)
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    unit = np.divide(d, norm, out=np.zeros_like(d), where=norm > 1e-9)
    step = (r * dt)[:, None] * unit
    # never step past the receiving container's axis
    step = np.where((np.linalg.norm(step, axis=1) > norm[:, 0])[:, None], d, step)
    new_base = np.where(move[:, None], base + step, base)
    new_tilt = np.clip(tilt + dtheta, 0.0, limits.max_tilt)
    return new_base, new_tilt, above
