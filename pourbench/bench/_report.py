"""Leaderboard writing shared by every benchmark suite.

Each suite produces rows (dicts of plain values) and hands them to :func:`write_report`,
which writes ``<out>/<suite>.json`` and ``<out>/<suite>.md`` stamped with the command line,
git SHA and machine, so every committed number says where it came from.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any


def git_sha() -> str:
    """Short SHA of HEAD, with ``-dirty`` when the tree has uncommitted changes outside
    ``leaderboard/`` (so ``bench all`` stamps its later suites clean). For a copy of
    the source run elsewhere (a tree shipped to a GPU machine, say), ``$POURBENCH_GIT_SHA``
    names the commit it was copied from and takes precedence."""
    if os.environ.get("POURBENCH_GIT_SHA"):
        return os.environ["POURBENCH_GIT_SHA"] + " (copied tree)"
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(  # tables written by an earlier suite of this run don't count
            ["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":!leaderboard"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def machine() -> str:
    """One line describing this machine: CPU model, core count, OS, Python."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (
        f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, "
        f"Python {platform.python_version()}"
    )


def provenance() -> dict[str, str]:
    """Command, git SHA, machine and UTC date of this run."""
    return {
        "command": "pourbench " + " ".join(sys.argv[1:]),
        "git_sha": git_sha(),
        "machine": machine(),
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
    }


def devices(choice: str, quick: bool = False) -> list[str]:
    """The devices a suite times for ``--device``: ``auto`` is the CPU plus CUDA when Warp sees
    a device (not in a quick run), ``cpu`` / ``cuda`` that device alone."""
    if choice in ("cpu", "cuda"):
        return [choice]
    from pourbench.fluids.solver import cuda_available

    return ["cpu"] + (["cuda"] if not quick and cuda_available() else [])


def report_stem(suite: str, choice: str) -> str:
    """Leaderboard file stem: a CUDA-only run writes ``<suite>_cuda`` beside the CPU table."""
    return f"{suite}_cuda" if choice == "cuda" else suite


def accelerator(rows: Sequence[dict[str, Any]]) -> str | None:
    """Name of the CUDA device, when any row ran on one."""
    if not any(r.get("device") == "cuda" for r in rows):
        return None
    import warp as wp

    dev = wp.get_device("cuda")
    return f"{dev.name} (sm_{dev.arch}), Warp {wp.config.version}"


def markdown_table(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """A GitHub markdown table of ``rows`` restricted to ``columns``."""

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return "–" if v is None else str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def write_report(
    suite: str,
    rows: Sequence[dict[str, Any]],
    *,
    out: str | Path = "leaderboard",
    title: str,
    body_md: str,
    extra: dict[str, Any] | None = None,
) -> tuple[Path, Path]:
    """Write ``<out>/<suite>.json`` (rows + provenance) and ``<out>/<suite>.md``.

    Args:
        suite: file stem, e.g. ``"fluids"``.
        rows: one dict per measured case.
        out: folder to write into (created if missing).
        title: markdown heading.
        body_md: the suite's tables and notes in markdown (provenance is added here).
        extra: more top-level JSON fields.
    """
    from pourbench.outputs import check_output_folder, write_text_atomic

    out = check_output_folder(out)
    prov = provenance()
    gpu = accelerator(rows)
    if gpu:
        prov["accelerator"] = gpu
    doc = {"suite": suite, **prov, **(extra or {}), "rows": list(rows)}
    json_path = out / f"{suite}.json"
    write_text_atomic(json_path, json.dumps(doc, indent=2) + "\n")
    md = [
        f"# {title}",
        "",
        f"- command: `{prov['command']}`",
        f"- git SHA: `{prov['git_sha']}`",
        f"- machine: {prov['machine']}",
        *([f"- accelerator: {gpu}"] if gpu else []),
        f"- date: {prov['date']}",
        "",
        body_md.strip(),
        "",
    ]
    md_path = out / f"{suite}.md"
    write_text_atomic(md_path, "\n".join(md))
    return json_path, md_path
