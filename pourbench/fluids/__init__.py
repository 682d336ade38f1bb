"""Liquids: a position-based-fluids solver in NVIDIA Warp, two-way coupled to MuJoCo."""

from pourbench.fluids.params import LiquidProfile, liquid_names, liquid_profile, load_liquids

__all__ = ["LiquidProfile", "liquid_names", "liquid_profile", "load_liquids"]
