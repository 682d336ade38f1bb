"""Agents for the pouring environments: the PD baseline, :func:`load_policy` (a policy by name
or path), and, imported on demand, the SB3 adapter (:mod:`pourbench.agents.sb3`), the
curiosity module (:mod:`~pourbench.agents.icm`), the curriculum schedule
(:mod:`~pourbench.agents.schedule`) and training (:mod:`~pourbench.agents.train`)."""

from __future__ import annotations

from pourbench.agents.loading import load_policy
from pourbench.agents.pd import PDConfig, PDPourer

__all__ = ["PDConfig", "PDPourer", "load_policy"]
