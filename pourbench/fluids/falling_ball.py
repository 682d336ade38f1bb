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

The marble itself is not in the thesis: a standard 15.9 mm (5/8 in) glass marble of
2500 kg/m³ is assumed. With both corrections the thesis' honey reads 11 Pa·s, within the
published range of honeys at 20 °C; dish soap, hand soap and hand-gel (Re ≤ 5) read
0.7–2 Pa·s. In water, apple juice and oil the marble falls at Re of hundreds to thousands
and had not reached its terminal speed within 8.9 cm, so the measurement says nothing about
their viscosities, and their profiles use published values.
"""

from __future__ import annotations

import math

from scipy.optimize import brentq

GRAVITY = 9.81
"""m/s²."""
MARBLE_RADIUS = 15.9e-3 / 2
"""m: a standard 5/8-inch glass marble (assumed; the thesis gives no size)."""
MARBLE_DENSITY = 2500.0
"""kg/m³: soda-lime glass (assumed)."""
CYLINDER_RADIUS = math.sqrt(50e-6 / 0.089 / math.pi)
"""m: the measuring cylinder's bore, from its 50 ml over 8.9 cm (thesis §3.3)."""
STOKES_LIMIT_RE = 10.0
"""Largest Reynolds number at which :func:`marble_viscosity` is taken as a measurement."""


def haberman_sayre(ratio: float) -> float:
    """Drag of a sphere moving slowly along the axis of a long cylinder over Stokes' drag in
    an unbounded liquid (Haberman & Sayre 1958); ``ratio``: sphere diameter over bore
    diameter, 0 ≤ ratio < 1."""
    lam = ratio
    num = 1.0 - 0.75857 * lam**5
    den = 1.0 - 2.1050 * lam + 2.0865 * lam**3 - 1.7068 * lam**5 + 0.72603 * lam**6
    return num / den


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
    wall = haberman_sayre(radius / bore_radius)
    net = 4.0 / 3.0 * math.pi * radius**3 * GRAVITY * (marble_density - liquid_density)

    def imbalance(mu: float) -> float:
        re = liquid_density * speed * 2.0 * radius / mu
        return 6.0 * math.pi * mu * radius * speed * wall * (1.0 + 0.15 * re**0.687) - net

    mu = brentq(imbalance, 1e-9, 1e6, xtol=1e-12, rtol=1e-10)
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
    wall = haberman_sayre(radius / bore_radius)
    net = 4.0 / 3.0 * math.pi * radius**3 * GRAVITY * (marble_density - liquid_density)

    def imbalance(speed: float) -> float:
        re = liquid_density * speed * 2.0 * radius / viscosity
        return 6.0 * math.pi * viscosity * radius * speed * wall * (1.0 + 0.15 * re**0.687) - net

    speed = brentq(imbalance, 0.0, 1e3, xtol=1e-12, rtol=1e-10)
    return speed, liquid_density * speed * 2.0 * radius / viscosity
