"""The thesis' falling-ball measurement (§3.3, Table 3.4, Eq. 3.7) redone with its corrections.

The thesis timed a marble over 8.9 cm (the height of 50 ml) of each liquid in a measuring
cylinder and turned the speed into a viscosity by Stokes' law, μ = 2/9 r² g (ρ_s − ρ_f) / V.
Its numbers (``LiquidProfile.marble_viscosity_cp``) are all about 3.6 × 10⁻⁴ Pa·m / V: they
leave out two factors that dominate in this setup.

- **The cylinder's wall.** 50 ml over 8.9 cm is a bore of 2.67 cm; a 15.9 mm marble fills
  0.59 of it. Haberman & Sayre (1958) give the drag of a sphere on the axis of a cylinder as
  Stokes' times K(λ), λ = sphere over bore diameter; K(0.59) ≈ 10.
- **Inertia.** Stokes' law holds for a Reynolds number Re = ρ_f V d / μ well below 1. The
  drag here is Stokes' × (1 + 0.15 Re^0.687) (Schiller & Naumann 1933), with the wall factor
  applied to the whole: an approximation beyond Re ≈ 1.

A sphere released from rest takes a while to reach that speed: :func:`startup_fall` is how far
the same drag (taken as quasi-steady, plus the added mass of half the displaced liquid)
lets it fall first, centimetres at Re in the hundreds, a fraction of a radius at Re ≪ 1.

The marble itself is not in the thesis: a standard 15.9 mm (5/8 in) glass marble of
2500 kg/m³ is assumed. Where the corrected fall is slow (Re of a few or less: dish soap, hand
soap, hand-gel, honey) it gives the liquid's viscosity; in water, apple juice and oil the
marble falls at Re in the hundreds to thousands and had not reached its terminal speed
within 8.9 cm, so it says nothing about their viscosities (docs/viscosity.md).
"""

from __future__ import annotations

import math

from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from pourbench.errors import InvalidParameterError

GRAVITY = 9.81
"""m/s²."""
MARBLE_RADIUS = 15.9e-3 / 2
"""m: a standard 5/8-inch glass marble (assumed; the thesis gives no size)."""
MARBLE_DENSITY = 2500.0
"""kg/m³: soda-lime glass (assumed)."""
CYLINDER_RADIUS = math.sqrt(50e-6 / 0.089 / math.pi)
"""m: the measuring cylinder's bore, from its 50 ml over 8.9 cm (thesis §3.3)."""


def haberman_sayre(ratio: float) -> float:
    """Drag of a sphere moving slowly along the axis of a long cylinder over Stokes' drag in
    an unbounded liquid (Haberman & Sayre 1958); ``ratio``: sphere diameter over bore
    diameter, 0 ≤ ratio < 1."""
    lam = ratio
    num = 1.0 - 0.75857 * lam**5
    den = 1.0 - 2.1050 * lam + 2.0865 * lam**3 - 1.7068 * lam**5 + 0.72603 * lam**6
    return num / den


def _unbalanced(
    mu: float, speed: float, rho_f: float, radius: float, rho_s: float, bore_radius: float
) -> float:
    """Drag less weight less buoyancy, N, of a sphere falling at ``speed`` (m/s, down; an
    integrator may try a negative one) on the cylinder's axis: Stokes' drag × the wall factor
    × (1 + 0.15 |Re|^0.687), opposing the motion."""
    re = rho_f * abs(speed) * 2.0 * radius / mu
    drag = 6.0 * math.pi * mu * radius * speed * haberman_sayre(radius / bore_radius)
    weight = 4.0 / 3.0 * math.pi * radius**3 * GRAVITY * (rho_s - rho_f)  # less buoyancy
    return drag * (1.0 + 0.15 * re**0.687) - weight


def marble_viscosity(
    speed: float,
    liquid_density: float,
    radius: float = MARBLE_RADIUS,
    marble_density: float = MARBLE_DENSITY,
    bore_radius: float = CYLINDER_RADIUS,
) -> tuple[float, float]:
    """Dynamic viscosity (Pa·s) of a liquid in which a sphere of ``radius`` (m) and
    ``marble_density`` (kg/m³) falls steadily at ``speed`` (m/s) on the axis of a cylinder of
    ``bore_radius`` (m), and the Reynolds number of that fall (sphere diameter). Weight less
    buoyancy balances Stokes' drag × the wall factor × (1 + 0.15 Re^0.687)."""
    args = (speed, liquid_density, radius, marble_density, bore_radius)
    mu = brentq(lambda m: _unbalanced(m, *args), 1e-9, 1e6, xtol=1e-12, rtol=1e-10)
    return mu, liquid_density * speed * 2.0 * radius / mu


def terminal_speed(
    viscosity: float,
    liquid_density: float,
    radius: float = MARBLE_RADIUS,
    marble_density: float = MARBLE_DENSITY,
    bore_radius: float = CYLINDER_RADIUS,
) -> tuple[float, float]:
    """The inverse of :func:`marble_viscosity`: the steady speed (m/s) of a sphere falling
    on the axis of a cylinder through a liquid of dynamic ``viscosity`` (Pa·s), and its
    Reynolds number."""
    rest = (liquid_density, radius, marble_density, bore_radius)
    speed = brentq(lambda v: _unbalanced(viscosity, v, *rest), 0.0, 1e3, xtol=1e-12, rtol=1e-10)
    return speed, liquid_density * speed * 2.0 * radius / viscosity


def startup_fall(
    viscosity: float,
    liquid_density: float,
    radius: float = MARBLE_RADIUS,
    marble_density: float = MARBLE_DENSITY,
    bore_radius: float = CYLINDER_RADIUS,
    fraction: float = 0.98,
) -> float:
    """How far (m) a sphere released from rest on the cylinder's axis falls before it moves at
    ``fraction`` of :func:`terminal_speed`, under the drag of :func:`terminal_speed` taken as
    quasi-steady and with the added mass of half the liquid it displaces:
    (m + m_a) dv/dt = weight − buoyancy − drag(v). The history (Basset) force, left out,
    slows the approach further, so this is a lower bound on the fall a measurement of the
    terminal speed must leave behind it."""
    if not 0.0 < fraction < 1.0:
        raise InvalidParameterError(f"fraction must be in (0, 1), got {fraction!r}")
    rest = (liquid_density, radius, marble_density, bore_radius)
    target = fraction * terminal_speed(viscosity, *rest)[0]
    volume = 4.0 / 3.0 * math.pi * radius**3
    inertia = (marble_density + 0.5 * liquid_density) * volume
    stokes = 6.0 * math.pi * viscosity * radius * haberman_sayre(radius / bore_radius)
    tau = inertia / stokes  # s: the Stokes regime's time constant; inertia only shortens it

    def motion(_t: float, state: list[float]) -> list[float]:
        return [state[1], -_unbalanced(viscosity, state[1], *rest) / inertia]

    def reached(_t: float, state: list[float]) -> float:
        return state[1] - target

    reached.terminal = True  # type: ignore[attr-defined]
    sol = solve_ivp(motion, (0.0, 50.0 * tau), [0.0, 0.0], events=reached, rtol=1e-9, atol=1e-12)
    return float(sol.y_events[0][0][0])
