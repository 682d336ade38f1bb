"""Pour-v0 as an earlier commit of pourbench steps it, beside this code, for ``bench env``.

What a user gains from a change to the step is its speed against the code they had before,
on the same machine at the same time. :class:`PinnedPour` runs Pour-v0 from the source tree of
an earlier commit (``git archive`` of that commit into ``runs/pinned/<sha>``, made once) in
child interpreters whose ``sys.path`` starts with that tree, in this venv, and steps it on
request with the bench's pouring action, so that :func:`pourbench.bench.env.run_case` can
alternate it step by step with the current code.

The children talk through their standard streams: a ``step`` line makes each child step its
env once and answer with the seconds its step took. A vector case of ``worlds`` on
``workers`` processes runs as that many children of ``worlds / workers`` worlds each (the
pinned vector env may have no workers of its own), stepped together; its step time is the
slowest child's. A child speaks only through Gymnasium's API and ``pourbench.register_envs``,
so any commit that registers ``pourbench/Pour-v0`` can be pinned.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from pourbench.errors import InvalidParameterError

PINNED_SHA = "f8f94b4"
"""The default pinned commit: the last before the batched step."""

PINNED_ROOT = Path("runs") / "pinned"

CHILD = r"""
import json, sys, time
import numpy as np
import gymnasium as gym
import pourbench

pourbench.register_envs()
front_end, worlds, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
if front_end == "single":
    env = gym.make("pourbench/Pour-v0").unwrapped
    action = np.array([0.5, 1.0], np.float32)
else:
    env = gym.make_vec(
        "pourbench/Pour-v0", num_envs=worlds, vectorization_mode="vector_entry_point"
    )
    action = np.tile(np.array([0.5, 1.0], np.float32), (worlds, 1))
env.reset(seed=seed)


def step():
    t0 = time.perf_counter()
    _, _, terminated, truncated, _ = env.step(action)
    if front_end == "single" and (terminated or truncated):
        env.reset()
    return time.perf_counter() - t0


for _ in range(2):
    step()
print(json.dumps({"ready": pourbench.__file__}), flush=True)
for line in sys.stdin:
    if line.strip() != "step":
        break
    print(json.dumps({"seconds": step()}), flush=True)
env.close()
"""


def resolve_commit(sha: str, repo: Path) -> str:
    """The full SHA of ``sha`` in the git repository at ``repo``; refused when ``repo`` is
    no git checkout or has no such commit."""
    try:
        out = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "--verify", "--quiet", f"{sha}^{{commit}}"],
            capture_output=True,
            text=True,
        )
    except OSError as exc:
        raise InvalidParameterError(f"--against {sha}: git is not available ({exc})") from None
    if out.returncode != 0:
        raise InvalidParameterError(
            f"--against {sha}: no such commit in {repo} (a pinned comparison needs the "
            "project's git checkout; give --against none to leave it out)"
        )
    return out.stdout.strip()


def source_tree(sha: str, repo: Path, root: Path = PINNED_ROOT) -> Path:
    """The source tree of commit ``sha`` of ``repo`` under ``root`` (extracted once)."""
    full = resolve_commit(sha, repo)
    tree = root / full
    if (tree / "pourbench" / "__init__.py").is_file():
        return tree
    root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root) as tmp:
        archive = Path(tmp) / "tree.tar"
        subprocess.run(
            ["git", "-C", str(repo), "archive", "--format=tar", "-o", str(archive), full],
            check=True,
        )
        with tarfile.open(archive) as tar:
            tar.extractall(Path(tmp) / "tree", filter="data")
        os.replace(Path(tmp) / "tree", tree)
    return tree


class PinnedPour:
    """Pour-v0 of the source ``tree`` in ``workers`` child processes: ``front_end`` "single"
    (one world, ``workers`` 1) or "vector" (``worlds`` split evenly over the children, child
    k's first world reset with seed k × worlds / workers, so that the worlds' seeds are 0, 1,
    … as in the case's own vector env). :meth:`step` steps every child once; close it when
    done."""

    def __init__(self, tree: Path, front_end: str, worlds: int, workers: int = 1) -> None:
        if front_end == "single" and (worlds, workers) != (1, 1):
            raise InvalidParameterError("a pinned single env has one world in one process")
        if worlds % workers:
            raise InvalidParameterError(f"{worlds} worlds do not split over {workers} workers")
        env = {**os.environ, "PYTHONPATH": str(tree.resolve())}
        each = worlds // workers
        self.children = [
            subprocess.Popen(
                [sys.executable, "-c", CHILD, front_end, str(each), str(k * each)],
                cwd=tree,
                env=env,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
            )
            for k in range(workers)
        ]
        for child in self.children:
            where = self._answer(child)["ready"]
            if not Path(where).resolve().is_relative_to(tree.resolve()):
                self.close()
                raise RuntimeError(f"the pinned child imported pourbench from {where}")

    def _answer(self, child: subprocess.Popen) -> dict:
        line = child.stdout.readline() if child.stdout else ""
        if not line:
            self.close()
            raise RuntimeError(f"a pinned Pour-v0 child ended (exit {child.wait()})")
        return json.loads(line)

    def step(self) -> float:
        """Step every child's env once (together); the slowest child's seconds."""
        for child in self.children:
            assert child.stdin is not None
            child.stdin.write("step\n")
            child.stdin.flush()
        return max(self._answer(child)["seconds"] for child in self.children)

    def close(self) -> None:
        for child in self.children:
            if child.poll() is None:
                try:
                    if child.stdin:
                        child.stdin.close()
                    child.wait(timeout=60)
                except (OSError, subprocess.TimeoutExpired):
                    child.kill()
                    child.wait()
