"""Liquids: a position-based-fluids solver in NVIDIA Warp, two-way coupled to MuJoCo.

The names below load on first use, so that ``pourbench.fluids.params`` (the liquid profiles)
imports without Warp.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

_HOME = {
    "SolverConfig": "config",
    "MujocoCoupling": "coupling",
    "LiquidMetrics": "metrics",
    "liquid_metrics": "metrics",
    "liquid_metrics_all": "metrics",
    "LiquidProfile": "params",
    "liquid_names": "params",
    "liquid_profile": "params",
    "load_liquids": "params",
    "PBFSolver": "solver",
}

__all__ = [
    "LiquidMetrics",
    "LiquidProfile",
    "MujocoCoupling",
    "PBFSolver",
    "SolverConfig",
    "liquid_metrics",
    "liquid_metrics_all",
    "liquid_names",
    "liquid_profile",
    "load_liquids",
]

if TYPE_CHECKING:
    from pourbench.fluids.config import SolverConfig
    from pourbench.fluids.coupling import MujocoCoupling
    from pourbench.fluids.metrics import LiquidMetrics, liquid_metrics, liquid_metrics_all
    from pourbench.fluids.params import LiquidProfile, liquid_names, liquid_profile, load_liquids
    from pourbench.fluids.solver import PBFSolver


def __getattr__(name: str) -> object:
    if name not in _HOME:
        raise AttributeError(f"module 'pourbench.fluids' has no attribute {name!r}")
    return getattr(importlib.import_module(f"pourbench.fluids.{_HOME[name]}"), name)
