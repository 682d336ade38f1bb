"""The planning benchmark's task set and its JSON output."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from pourbench.bench import planning
from pourbench.planners.distance import capsule_obstacle_distances
from pourbench.planners.robots import arm_kinematics


def test_task_set_matches_the_issue():
    movo = {t.key: t for t in planning.make_tasks("movo")}
    panda = {t.key: t for t in planning.make_tasks("panda")}
    assert set(movo) == {"i", "ii", "iii", "iv", "v"}
    assert set(panda) == {"i", "ii", "iii", "iv"}
    assert (movo["i"].ph, movo["i"].ch) == (1, 1)
    assert len(movo["ii"].goals) == 6
    assert movo["v"].dual is not None
    assert [t.key for t in planning.make_tasks("movo", quick=True)] == ["iii"]
    assert set(planning.OFFLINE) <= set(movo["iii"].planners)


@pytest.mark.parametrize("robot", ["movo", "panda"])
def test_task_iii_box_blocks_the_straight_line(robot):
    """The box of task (iii) lies across the straight end-effector line to the goal."""
    task = next(t for t in planning.make_tasks(robot) if t.key == "iii")
    kin = arm_kinematics(task.arm)
    p0 = kin.ee_pose(kin.home())[0]
    goal = task.goals[0][0]
    box = task.obstacles(0.0)[0]
    sd = capsule_obstacle_distances(p0[None, None], goal[None, None], np.zeros(1), [box]).sd
    assert sd.min() < 0.0


@pytest.mark.slow
def test_quick_benchmark_json(capsys, tmp_path):
    args = argparse.Namespace(quick=True, json=True, out=str(tmp_path), no_write=False)
    assert planning.run(args) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = doc["rows"]
    assert {r["planner"] for r in rows} == set(planning.ONLINE) | set(planning.OFFLINE)
    for r in rows:
        for key in ("robot", "task", "planner", "success_rate", "avg_time_s",
                    "avg_normalized_length", "min_clearance_m", "collisions"):  # fmt: skip
            assert key in r
    nmpc = next(r for r in rows if r["planner"] == "NMPC-MP (GN)")
    assert nmpc["collisions"] == 0
    assert (tmp_path / "planning.md").exists() and (tmp_path / "planning.json").exists()


@pytest.mark.parametrize("robot", ["movo", "panda"])
def test_task_iv_keeps_clearance_on_the_real_robots(robot):
    """Task (iv) as benchmarked (NMPC-MP, Gauss-Newton): MuJoCo clearance at 4 sub-steps per
    control step never drops more than 5 mm below the 5 cm safety distance, nothing collides,
    and (Panda) no joint leaves its limits."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
    task = next(t for t in planning.make_tasks(robot) if t.key == "iv")
    res = planning._run_online(task, "NMPC-MP (GN)")
    assert res["min_clearance_m"] >= planning.SAFETY_DYNAMIC - 0.005
    assert res["collisions"] == 0
    assert res["joint_limit_violation_rad"] == 0.0
    # The sphere really came close (within 2 cm of the safety distance).
    assert res["min_clearance_m"] < planning.SAFETY_DYNAMIC + 0.02
