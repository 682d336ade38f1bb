"""pourbench: MuJoCo + Warp liquid-pouring and assistive-teleoperation benchmark.

Subpackages, in import order: ``assets`` → ``scene`` → ``fluids`` → ``envs`` → ``agents``
→ ``bench``. ``planners`` and ``teleop`` are standalone libraries.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]
