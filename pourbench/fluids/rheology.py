"""Generalised-Newtonian rheology: the Herschel–Bulkley law and its closed forms.

A liquid profile with a yield stress τ_y, a consistency K and a flow index n
(``LiquidProfile.yield_stress_pa``, ``consistency_pa_sn``, ``flow_index``) has the shear stress

    τ = τ_y + K γ̇ⁿ  where it flows (τ > τ_y),  γ̇ = 0 where it does not,

(Herschel & Bulkley 1926): n = 1 and τ_y = 0 is a Newtonian liquid of viscosity K, τ_y > 0 and
n = 1 a Bingham plastic, n < 1 a shear-thinning liquid. The solver applies it as a viscosity
that depends on the local shear rate, regularised so that it stays finite where the liquid
does not flow (the bi-viscous form of :func:`apparent_viscosity`), by the implicit solve of
:mod:`pourbench.fluids.viscosity`, each particle's viscosity taken from the velocity field by
Picard passes (``SolverConfig.shear_passes``) toward the fixed point where viscosity and
velocity agree.

:func:`couette_inner_stress` is the closed form the solver is measured against: the stress on
the inner cylinder of a concentric-cylinder cell (a Couette rheometer) turning at Ω inside a
fixed outer one, for any such law, by quadrature of the rate over the gap. Written by hand:
it is a few lines of scipy, and no library states it for a yield-stress liquid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import quad
from scipy.optimize import brentq

from pourbench.errors import InvalidParameterError, check_finite, check_positive


@dataclass(frozen=True)
class HerschelBulkley:
    """A Herschel–Bulkley law (module docstring).

    Attributes:
        yield_stress_pa: τ_y, Pa (0: no yield).
        consistency_pa_sn: K, Pa·sⁿ.
        flow_index: n, dimensionless, in (0, 2].
    """

    yield_stress_pa: float
    consistency_pa_sn: float
    flow_index: float

    def __post_init__(self) -> None:
        check_finite("yield_stress_pa", self.yield_stress_pa, minimum=0.0)
        check_positive("consistency_pa_sn", self.consistency_pa_sn)
        n = check_positive("flow_index", self.flow_index)
        if n > 2.0:
            raise InvalidParameterError(f"flow_index must be in (0, 2], got {n!r}")

    def stress(self, rate: np.ndarray | float) -> np.ndarray:
        """τ(γ̇), Pa, of a flowing liquid at shear rate ``rate`` (1/s, ≥ 0)."""
        rate = np.asarray(rate, float)
        return self.yield_stress_pa + self.consistency_pa_sn * rate**self.flow_index

    def rate(self, stress: np.ndarray | float) -> np.ndarray:
        """γ̇(τ), 1/s: the inverse of :meth:`stress`, 0 at or below the yield stress."""
        excess = np.maximum(np.asarray(stress, float) - self.yield_stress_pa, 0.0)
        return (excess / self.consistency_pa_sn) ** (1.0 / self.flow_index)


def apparent_viscosity(
    law: HerschelBulkley, rate: np.ndarray | float, max_viscosity_pa_s: float
) -> np.ndarray:
    """τ(γ̇) / γ̇, Pa·s, capped at ``max_viscosity_pa_s`` (the bi-viscous regularisation: an
    unyielded region is a liquid of that viscosity, so it creeps at τ / max where the law
    has it still). The kernels evaluate the same expression per particle."""
    rate = np.maximum(np.asarray(rate, float), 1e-12)
    return np.minimum(law.stress(rate) / rate, max_viscosity_pa_s)


def couette_inner_stress(law: HerschelBulkley, omega: float, inner: float, outer: float) -> float:
    """The shear stress (Pa) on the inner cylinder (radius ``inner``, m) of a long
    concentric-cylinder cell turning at ``omega`` (rad/s) inside a fixed outer cylinder
    (radius ``outer``).

    The torque per length is the same through every cylindrical surface, so the stress falls
    as τ(r) = τ₁ (R₁ / r)²; the liquid's angular speed changes by γ̇(τ(r)) / r dr across
    each shell, and τ₁ is the root of ∫_{R₁}^{R₂} γ̇(τ₁ R₁² / r²) / r dr = Ω. Where τ(r)
    falls below the yield stress the liquid turns rigidly with the outer cylinder (the
    integrand is zero there). For a Newtonian law this is 2 μ Ω R₂² / (R₂² − R₁²).
    """
    omega = check_positive("omega", omega)
    if not 0.0 < inner < outer:
        raise InvalidParameterError(f"need 0 < inner < outer, got {inner!r}, {outer!r}")

    def turn(tau1: float) -> float:
        return quad(lambda r: float(law.rate(tau1 * (inner / r) ** 2)) / r, inner, outer)[0]

    low = law.yield_stress_pa
    high = max(2.0 * low, law.stress(2.0 * omega * outer**2 / (outer**2 - inner**2)) * 2.0)
    while turn(high) < omega:
        high *= 2.0
    return float(brentq(lambda t: turn(t) - omega, low, high, xtol=1e-10 * high))


def newtonian_rate(omega: float, inner: float, outer: float) -> float:
    """A Newtonian liquid's shear rate at the inner cylinder of the cell of
    :func:`couette_inner_stress`, 1/s: 2 Ω R₂² / (R₂² − R₁²)."""
    return 2.0 * omega * outer**2 / (outer**2 - inner**2)


def omega_for_rate(rate: float, inner: float, outer: float) -> float:
    """The inverse of :func:`newtonian_rate`, rad/s."""
    return rate * (outer**2 - inner**2) / (2.0 * outer**2)


def yield_tilt(law: HerschelBulkley, density: float, depth: float, gravity: float) -> float:
    """The tilt (rad) above which a layer ``depth`` (m) deep on a plane yields: the stress at
    its floor, ρ g h sin θ, reaches τ_y. π/2 when even a vertical wall holds it."""
    ratio = law.yield_stress_pa / (density * gravity * depth)
    return math.pi / 2 if ratio >= 1.0 else math.asin(ratio)
