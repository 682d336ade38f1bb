"""``pourbench bench transfer``: the episodes it runs, its resume log and its table."""

from __future__ import annotations

import argparse
import json

import pytest

from pourbench.bench import transfer
from pourbench.bench._jobs import job_key


def test_the_table_sets_each_robot_beside_pour_v0_and_the_thesis() -> None:
    results = {}
    for seed, (pour, movo, panda) in enumerate([(2.0, 5.0, 3.0), (4.0, 9.0, 1.0)]):
        for env, err in (("pour", pour), ("movo", movo), ("panda", panda)):
            results[(env, "honey", 100.0, seed)] = {
                "error_g": err,
                "collided": env == "movo" and seed == 1,
                "planner_failed": False,
                "sim_diverged": False,
            }
    (row,) = transfer.table(results, ("honey",), (100.0,), 2)
    assert row["thesis_movo_g"] == 8.66  # Table 6.4, honey at 100 g
    assert (row["pour_v0_g"], row["movo_g"], row["panda_g"]) == (3.0, 7.0, 2.0)
    assert (row["gap_movo_g"], row["gap_panda_g"]) == (4.0, -1.0)
    assert (row["movo_flags"], row["panda_flags"]) == ("collided 1", "")


def test_a_stopped_run_resumes_from_its_log(tmp_path, monkeypatch) -> None:
    """Episodes logged under this SHA and policy are taken from the log; only the rest run,
    and each is appended as it finishes."""
    log = tmp_path / "episodes.jsonl"
    sha = transfer.git_sha()
    first = ("pour", "water", 50.0, 0)
    log.write_text(
        json.dumps({"key": job_key(sha, ("pd", *first)), "result": {"error_g": 1.5}}) + "\n"
    )
    ran = []

    def fake_episode(policy, env, liquid, target, seed):
        ran.append((env, liquid, target, seed))
        return {"error_g": 2.0}

    monkeypatch.setattr(transfer, "episode", fake_episode)
    results = transfer.run_episodes(("water",), (50.0,), 1, "pd", log, sha)
    assert ran == [("movo", "water", 50.0, 0), ("panda", "water", 50.0, 0)]
    assert results[first] == {"error_g": 1.5}
    assert len(log.read_text().splitlines()) == 3
    ran.clear()
    transfer.run_episodes(("water",), (50.0,), 1, "pd", log, "another commit")
    assert len(ran) == 3  # another commit's code runs every episode again
    ran.clear()
    transfer.run_episodes(("water",), (50.0,), 1, "pd", log, sha)
    assert ran == []


@pytest.mark.slow
def test_quick_transfer_pours_water_on_both_robots(tmp_path, monkeypatch) -> None:
    """The quick variant: 100 g of water by the PD baseline on Pour-v0, the Movo and the
    Panda, each within 10 g and unflagged, written to a table."""
    monkeypatch.chdir(tmp_path)
    args = argparse.Namespace(quick=True, no_write=False, out=str(tmp_path), json=False)
    assert transfer.run(args) == 0
    data = json.loads((tmp_path / "transfer.json").read_text())
    (row,) = data["rows"]
    assert row["thesis_movo_g"] == 3.55
    for env in ("pour_v0_g", "movo_g", "panda_g"):
        assert row[env] <= 10.0, row
    assert row["movo_flags"] == row["panda_flags"] == ""
