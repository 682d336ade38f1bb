"""The stamp every leaderboard table and training session carries: which code, which command."""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

from pourbench.provenance import git_sha, provenance

GIT = ["git", "-c", "user.name=t", "-c", "user.email=t@t"]


def _repo(folder: Path) -> None:
    """A fresh git repository in ``folder`` with one commit of ``code.py`` and a table."""
    (folder / "leaderboard").mkdir(parents=True)
    (folder / "leaderboard" / "fluids.md").write_text("old\n")
    (folder / "code.py").write_text("x = 1\n")
    for args in (["init", "-q"], ["add", "."], ["commit", "-qm", "init"]):
        subprocess.run([*GIT, "-C", str(folder), *args], check=True)


def test_the_sha_does_not_depend_on_the_current_folder(tmp_path, monkeypatch) -> None:
    """The SHA and dirty flag are those of the repository holding pourbench, run from a
    subfolder of it, from a folder outside any repository or from another repository."""
    monkeypatch.delenv("POURBENCH_GIT_SHA", raising=False)
    here = git_sha()
    assert here != "unknown"
    other = tmp_path / "other"
    _repo(other)
    for cwd in (Path(__file__).parent, tmp_path, other):
        monkeypatch.chdir(cwd)
        assert git_sha() == here, f"from {cwd}"


def test_the_dirty_flag_covers_the_whole_repository(tmp_path, monkeypatch) -> None:
    """Asked about a subfolder, the flag still covers every tracked file of the repository
    but its top-level ``leaderboard/``."""
    monkeypatch.delenv("POURBENCH_GIT_SHA", raising=False)
    repo, pkg = tmp_path / "repo", tmp_path / "repo" / "pkg"
    _repo(repo)
    pkg.mkdir()
    (repo / "leaderboard" / "fluids.md").write_text("new\n")
    assert not git_sha(pkg).endswith("-dirty")
    (repo / "code.py").write_text("x = 2\n")
    assert git_sha(pkg).endswith("-dirty")
    assert git_sha(pkg) == git_sha(repo)
    assert git_sha(tmp_path) == "unknown"  # in no repository


def test_the_command_is_shell_quoted(monkeypatch) -> None:
    """The stamped command splits back into the arguments it was run with."""
    argv = ["bench", "all", "--out", "my tables", "--note=it's", ""]
    monkeypatch.setattr(sys, "argv", ["/venv/bin/pourbench", *argv])
    assert shlex.split(provenance()["command"]) == ["pourbench", *argv]
