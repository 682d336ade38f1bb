"""Training curves of a ``pourbench train`` run as one PNG (matplotlib, no display needed).

Reads every ``logs/<session>/progress.csv`` of a run (one per training session: a resumed
run adds one) and plots, against environment steps, whichever of these it logged: episode
reward and length, pouring error, success rate, intrinsic reward, lesson, evaluation error.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

PANELS: tuple[tuple[str, str], ...] = (
    ("rollout/ep_rew_mean", "episode reward (extrinsic)"),
    ("rollout/ep_len_mean", "episode length, steps"),
    ("pour/error_g", "pouring error, g"),
    ("pour/average_error_g", "running average error, g"),
    ("rollout/success_rate", "success rate"),
    ("icm/intrinsic_reward", "intrinsic reward per step"),
    ("curriculum/lesson", "curriculum lesson"),
    ("eval/mean_abs_error_g", "evaluation mean abs error, g"),
)
STEP = "time/total_timesteps"


def read_progress(paths: Sequence[str | Path]) -> dict[str, list[tuple[float, float]]]:
    """Each logged key's ``(steps, value)`` points from SB3 ``progress.csv`` files, in order
    of steps (empty cells skipped)."""
    series: dict[str, list[tuple[float, float]]] = {}
    for path in paths:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                try:
                    step = float(row.get(STEP) or "nan")
                except ValueError:
                    continue
                if math.isnan(step):
                    continue
                for key, text in row.items():
                    if key == STEP or not text:
                        continue
                    try:
                        series.setdefault(key, []).append((step, float(text)))
                    except ValueError:
                        pass
    return {k: sorted(v) for k, v in series.items()}


def plot_training(run_dir: str | Path) -> Path:
    """Write the run's training curves to ``<run_dir>/training.png``.

    Raises:
        FileNotFoundError: the run has no ``logs/*/progress.csv``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run = Path(run_dir)
    paths = sorted(run.glob("logs/*/progress.csv"), key=lambda p: _session(p.parent.name))
    if not paths:
        raise FileNotFoundError(f"no logs/*/progress.csv in {str(run)!r}")
    series = read_progress(paths)
    panels = [(k, t) for k, t in PANELS if series.get(k)] or [(k, k) for k in sorted(series)][:1]
    cols = 2
    rows = max(1, math.ceil(len(panels) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(10, 2.6 * rows), squeeze=False)
    for ax, (key, title) in zip(axes.flat, panels, strict=False):
        pts = series.get(key, [])
        if pts:
            xs, ys = zip(*pts, strict=True)
            ax.plot(xs, ys, marker="." if len(pts) < 30 else None)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("environment steps", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels) :]:
        ax.axis("off")
    fig.suptitle(f"training: {run.name}", fontsize=10)
    fig.tight_layout()
    out = run / "training.png"
    partial = out.with_name(out.stem + ".partial.png")
    fig.savefig(partial, dpi=100)
    plt.close(fig)
    partial.replace(out)
    return out


def _session(name: str) -> int:
    return int(name) if name.isdigit() else -1
