"""Where a result came from: the command line, git SHA, machine and date of this run (the
leaderboard's stamp, and a training run's record of its sessions)."""

from __future__ import annotations

import os
import platform
import shlex
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path


def git_sha(source: str | Path = Path(__file__).parent) -> str:
    """Short SHA of HEAD of the git repository holding ``source`` (by default this package, so
    the answer does not depend on the current folder), with ``-dirty`` when that repository
    has uncommitted changes outside its top-level ``leaderboard/`` (so ``bench all`` stamps
    its later suites clean); ``"unknown"`` when ``source`` is in no repository or git is
    missing. For a copy of the source run elsewhere (a tree shipped to a GPU machine, say),
    ``$POURBENCH_GIT_SHA`` names the commit it was copied from and takes precedence."""
    if os.environ.get("POURBENCH_GIT_SHA"):
        return os.environ["POURBENCH_GIT_SHA"] + " (copied tree)"

    def git(*args: str, where: str | Path) -> str:
        return subprocess.run(
            ["git", "-C", str(where), *args], capture_output=True, text=True, check=True
        ).stdout.strip()

    try:
        root = git("rev-parse", "--show-toplevel", where=source)
        sha = git("rev-parse", "--short", "HEAD", where=root)
        # tables written by an earlier suite of this run don't count
        dirty = git(
            "status", "--porcelain", "--untracked-files=no", "--", ".", ":!leaderboard", where=root
        )
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


def load() -> str:
    """The machine's load averages over the last 1, 5 and 15 minutes beside its core count:
    above the core count, other processes shared the cores a timing ran on."""
    try:
        one, five, fifteen = os.getloadavg()
    except OSError:  # not every platform reports it
        return "unknown"
    return f"{one:.2f} / {five:.2f} / {fifteen:.2f} (1 / 5 / 15 min) on {os.cpu_count()} cores"


def provenance() -> dict[str, str]:
    """Command (shell-quoted: ``shlex.split`` gives back the arguments), git SHA, machine, its
    load and UTC date of this run."""
    return {
        "command": shlex.join(["pourbench", *sys.argv[1:]]),
        "git_sha": git_sha(),
        "machine": machine(),
        "load": load(),
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
    }
