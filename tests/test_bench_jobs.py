"""The job log of ``bench pouring`` and ``bench transfer``: a stopped run resumes from it."""

from __future__ import annotations

import json

import pytest

from pourbench.bench._jobs import job_key, run_jobs
from pourbench.errors import PourbenchError


def _line(job: tuple) -> str:
    return json.dumps({"key": job_key("sha", job), "result": {"value": job[0]}}) + "\n"


def test_a_run_killed_while_logging_resumes(tmp_path, capsys) -> None:
    """A log whose last line was cut short (its run was killed while writing it): the two
    complete results are resumed, the third job runs again, with a warning, and the log is
    whole again for the next run."""
    log = tmp_path / "jobs.jsonl"
    jobs = [(1,), (2,), (3,)]
    log.write_text(_line(jobs[0]) + _line(jobs[1]) + _line(jobs[2])[:20])
    ran = []

    def fn(value):
        ran.append(value)
        return {"value": value}

    results = run_jobs(fn, jobs, log, "sha", "jobs")
    assert ran == [3]
    assert results == {j: {"value": j[0]} for j in jobs}
    assert "incomplete last line" in capsys.readouterr().err
    assert log.read_text() == "".join(_line(j) for j in jobs)
    assert run_jobs(fn, jobs, log, "sha", "jobs") == results and ran == [3]


def test_a_log_broken_before_its_last_line_is_a_clear_error(tmp_path) -> None:
    log = tmp_path / "jobs.jsonl"
    text = _line((1,)) + "{not json\n" + _line((2,))
    log.write_text(text)
    with pytest.raises(PourbenchError, match="line 2"):
        run_jobs(lambda v: {"value": v}, [(1,), (2,), (3,)], log, "sha", "jobs")
    assert log.read_text() == text


def test_pool_workers_leave_when_their_parent_is_killed(tmp_path) -> None:
    """A bench killed by SIGTERM (a scheduler, ``kill``) leaves no worker behind: each
    exits within seconds, where it would have slept through its minute-long job."""
    import os
    import signal
    import subprocess
    import sys
    import time

    (tmp_path / "napping.py").write_text(
        "import os, pathlib, time\n"
        "def nap(k):\n"
        f"    pathlib.Path({str(tmp_path)!r}, f'worker-{{os.getpid()}}').touch()\n"
        "    time.sleep(60)\n"
        "    return {}\n"
    )
    script = (
        "from pathlib import Path\n"
        "from napping import nap\n"
        "from pourbench.bench._jobs import run_jobs\n"
        f"run_jobs(nap, [(k,) for k in range(4)], Path({str(tmp_path)!r}) / 'log', 'sha',"
        " 'naps', workers=2)\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    bench = subprocess.Popen([sys.executable, "-c", script], env=env, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while len(list(tmp_path.glob("worker-*"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    workers = [int(p.name.split("-")[1]) for p in tmp_path.glob("worker-*")]
    assert len(workers) == 2
    bench.send_signal(signal.SIGTERM)
    bench.wait(timeout=30)

    def alive(pid: int) -> bool:
        try:
            state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
        except FileNotFoundError:
            return False
        return state != "Z"  # a zombie has exited; nothing may reap it here

    deadline = time.monotonic() + 10
    while any(alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(alive(pid) for pid in workers)
