"""The thesis' falling-ball viscosities redone with the wall and inertia corrections: the
corrections against their limits, and the profiles derived from them."""

from __future__ import annotations

import math

import pytest

from pourbench.errors import InvalidParameterError
from pourbench.fluids.falling_ball import (
    GRAVITY,
    MARBLE_DENSITY,
    MARBLE_RADIUS,
    haberman_sayre,
    marble_viscosity,
    startup_fall,
    terminal_speed,
)
from pourbench.fluids.params import liquid_profile


def test_wall_factor_limits() -> None:
    """No wall, no correction; a small sphere gains Ladenburg's first-order 2.1 λ; a sphere
    nearly filling the bore is held back without bound."""
    assert haberman_sayre(0.0) == 1.0
    lam = 0.01
    assert haberman_sayre(lam) - 1.0 == pytest.approx(2.105 * lam, rel=0.03)
    assert haberman_sayre(0.5) < haberman_sayre(0.6) < haberman_sayre(0.9)
    assert haberman_sayre(0.9) > 100


def test_slow_fall_in_a_wide_bore_is_stokes_law() -> None:
    """In a bore 1000 marbles wide and at Re ≪ 1 the viscosity is Stokes' 2/9 r² g Δρ / V."""
    speed, rho = 1e-4, 1000.0
    mu, re = marble_viscosity(speed, rho, bore_radius=1000 * MARBLE_RADIUS)
    stokes = 2 / 9 * MARBLE_RADIUS**2 * GRAVITY * (MARBLE_DENSITY - rho) / speed
    assert re < 1e-3
    assert mu == pytest.approx(stokes, rel=3e-3)


def test_the_thesis_honey_reads_as_a_real_honey() -> None:
    """Honey's marble speed (1.2 mm/s) with the corrections gives a viscosity in the range
    published for honeys at 20 °C (5–20 Pa·s), where the thesis' uncorrected Stokes law read
    0.30."""
    honey = liquid_profile("honey")
    mu, re = marble_viscosity(honey.marble_speed, honey.density)
    assert re < 0.01
    assert 5.0 <= mu <= 20.0
    assert honey.marble_viscosity_cp * 1e-3 < mu / 30


@pytest.mark.parametrize("name", ["dish soap", "hand soap", "hand-gel"])
def test_profiles_derived_from_the_marble(name: str) -> None:
    """The profiles without a published value take the corrected marble's, to three figures."""
    p = liquid_profile(name)
    mu, re = marble_viscosity(p.marble_speed, p.density)
    assert re < 10
    assert p.viscosity_pa_s == pytest.approx(mu, rel=2e-3)


@pytest.mark.parametrize("name", ["water", "apple juice", "rapeseed oil"])
def test_thin_liquids_are_beyond_the_marble(name: str) -> None:
    """In thin liquids the marble falls at Re in the hundreds or more: outside any Stokes-type
    law, so their profiles take published values instead."""
    p = liquid_profile(name)
    _, re = marble_viscosity(p.marble_speed, p.density)
    assert re > 300
    assert not math.isclose(p.viscosity_pa_s, marble_viscosity(p.marble_speed, p.density)[0])


@pytest.mark.parametrize("mu, rho", [(10.0, 1500.0), (0.3, 810.0), (0.001, 1000.0)])
def test_terminal_speed_inverts_the_viscosity(mu: float, rho: float) -> None:
    speed, re = terminal_speed(mu, rho)
    back, re_back = marble_viscosity(speed, rho)
    assert back == pytest.approx(mu, rel=1e-8) and re_back == pytest.approx(re, rel=1e-8)


@pytest.mark.filterwarnings("error")
def test_a_slow_sphere_starts_up_as_the_linear_drag_says() -> None:
    """At Re ≪ 1 the drag is linear, v(t) = V (1 − e^(−t/τ)) with τ = (m + m_a) / (6πμRK),
    and the fall until v = f V is V τ (−ln(1 − f) − f); the integrator's trial steps at a
    speed below zero meet a drag that opposes them (no warning, no complex power)."""
    radius, rho_s, rho, mu, bore = 0.015, 2500.0, 1000.0, 5000.0, 0.05
    speed, re = terminal_speed(mu, rho, radius, rho_s, bore)
    volume = 4 / 3 * math.pi * radius**3
    tau = (rho_s + 0.5 * rho) * volume / (6 * math.pi * mu * radius * haberman_sayre(radius / bore))
    assert re < 1e-6
    for f in (0.9, 0.98):
        closed = speed * tau * (-math.log(1 - f) - f)
        assert startup_fall(mu, rho, radius, rho_s, bore, fraction=f) == pytest.approx(
            closed, rel=1e-3
        )


def test_a_fast_sphere_needs_a_long_fall_to_reach_its_terminal_speed() -> None:
    """In 0.1 Pa·s (Re near 160) the settling sphere of ``validation.falling_ball`` needs
    more fall than its 14 cm column leaves it, in 5 Pa·s a few millimetres."""
    args = (1000.0, 0.015, 2500.0, 0.05)
    assert startup_fall(0.1, *args) > 0.09
    assert startup_fall(5.0, *args) < 0.005
    assert startup_fall(0.1, *args, fraction=0.9) < startup_fall(0.1, *args)


def test_a_start_up_fraction_outside_zero_to_one_is_refused() -> None:
    """The terminal speed is approached, never reached: a fraction of 1 or more has no fall."""
    with pytest.raises(InvalidParameterError, match="fraction"):
        startup_fall(1.0, 1000.0, fraction=1.0)
