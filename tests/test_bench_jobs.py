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
