"""Agents for the pouring environments: the PD baseline (and the SB3 adapter in
:mod:`pourbench.agents.sb3`, imported on demand)."""

from __future__ import annotations

from pourbench.agents.pd import PDConfig, PDPourer

__all__ = ["PDConfig", "PDPourer"]
