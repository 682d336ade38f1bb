"""Evaluation episodes as independent jobs, run once each and logged; shared by ``bench
pouring`` and ``bench transfer``.

A job is a tuple of plain values, and its result depends on nothing else: it pours in a
fresh env of its own, with seeds it names. So a job may run anywhere (in this process, in one
process per core, or on Ray workers with ``--ray``) and the tables come out the same.
Each result is appended as it finishes to a JSON-lines log, keyed by the git SHA at the
start, so a run that stops resumes where it was (a line it was writing when it stopped is
dropped, and that job runs again).

Ray is optional (the ``ray`` extra). ``ray_address="local"`` starts a Ray on this machine's
cores for the run; any other address joins that cluster, whose workers must have this
project installed at the same commit (docs/ray.md).
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from tqdm import tqdm

from pourbench.errors import PourbenchError

Job = tuple[Any, ...]

RAY_INSTALL = "pip install 'pourbench[ray]'"


def job_key(sha: str, job: Job) -> str:
    """The log's key of ``job`` run by the code at git SHA ``sha``."""
    return json.dumps([sha, *job])


def load_log(path: Path) -> tuple[dict[str, dict], int]:
    """The results logged in ``path`` by key (empty when there is no log yet), and the size in
    bytes of the log's complete lines. A last line that does not parse or has no newline (a
    run stopped while writing it) is left out, with a warning on stderr; its job runs again.

    Raises:
        PourbenchError: a line before the last one does not parse.
    """
    if not path.is_file():
        return {}, 0
    lines = path.read_bytes().splitlines(keepends=True)
    last = max((i for i, line in enumerate(lines) if line.strip()), default=-1)
    done: dict[str, dict] = {}
    size = 0
    for i, line in enumerate(lines):
        try:
            if line.strip():  # only the last line can lack its newline
                entry = json.loads(line if line.endswith(b"\n") else b"")
                done[entry["key"]] = entry["result"]
        except (ValueError, KeyError, TypeError) as exc:
            if i < last:
                raise PourbenchError(
                    f"{path}, line {i + 1}, is not a logged result ({exc}); delete that "
                    "line (its job runs again)"
                ) from exc
            print(
                f"warning: {path}: ignoring its incomplete last line (a run stopped while "
                "writing it); that job runs again",
                file=sys.stderr,
            )
            break
        size += len(line)
    return done, size


def import_ray() -> Any:
    """The ``ray`` module, or an error that says how to install it."""
    try:
        import ray
    except ImportError as exc:
        raise PourbenchError(f"Ray is not installed: {RAY_INSTALL}") from exc
    return ray


def init_ray(address: str) -> bool:
    """Connect to Ray: ``"local"`` starts one on this machine, anything else joins the
    cluster at that address. True when this call started or joined it (so the caller shuts it
    down), False when this process was already connected."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING"}
    if address != "local":
        kwargs["address"] = address
    ray.init(**kwargs)
    return True


def _ray_results(fn: Callable[..., dict], todo: list[Job], address: str) -> Iterator[tuple]:
    ray = import_ray()
    started = init_ray(address)
    try:
        remote = ray.remote(num_cpus=1)(fn)
        refs = {remote.remote(*job): job for job in todo}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield refs[ref], ray.get(ref)
    finally:
        if started:
            ray.shutdown()


def flag_counts(episodes: list[dict], flags: tuple[str, ...]) -> str:
    """How many ``episodes`` ended on each of ``flags``, e.g. "collided 2" ("" when none did)."""
    counts = {k: sum(e[k] for e in episodes) for k in flags}
    return ", ".join(f"{k} {v}" for k, v in counts.items() if v)


def _call(fn: Callable[..., dict], job: Job) -> tuple[Job, dict]:
    return job, fn(*job)


def run_jobs(
    fn: Callable[..., dict],
    jobs: list[Job],
    log: Path,
    sha: str,
    desc: str,
    workers: int = 1,
    ray_address: str | None = None,
) -> dict[Job, dict]:
    """``fn(*job)`` for every job: from ``log`` where the code at git SHA ``sha`` ran it
    already, otherwise run (with a progress bar named ``desc``) and appended to it. The rest
    run in this process (``workers`` 1), over ``workers`` fresh processes, or as Ray tasks
    (``ray_address``, one CPU each). ``fn`` is a module-level function, so that other
    processes can import it."""
    done, complete = load_log(log)
    results = {j: done[job_key(sha, j)] for j in jobs if job_key(sha, j) in done}
    todo = [j for j in jobs if j not in results]
    if results:
        print(f"{desc}: {len(results)} from {log}", file=sys.stderr)
    log.parent.mkdir(parents=True, exist_ok=True)
    bar = tqdm(total=len(todo), desc=desc, file=sys.stderr)
    with log.open("a") as f:
        f.truncate(complete)  # an incomplete last line goes: the next result starts a line
        if ray_address is not None and todo:
            finished: Iterator[tuple] = _ray_results(fn, todo, ray_address)
        elif workers <= 1 or len(todo) <= 1:
            finished = (_call(fn, job) for job in todo)
        else:
            finished = _pool_results(fn, todo, workers)
        for job, result in finished:
            results[job] = result
            f.write(json.dumps({"key": job_key(sha, job), "result": result}) + "\n")
            f.flush()
            bar.update()
    bar.close()
    return results


def _leave_with_parent(parent: int) -> None:
    """A pool worker's initializer: the worker exits within a second of the process that
    started it. A parent killed by a signal cannot shut its pool down, and its workers would
    go on with the jobs already queued to them, then wait for more forever."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _pool_results(fn: Callable[..., dict], todo: list[Job], workers: int) -> Iterator[tuple]:
    context = get_context("spawn")  # fresh interpreters: no forked Warp or torch state
    with ProcessPoolExecutor(
        min(workers, len(todo)),
        mp_context=context,
        initializer=_leave_with_parent,
        initargs=(os.getpid(),),
    ) as pool:
        for future in as_completed([pool.submit(_call, fn, j) for j in todo]):
            yield future.result()
