"""Functions that tests run inside a vector env's worker through ``call_world``: they are
module-level so that they pickle by reference (a worker imports this module)."""

from __future__ import annotations

import numpy as np


def poison(batch, world: int, count: int = 5) -> None:
    """Put NaN into ``count`` particle positions of ``world``."""
    solver = batch.solver
    x = solver.positions()
    x[solver.world_slice(world)][:count] = np.nan
    solver.buf.x.assign(x.astype(np.float32))


def world_steps(batch, world: int) -> int:
    """Environment steps of ``world``'s episode."""
    return int(batch.steps[world])


def positions(batch, world: int) -> np.ndarray:
    """``world``'s particle positions."""
    return batch.solver.positions()[batch.solver.world_slice(world)]


def largest_capacity_per_density(batch, world: int) -> float:
    """Grams per kg/m³ of density that the largest of the batch's pouring containers holds."""
    return max(batch.capacity_g(c, 1.0) for c in batch.candidates)


def liquid_name(batch, world: int) -> str:
    """The liquid of ``world``'s episode."""
    return batch.worlds[world].liquid.name
