"""Liquids: a position-based-fluids solver in NVIDIA Warp, two-way coupled to MuJoCo."""

from pourbench.fluids.config import SolverConfig
from pourbench.fluids.coupling import MujocoCoupling
from pourbench.fluids.metrics import LiquidMetrics, liquid_metrics, liquid_metrics_all
from pourbench.fluids.params import LiquidProfile, liquid_names, liquid_profile, load_liquids
from pourbench.fluids.solver import PBFSolver
from pourbench.geometry.shapes import (
    BoxShell,
    ContainerShape,
    RevolvedShell,
    bottle,
    bowl,
    cup,
    tray,
)

__all__ = [
    "BoxShell",
    "ContainerShape",
    "LiquidMetrics",
    "LiquidProfile",
    "MujocoCoupling",
    "PBFSolver",
    "RevolvedShell",
    "SolverConfig",
    "bottle",
    "bowl",
    "cup",
    "liquid_metrics",
    "liquid_metrics_all",
    "liquid_names",
    "liquid_profile",
    "load_liquids",
    "tray",
]
