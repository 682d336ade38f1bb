"""``pourbench bench teleop``: Skill-CPD under network drops (thesis Tables 5.1 and 5.2).

Protocol. 2-D letters: every letter's skill is learnt from 10 generated demonstrations
(:mod:`pourbench.teleop.demos`) by an HSMM of ``LETTER_STATES`` (20) states, where the
thesis used 5. The simulated operator is one of two:

* ``held-out demo``: a demonstration never used in training (indices 10, 11, 12 for the 3
  repetitions), with its own spatial and timing variability;
* ``skill replay``: the learnt skill's own LQT trajectory traversed at constant speed, as
  the thesis' simulation appears to have done (its Skill-CPD RMSE of 0.001 cm implies an
  operator that the skill matches exactly). One repetition (only the outage differs
  between repetitions of a replay).

Recognition uses :meth:`~pourbench.teleop.skills.SkillLibrary.recognize` with the shape
recognizer (``RECOGNIZER``, our addition: the operator's step directions against each skill's
mean path, :mod:`pourbench.teleop.shape`; the thesis scores with the HSMMs) and
``invariant=True`` (rotations up to 45° and scales up to 1.5 searched, so that the rotated
and scaled operators below are recognised). Its confidence is calibrated
(:meth:`~pourbench.teleop.skills.SkillLibrary.calibrate`) on held-out demonstrations that
are never operators: per letter demonstrations 20-22, copied under the identical, ±30° and x1.3
/ x1/1.3 variations (a translation changes no direction); per feeding target demonstrations
10-12. Skill-CPD and standard SA switch only when it is >= λ_minconf (0.9 letters, 0.8
feeding) at the deadline.

Letters outside the library: a second library learns the 21 letters other than
``UNKNOWN_LETTERS`` (B, D, O, U, Z) and is calibrated the same way. Its 5 unknown letters
(class ``letter not in library``, as many repetitions as above) and its 21 own letters (class
``letter in library``, one repetition) are replayed like the others, after them (so the
earlier rows keep their outages). The report gives their switch rates and displacement, and
``teleop_confidence.png`` beside the tables shows the histograms of their confidence at the
deadline. In full mode the gate is also measured on other sets of letters left out of a
library (``GATE_SETS``, each letter confused with letters of the rest), with the Skill-CPD
arbitration alone and the same variations and repetitions.

Every arbitration mode takes over and hands back the same way: the robot's offset from the
skill at the switch fades over 10 packets (``takeover_step`` 0.1) and the hand-back closes the
skill-operator gap at no more than 3 cm/s (``handback_speed``), where the thesis jumps onto
the skill and ramps alpha over 10 packets whatever the gap (docs/teleop.md).

The operator's trajectory is transformed by one of 8 variations about the
letter's centre (identical; shifted +10 cm x, -10 cm x, +10 cm y; rotated ±30°; scaled
x1.3 and x1/1.3). One outage per run starts uniformly between 40 % and 60 % of the task and
lasts 0.5-5 s. 3-D feeding: 3 targets x 3 held-out repetitions x (±15 cm along x), 5 demos
per target. Each run is replayed with the three arbitration modes of
:mod:`pourbench.teleop.skill_cpd` on the same operator trajectory and outage.

Metrics (cm, the thesis' unit):

* ``max_displacement_cm``: the largest distance between consecutive points of the robot's
  trajectory after the Δd sampling rule (the thesis' "maximum displacement"; a trajectory
  without any jump still scores about Δd plus one packet's motion, reported as
  ``human_max_step_cm`` for the operator's own trajectory);
* ``switch_jump_cm``: the largest per-packet (33 ms) motion of the robot from the drop to
  the end of the hand-back, raw (no Δd sampling); ``takeover_jump_cm`` (first 3 packets of
  the outage) and ``handback_jump_cm`` (first packet back to the end of the hand-back)
  split it;
* ``rmse_cm``: RMS over all packet times of the distance between the robot and the
  operator's true (undelivered during the outage) position;
* recognition accuracy at the deadline (``recognised``), the runs that switched to the right
  skill (``switched_right``), the letters recognised as another one (the confusions),
  registration kind and wall time (one core).

``--quick``: held-out operator only, one repetition of 26 letters x the +10 cm x shift, no
feeding, one timing pass; the open-set classes with the same variation.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from pourbench.bench._report import markdown_table, write_report
from pourbench.teleop import (
    DT_S,
    FEEDING_DURATION_S,
    FEEDING_TARGETS,
    LETTER_DURATION_S,
    LETTERS,
    NetworkModel,
    SkillCPD,
    SkillCPDConfig,
    SkillLibrary,
    delta_sample,
    feeding_demos,
    letter_demos,
    register_nonrigid,
    register_skill,
    task_outage,
)

SEED = 2026
METHODS = ("none", "skill_cpd", "standard")  # standard reuses skill_cpd's cached recognition
METHOD_NAMES = {"none": "No SA", "standard": "Standard SA", "skill_cpd": "Skill-CPD"}

# Thesis Table 5.1 (cm): (max displacement, RMSE) per method, by variation class.
THESIS = {
    ("2d", "identical"): {"none": ("9.98", "3.74"), "standard": ("0.90", "0.0020"),
                          "skill_cpd": ("0.82", "0.0010")},
    ("2d", "translated"): {"none": ("9.95", "3.76"), "standard": ("14.42", "2.96"),
                           "skill_cpd": ("0.85", "0.0014")},
    ("2d", "rotated"): {"none": ("9.95", "3.73"), "standard": ("14.05", "1.86"),
                        "skill_cpd": ("0.85", "0.0012")},
    ("2d", "scaled"): {"none": ("4.23-11.94", "1.20-5.75"), "standard": ("7.15-15.63", "2.13-5.12"),
                       "skill_cpd": ("0.83", "0.0013")},
    ("3d", "translated"): {"none": ("20.93", "12.34"), "standard": ("14.58", "9.76"),
                           "skill_cpd": ("1.12", "0.56")},
}  # fmt: skip


@dataclass(frozen=True)
class Variation:
    """A spatial change of the operator's trajectory relative to the learnt skill."""

    name: str
    cls: str
    shift: tuple[float, ...] = (0.0, 0.0)
    angle_deg: float = 0.0
    scale: float = 1.0

    def apply(self, pts: np.ndarray, centre: np.ndarray) -> np.ndarray:
        """Transform (n, D) points about ``centre`` (rotation about the vertical axis in 3-D)."""
        a = np.deg2rad(self.angle_deg)
        R = np.eye(pts.shape[1])
        R[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        shift = np.zeros(pts.shape[1])
        shift[: len(self.shift)] = self.shift
        return (pts - centre) @ R.T * self.scale + centre + shift


VARIATIONS_2D = (
    Variation("identical", "identical"),
    Variation("shift +10 cm x", "translated", shift=(0.10, 0.0)),
    Variation("shift -10 cm x", "translated", shift=(-0.10, 0.0)),
    Variation("shift +10 cm y", "translated", shift=(0.0, 0.10)),
    Variation("rotate +30°", "rotated", angle_deg=30.0),
    Variation("rotate -30°", "rotated", angle_deg=-30.0),
    Variation("scale x1.3", "scaled", scale=1.3),
    Variation("scale x1/1.3", "scaled", scale=1.0 / 1.3),
)
VARIATIONS_3D = (
    Variation("shift +15 cm x", "translated", shift=(0.15, 0.0, 0.0)),
    Variation("shift -15 cm x", "translated", shift=(-0.15, 0.0, 0.0)),
)


OPERATORS = ("held-out demo", "skill replay")

# How the bench recognises (docs/teleop.md measures the HSMM recognizer beside it).
RECOGNIZER = "shape"

# HSMM states of a letter skill (thesis: 5). Five states cut the letters' corners, in the LQT
# reproduction and in what the recognition aligns to (docs/teleop.md measures both).
LETTER_STATES = 20

# The takeover and the hand-back of every arbitration mode (thesis: 1.0 and no limit): the
# robot's offset from the skill at the switch fades over 10 packets, and the hand-back closes
# the skill-operator gap at no more than 3 cm/s (docs/teleop.md has the measurements).
TAKEOVER_STEP = 0.1
HANDBACK_SPEED = 0.03

# CPD stops once sigma^2 changes by less than 0.1 % an iteration (the library's default:
# 0.01 %); what that costs the registration and saves in time: docs/teleop.md,
# "Registration time".
CPD_TOL = 1e-3

# Open-set classes: a 21-letter library without these 5 letters (a closed-set posterior
# "recognises" each at confidence 1.0); its own letters form the other class.
UNKNOWN_LETTERS = "BDOUZ"
OPEN_SET_CLASSES = {False: "letter in library", True: "letter not in library"}
# More sets of letters left out of a library, for the gate alone (full mode): each holds
# letters that the recognition confuses with letters of the library it is left out of
GATE_SETS = ("AKMQW", "CHNSX")


@dataclass(frozen=True)
class Job:
    """One operator trajectory to replay with every method."""

    op: str
    task: str
    label: str
    rep: int
    var: Variation
    cls: str
    lib: SkillLibrary

    def operator(self) -> np.ndarray:
        """The operator's (untransformed) trajectory."""
        if self.op == "skill replay":
            duration = LETTER_DURATION_S if self.task == "2d" else FEEDING_DURATION_S
            return _skill_replay(self.lib.skill(self.label).trajectory, duration)
        if self.task == "2d":
            return letter_demos(self.label, 1, seed=SEED, start=10 + self.rep)[0].points
        return feeding_demos(self.label, 1, seed=SEED, start=5 + self.rep)[0].points


# what the calibration copies a letter under (a translation changes no feature)
CALIBRATION_VARIATIONS = tuple(v for v in VARIATIONS_2D if v.cls != "translated")
# held-out demonstrations a letter the calibration scores (indices 20, 21, 22; one against
# three measured in docs/teleop.md, "The fit gate")
CALIBRATION_DEMOS = 3


def _centre(pts: np.ndarray) -> np.ndarray:
    return 0.5 * (pts.min(axis=0) + pts.max(axis=0))


def _calibration_demos(letters: Sequence[str]) -> dict[str, list[np.ndarray]]:
    """Held-out demonstrations (indices 20-22) of ``letters`` under CALIBRATION_VARIATIONS."""
    out: dict[str, list[np.ndarray]] = {}
    for L in letters:
        out[L] = []
        for demo in letter_demos(L, CALIBRATION_DEMOS, seed=SEED, start=20):
            out[L] += [v.apply(demo.points, _centre(demo.points)) for v in CALIBRATION_VARIATIONS]
    return out


def _library_without(left_out: str, log: Any) -> SkillLibrary:
    """The letter library without ``left_out``, learnt and calibrated as the 26-letter one."""
    known = [L for L in LETTERS if L not in left_out]
    print(f"teleop: learning and calibrating a library without {left_out}", file=log)
    lib = SkillLibrary(0.006, n_states=LETTER_STATES).fit(
        {L: [d.points for d in letter_demos(L, 10, seed=SEED)] for L in known}
    )
    lib.calibrate(_calibration_demos(known), invariant=True, recognizer=RECOGNIZER)
    return lib


def _skill_replay(traj: np.ndarray, duration: float) -> np.ndarray:
    """The skill's own trajectory traversed at constant speed in ``duration`` s, every 33 ms."""
    seg = np.linalg.norm(np.diff(traj, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.arange(0.0, duration + 1e-9, DT_S)
    u = s[-1] * t / t[-1]
    return np.stack([np.interp(u, s, traj[:, d]) for d in range(traj.shape[1])], axis=1)


def _config(method: str, task: str) -> SkillCPDConfig:
    """The arbitration of ``method`` for a 2-D letter or 3-D feeding ``task``."""
    return SkillCPDConfig(
        mode=method,
        delta_d=0.006 if task == "2d" else 0.01,
        min_confidence=0.9 if task == "2d" else 0.8,
        invariant_recognition=True,
        recognizer=RECOGNIZER,
        takeover_step=TAKEOVER_STEP,
        handback_speed=HANDBACK_SPEED,
        cpd_tol=CPD_TOL,
    )


def _max_step(traj: np.ndarray, delta_d: float) -> float:
    pts = delta_sample(traj, delta_d)
    if pts.shape[0] < 2:
        return 0.0
    return float(np.max(np.linalg.norm(np.diff(pts, axis=0), axis=1)))


def _run_one(
    lib: SkillLibrary, human: np.ndarray, outage_net: NetworkModel, cfg: SkillCPDConfig
) -> dict[str, Any]:
    """Replay one operator trajectory through the arbitration; return metrics and traces."""
    sa = SkillCPD(lib, cfg)
    robot = np.empty_like(human)
    for k in range(human.shape[0]):
        t = k * DT_S
        robot[k] = sa.step(t, human[k] if outage_net.delivered(t) else None)
    err = np.linalg.norm(robot - human, axis=1)
    step = np.concatenate([[0.0], np.linalg.norm(np.diff(robot, axis=0), axis=1)])
    lost = [k for k in range(human.shape[0]) if not outage_net.delivered(k * DT_S)]
    if lost:
        k0, k1 = lost[0], lost[-1] + 1  # first missed packet, first packet back
        # the hand-back ends where the robot follows the operator again
        ends = [round(t / DT_S) for t, a, b in sa.transitions if a == "handback" and b == "direct"]
        k2 = max([k1, *ends])
        take = float(step[k0 : min(k0 + 3, k1)].max())
        back = float(step[k1 : k2 + 1].max()) if k1 < human.shape[0] else 0.0
        window = float(step[k0 : k2 + 1].max())
    else:
        take = back = window = 0.0
    reg = sa.registrations[0] if sa.registrations else None
    rec = sa.recognitions[0][1] if sa.recognitions else None  # at the deadline
    return {
        "max_displacement_cm": 100.0 * _max_step(robot, cfg.delta_d),
        "switch_jump_cm": 100.0 * window,
        "takeover_jump_cm": 100.0 * take,
        "handback_jump_cm": 100.0 * back,
        "rmse_cm": 100.0 * float(np.sqrt(np.mean(err**2))),
        "switched": reg is not None,
        "label": rec.label if rec else None,
        "confidence": rec.confidence if rec else None,
        "registration": reg.kind if reg else None,
        "registration_ms": 1e3 * reg.seconds if reg else None,
        "recognition_ms": 1e3 * reg.recognition_seconds if reg else None,
        "n_operator_points": int(reg.operator_points.shape[0])
        if reg is not None and reg.operator_points is not None
        else None,
        "n_skill_points": int(reg.trajectory.shape[0]) if reg else None,
        "_reg": reg,
        "_rec": rec,
    }


@contextmanager
def _on_one_core() -> Iterator[str]:
    """Run the block on one core (timings are 'on one core'): BLAS and OpenMP on one thread
    and this process pinned to one CPU; yields what was done. On leaving, the CPUs and
    thread limits are those from before, so later work in this process (``bench all``'s
    next suites) and the workers it starts have every core again."""
    with threadpool_limits(1):
        try:
            before = os.sched_getaffinity(0)
            os.sched_setaffinity(0, {min(before)})
        except (AttributeError, OSError):
            before = None
        try:
            yield (
                f"pinned to CPU {min(before)}"
                if before
                else "not pinned (sched_setaffinity unavailable)"
            )
        finally:
            if before:
                os.sched_setaffinity(0, before)


def _time_paths(
    cases: list[tuple[np.ndarray, np.ndarray]], cfg: SkillCPDConfig, repeats: int
) -> list[dict[str, Any]]:
    """Time non-rigid CPD with the exact, low-rank, FGT and FGT + low-rank paths."""
    paths: dict[str, dict[str, bool]] = {
        "exact (direct E-step, full kernel)": {"fgt": False, "lowrank": False},
        "low-rank kernel": {"fgt": False, "lowrank": True},
        "FGT E-step": {"fgt": True, "lowrank": False},
        "FGT + low-rank": {"fgt": True, "lowrank": True},
    }
    rows = []
    ref: list[np.ndarray] = []
    for name, kw in paths.items():
        times, devs, fgt_frac, ranks = [], [], [], []
        for i, (X, Y) in enumerate(cases):
            best = np.inf
            res = None
            for _ in range(repeats):
                t0 = time.perf_counter()
                res = register_nonrigid(X, Y, beta=cfg.beta, lmbda=cfg.lmbda, w=cfg.cpd_w, **kw)
                best = min(best, time.perf_counter() - t0)
            assert res is not None
            times.append(best)
            if len(ref) <= i:
                ref.append(res.points)
            devs.append(float(np.max(np.linalg.norm(res.points - ref[i], axis=1))))
            fgt_frac.append(res.fgt_steps / max(res.iterations, 1))
            ranks.append(res.rank)
        t = 1e3 * np.array(times)
        rows.append(
            {
                "path": name,
                "cases": len(cases),
                "median_ms": float(np.median(t)),
                "p95_ms": float(np.percentile(t, 95)),
                "max_ms": float(t.max()),
                "max_deviation_from_exact_cm": 100.0 * float(max(devs)),
                "fgt_estep_fraction": float(np.mean(fgt_frac)),
                "median_rank": float(np.median(ranks)),
            }
        )
    return rows


def _summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    groups: dict[tuple[str, str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[(r["operator"], r["task"], r["class"], r["method"])].append(r)
    out = []
    for (op, task, cls, method), rs in groups.items():
        th = THESIS.get((task, cls), {}).get(method, ("–", "–"))
        regs = [r["registration_ms"] for r in rs if r["registration_ms"] is not None]
        out.append(
            {
                "operator": op,
                "task": task.upper(),
                "class": cls,
                "skills": rs[0]["library_size"],
                "method": METHOD_NAMES[method],
                "runs": len(rs),
                "max_disp_cm (ours)": float(np.mean([r["max_displacement_cm"] for r in rs])),
                "max_disp_cm (thesis)": th[0],
                "max_disp_cm (switched runs)": float(
                    np.mean([r["max_displacement_cm"] for r in rs if r["switched"]])
                )
                if any(r["switched"] for r in rs)
                else None,
                "rmse_cm (ours)": float(np.mean([r["rmse_cm"] for r in rs])),
                "rmse_cm (thesis)": th[1],
                "switch_jump_cm": float(np.mean([r["switch_jump_cm"] for r in rs])),
                "human_max_step_cm": float(np.mean([r["human_max_step_cm"] for r in rs])),
                "takeover_jump_cm": float(np.mean([r["takeover_jump_cm"] for r in rs])),
                "handback_jump_cm": float(np.mean([r["handback_jump_cm"] for r in rs])),
                "switched": float(np.mean([r["switched"] for r in rs])),
                "recognised": float(np.mean([r["recognised"] for r in rs]))
                if rs[0]["recognised"] is not None
                else None,
                "switched_right": float(np.mean([r["switched"] and r["recognised"] for r in rs]))
                if rs[0]["recognised"] is not None and method != "none"
                else None,
                "nonrigid": float(np.mean([r["registration"] == "nonrigid" for r in rs])),
                "reg_ms_median": float(np.median(regs)) if regs else None,
            }
        )
    return out


def _targets(summary: list[dict[str, Any]]) -> list[str]:
    lines = []
    for op, cls in [
        (o, c) for o in OPERATORS for c in ("identical", "translated", "rotated", "scaled")
    ]:
        ours = [
            s for s in summary if s["operator"] == op and s["task"] == "2D" and s["class"] == cls
        ]
        cpd = [s for s in ours if s["method"] == "Skill-CPD"]
        std = [s for s in ours if s["method"] == "Standard SA"]
        if not cpd:
            continue
        v, w = cpd[0]["max_disp_cm (ours)"], std[0]["max_disp_cm (ours)"] if std else np.nan
        limit = 1.0 if cls == "scaled" else 0.85
        sw = cpd[0]["max_disp_cm (switched runs)"]
        switched = (
            "none"
            if sw is None
            else f"{sw:.3f} cm ({'meets' if sw <= 0.85 else 'MISSES'} ≤ 0.85 cm)"
        )
        right = cpd[0]["switched_right"]
        lines.append(
            f"- {op}, 2-D {cls}: Skill-CPD max displacement {v:.3f} cm "
            f"({'meets' if v <= limit else 'MISSES'} ≤ {limit:.2f} cm), "
            f"{'below' if v < w else 'NOT below'} standard SA's {w:.3f} cm; switched runs "
            f"{switched}; switched to the right letter in {100 * right:.1f} % of runs "
            f"({'meets' if right >= 0.97 else 'MISSES'} ≥ 97 %)"
        )
    return lines


def _confusions(rows: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], list[str]]:
    """Letters recognised as another letter at the deadline in Table 5.1's held-out runs."""
    rs = [
        r
        for r in rows
        if r["method"] == "skill_cpd"
        and r["operator"] == OPERATORS[0]
        and r["task"] == "2d"
        and r["class"] not in OPEN_SET_CLASSES.values()
        and r["label"] is not None
    ]
    runs = Counter(r["skill"] for r in rs)
    pairs = Counter((r["skill"], r["label"]) for r in rs if r["label"] != r["skill"])
    out = [
        {"letter": a, "recognised_as": b, "runs": n, "of": runs[a], "rate": n / runs[a]}
        for (a, b), n in pairs.most_common()
    ]
    switched = Counter(
        (r["skill"], r["label"]) for r in rs if r["label"] != r["skill"] and r["switched"]
    )
    lines = [
        f"- {c['letter']} recognised as {c['recognised_as']}: {c['runs']} of {c['of']} runs "
        f"({100 * c['rate']:.0f} %), {switched[(c['letter'], c['recognised_as'])]} of them "
        f"switched to the wrong skill"
        for c in out
    ]
    return out, lines or ["- none"]


def _open_set(rows: list[dict[str, Any]]) -> tuple[dict[str, Any], list[str]]:
    """Confidence at the deadline and switch rates of the open-set classes."""
    bins = np.linspace(0.0, 1.0, 21)
    out: dict[str, Any] = {"bins": bins.tolist(), "histograms": {}, "rates": {}}
    lines = []
    for unknown, cls in OPEN_SET_CLASSES.items():
        rs = [r for r in rows if r["class"] == cls and r["method"] == "skill_cpd"]
        conf = np.array([r["confidence"] for r in rs if r["confidence"] is not None])
        if not rs or not conf.size:
            continue
        out["histograms"][cls] = np.histogram(conf, bins)[0].tolist()
        if unknown:
            ok = float(np.mean(conf < 0.9))
            what = "confidence < 0.9"
        else:
            ok = float(np.mean([r["confidence"] >= 0.9 and r["recognised"] for r in rs]))
            what = "confidence ≥ 0.9 and the right letter"
        sw = float(np.mean([r["switched"] for r in rs]))
        out["rates"][cls] = {"runs": len(rs), "ok": ok, "switched": sw}
        lines.append(
            f"- {cls}: {what} in {100 * ok:.1f} % of {len(rs)} runs; Skill-CPD switched in "
            f"{100 * sw:.1f} %."
        )
    return out, lines


def _confidence_png(path: Path, hists: dict[str, list[int]], bins: list[float]) -> Path:
    """Side-by-side bar histograms (fraction of runs per confidence bin) as a PNG."""
    from PIL import Image, ImageDraw  # only needed here

    W, H, left, bottom, top = 720, 360, 60, 40, 40
    img = Image.new("RGB", (W, H), "white")
    d = ImageDraw.Draw(img)
    colours = ("#1f77b4", "#d62728")
    n = len(bins) - 1
    fr = {k: np.asarray(v, float) / max(sum(v), 1) for k, v in hists.items()}
    ymax = max([float(v.max()) for v in fr.values()] + [1e-9])
    bw = (W - left - 20) / n
    x_of = lambda c: left + (W - left - 20) * c  # noqa: E731
    y_of = lambda f: H - bottom - (H - bottom - top) * f / ymax  # noqa: E731
    for j, (name, f) in enumerate(fr.items()):
        for i in range(n):
            x0 = left + i * bw + j * bw / len(fr)
            d.rectangle([x0, y_of(f[i]), x0 + bw / len(fr) - 1, H - bottom], fill=colours[j % 2])
        d.rectangle([left + 10, 8 + 14 * j, left + 20, 18 + 14 * j], fill=colours[j % 2])
        d.text((left + 26, 7 + 14 * j), f"{name} ({sum(hists[name])} runs)", fill="black")
    d.line([left, H - bottom, W - 20, H - bottom], fill="black")
    d.line([left, top, left, H - bottom], fill="black")
    d.line([x_of(0.9), top, x_of(0.9), H - bottom], fill="black", width=2)
    d.text((x_of(0.9) - 60, top - 12), "lambda_minconf 0.9", fill="black")
    for c in (0.0, 0.25, 0.5, 0.75, 1.0):
        d.text((x_of(c) - 8, H - bottom + 4), f"{c:.2f}", fill="black")
    d.text((left + 200, H - 18), "recognition confidence at the deadline", fill="black")
    d.text((4, top - 4), f"{ymax:.2f}", fill="black")
    d.text((4, H - bottom - 8), "0", fill="black")
    d.text((4, (H - bottom + top) / 2), "fraction\nof runs", fill="black")
    tmp = path.with_name(path.name + ".partial")
    img.save(tmp, format="PNG")
    os.replace(tmp, path)
    return path


def run(args: argparse.Namespace) -> int:
    """Run the suite (see the module docstring) on one core; returns 0."""
    with _on_one_core() as pinned:
        return _run(args, pinned)


def _run(args: argparse.Namespace, pinned: str) -> int:
    quick = bool(getattr(args, "quick", False))
    rng = np.random.default_rng(SEED)
    log = sys.stderr
    t_start = time.perf_counter()
    load_start = os.getloadavg()[0]
    base = SkillCPDConfig()
    reps = 1 if quick else 3
    variations = (VARIATIONS_2D[1],) if quick else VARIATIONS_2D
    print(f"teleop: learning 26 letter skills (10 demos each, {LETTER_STATES} states)", file=log)
    lib2 = SkillLibrary(0.006, n_states=LETTER_STATES).fit(
        {L: [d.points for d in letter_demos(L, 10, seed=SEED)] for L in LETTERS}
    )
    print("teleop: calibrating the recognition confidence on held-out demos", file=log)
    lib2.calibrate(_calibration_demos(LETTERS), invariant=True, recognizer=RECOGNIZER)
    jobs: list[Job] = []
    operators = ("held-out demo",) if quick else OPERATORS
    for op in operators:
        for rep in range(reps if op == "held-out demo" else 1):
            for L in LETTERS:
                for var in variations:
                    jobs.append(Job(op, "2d", L, rep, var, var.cls, lib2))
    if not quick:
        print("teleop: learning 3 feeding skills (5 demos each)", file=log)
        lib3 = SkillLibrary(0.01).fit(
            {T: [d.points for d in feeding_demos(T, 5, seed=SEED)] for T in FEEDING_TARGETS}
        )
        lib3.calibrate(
            {
                T: [d.points for d in feeding_demos(T, 3, seed=SEED, start=10)]
                for T in FEEDING_TARGETS
            },
            invariant=True,
            recognizer=RECOGNIZER,
        )
        for op in operators:
            for rep in range(3 if op == "held-out demo" else 1):
                for T in FEEDING_TARGETS:
                    for var in VARIATIONS_3D:
                        jobs.append(Job(op, "3d", T, rep, var, var.cls, lib3))
    # the open-set classes: a library without UNKNOWN_LETTERS (after the rows above, so
    # their outages are drawn as before)
    lib21 = _library_without(UNKNOWN_LETTERS, log)
    for L in LETTERS:
        cls = OPEN_SET_CLASSES[L in UNKNOWN_LETTERS]
        for rep in range(reps if L in UNKNOWN_LETTERS else 1):
            for var in variations:
                jobs.append(Job(OPERATORS[0], "2d", L, rep, var, cls, lib21))
    rows: list[dict[str, Any]] = []
    timing_cases: list[tuple[np.ndarray, np.ndarray]] = []
    switch_cases: list[tuple[np.ndarray, np.ndarray, SkillCPDConfig]] = []
    for job in tqdm(jobs, desc="teleop runs", file=log):
        op, task, label, rep, var, lib = job.op, job.task, job.label, job.rep, job.var, job.lib
        delta_d = 0.006 if task == "2d" else 0.01
        raw = job.operator()
        human = var.apply(raw, _centre(raw))
        outage = task_outage(rng, human.shape[0] * DT_S)
        net = NetworkModel([outage], DT_S)
        human_step = 100.0 * _max_step(human, delta_d)
        for method in METHODS:
            cfg = _config(method, task)
            m = _run_one(lib, human, net, cfg)
            reg, rec = m.pop("_reg"), m.pop("_rec")
            table51 = job.cls not in OPEN_SET_CLASSES.values()
            if method == "skill_cpd" and reg is not None and op == OPERATORS[0] and table51:
                xi_a = lib.skill(reg.label).trajectory
                switch_cases.append((reg.operator_points, xi_a, cfg, rec.alignment))
                if reg.nonrigid_template is not None and len(timing_cases) < (26 if quick else 60):
                    timing_cases.append((reg.operator_points, reg.nonrigid_template))
            rows.append(
                {
                    "operator": op,
                    "task": task,
                    "skill": label,
                    "repetition": rep,
                    "variation": var.name,
                    "class": job.cls,
                    "method": method,
                    "library_size": len(lib.skills),
                    "outage_start_s": outage.start,
                    "outage_s": outage.duration,
                    "human_max_step_cm": human_step,
                    "recognised": None
                    if m["label"] is None or job.cls == OPEN_SET_CLASSES[True]
                    else m["label"] == label,
                    **m,
                }
            )
    gate_jobs: list[tuple[str, Job]] = []  # (the letters left out, a run of one of them)
    for left_out in () if quick else GATE_SETS:
        lib_out = _library_without(left_out, log)
        for L in left_out:
            for rep in range(reps):
                for var in variations:
                    job = Job(OPERATORS[0], "2d", L, rep, var, OPEN_SET_CLASSES[True], lib_out)
                    gate_jobs.append((left_out, job))
    gate_conf: dict[str, list[float]] = defaultdict(list)
    for left_out, job in tqdm(gate_jobs, desc="teleop gate runs", file=log):
        raw = job.operator()
        human = job.var.apply(raw, _centre(raw))
        net = NetworkModel([task_outage(rng, human.shape[0] * DT_S)], DT_S)
        m = _run_one(job.lib, human, net, _config("skill_cpd", "2d"))
        gate_conf[left_out].append(m["confidence"])
    print(f"teleop: timing non-rigid CPD paths on {len(timing_cases)} switches", file=log)
    timing = _time_paths(timing_cases, base, repeats=1 if quick else 3)
    # registration re-timed on the same inputs, best of 3, to damp the shared-CPU noise
    stride = 1 if quick else 4
    best_ms = []
    for X, xi_a, cfg, init in switch_cases[::stride]:
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            register_skill(X, xi_a, X[-1], cfg, init)
            best = min(best, time.perf_counter() - t0)
        best_ms.append(1e3 * best)
    best_arr = np.array(best_ms)
    summary = _summarise(rows)
    t51 = [
        r
        for r in rows
        if r["method"] == "skill_cpd" and r["class"] not in OPEN_SET_CLASSES.values()
    ]
    regs = np.array([r["registration_ms"] for r in t51 if r["registration_ms"]])
    npts = [(r["n_operator_points"], r["n_skill_points"]) for r in t51 if r["n_operator_points"]]
    open_set, open_lines = _open_set(rows)
    for left_out, conf in gate_conf.items():
        below = float(np.mean(np.array(conf) < 0.9))
        open_set["rates"][f"left out: {left_out}"] = {"runs": len(conf), "ok": below}
        open_lines.append(
            f"- {', '.join(left_out)} left out of a library of the other 21: confidence < 0.9 "
            f"in {100 * below:.1f} % of {len(conf)} runs."
        )
    confusions, confusion_lines = _confusions(rows)
    best_line = (
        f"Same registrations re-timed on the same inputs, best of 3 ({best_arr.size} switches, "
        f"every {stride}th held-out one): median {np.median(best_arr):.1f} ms, p95 "
        f"{np.percentile(best_arr, 95):.1f} ms, max {best_arr.max():.1f} ms; "
        f"{100.0 * np.mean(best_arr <= 33.0):.0f} % within 33 ms."
        if best_arr.size
        else ""
    )
    reg_line = (
        f"Registration per switch (rigid + non-rigid when needed + closest step, low-rank "
        f"kernel, {pinned}): median {np.median(regs):.1f} ms, p95 {np.percentile(regs, 95):.1f} "
        f"ms, max {regs.max():.1f} ms over {regs.size} switches; operator points "
        f"{int(np.median([a for a, _ in npts]))} (median), skill points "
        f"{int(np.median([b for _, b in npts]))} (median); the rigid step starts from the "
        f"recognition's alignment. Targets: median ≤ 10 ms, p95 ≤ 20 ms (the update period "
        f"is 33 ms)."
        if regs.size
        else "No switch happened."
    )
    elapsed = time.perf_counter() - t_start
    load = f"load average {load_start:.2f} at the start, {os.getloadavg()[0]:.2f} at the end"
    cols = [
        "operator", "task", "class", "skills", "method", "runs", "max_disp_cm (ours)",
        "max_disp_cm (thesis)", "max_disp_cm (switched runs)",
        "rmse_cm (ours)", "rmse_cm (thesis)", "takeover_jump_cm", "handback_jump_cm",
        "human_max_step_cm",
        "switched", "recognised", "switched_right", "nonrigid", "reg_ms_median",
    ]  # fmt: skip
    body = "\n".join(
        [
            "Skill-CPD shared autonomy under a network outage, laid out as thesis Table 5.1. "
            "Columns marked *(thesis)* are the thesis' numbers (Unity3D simulation, their "
            "letter set), copied for comparison; every other number was measured by this "
            "run. Protocol and metric definitions: `pourbench/bench/teleop.py` docstring.",
            "",
            f"Mode: {'quick' if quick else 'full'}; {len(jobs)} operator trajectories x "
            f"{len(METHODS)} methods; seed {SEED}; wall time {elapsed:.0f} s; {load} "
            f"(the machine's 2 cores are shared, so wall-clock timings include contention).",
            "",
            markdown_table(summary, cols),
            "",
            "## Targets",
            "",
            *_targets(summary),
            f"- {reg_line}",
            f"- {best_line}",
            "",
            "## Confusions",
            "",
            "Held-out demonstrations of Table 5.1 (all 2-D classes) whose recognition at the "
            "deadline named another letter; a wrong letter switches only when its confidence "
            "reaches λ_minconf.",
            "",
            *confusion_lines,
            "",
            "## Letters outside the library",
            "",
            f"A library of {26 - len(UNKNOWN_LETTERS)} letters without "
            f"{', '.join(UNKNOWN_LETTERS)}, learnt and calibrated as the 26-letter one. Class "
            f"'{OPEN_SET_CLASSES[True]}': those 5 letters ({reps} repetition(s)); class "
            f"'{OPEN_SET_CLASSES[False]}': its 21 letters (1 repetition); same variations and "
            "outages as above. Confidence = the recognition's at the deadline in the Skill-CPD "
            "runs; λ_minconf = 0.9.",
            "",
            *open_lines,
            "",
            "![confidence at the deadline, letters in and not in the library]"
            "(teleop_confidence.png)",
            "",
            "## Non-rigid CPD: exact vs accelerated paths",
            "",
            "The non-rigid problems of the first switches that needed one (operator prefix "
            "onto the rigidly registered skill prefix), solved again with each path; best of "
            "the repeats; deviation = largest distance between a path's registered points "
            "and the exact path's.",
            "",
            markdown_table(timing, list(timing[0]) if timing else ["path"]),
            "",
            "Notes: `max_disp_cm` cannot go below about Δd + one packet's motion "
            "(`human_max_step_cm` is the same metric on the operator's own path). "
            "`switched` = fraction of runs that switched to the skill (recognition "
            "confidence ≥ λ_minconf at the deadline); `max_disp_cm (switched runs)` = the "
            "same mean over the runs that switched only (a run that did not switch holds "
            "and jumps on reconnection as No SA does); `recognised` = the recognised skill "
            "was the right one.",
        ]
    )
    extra = {
        "quick": quick,
        "seed": SEED,
        "summary": summary,
        "cpd_paths": timing,
        "registration_ms_best_of_3": {
            "median": float(np.median(best_arr)) if best_arr.size else None,
            "p95": float(np.percentile(best_arr, 95)) if best_arr.size else None,
            "max": float(best_arr.max()) if best_arr.size else None,
            "switches": int(best_arr.size),
        },
        "registration_ms": {
            "median": float(np.median(regs)) if regs.size else None,
            "p95": float(np.percentile(regs, 95)) if regs.size else None,
            "max": float(regs.max()) if regs.size else None,
        },
        "cpu": pinned,
        "load_during_run": load,
        "open_set": open_set,
        "confusions": confusions,
    }
    if not getattr(args, "no_write", False):
        paths = write_report(
            "teleop",
            rows,
            out=getattr(args, "out", "leaderboard"),
            title="Teleoperation: Skill-CPD under network drops",
            body_md=body,
            extra=extra,
        )
        png = _confidence_png(
            paths[0].parent / "teleop_confidence.png", open_set["histograms"], open_set["bins"]
        )
        print(f"teleop: wrote {paths[0]}, {paths[1]} and {png}", file=log)
    if getattr(args, "json", False):
        print(json.dumps({"suite": "teleop", **extra, "rows": rows}, default=str))
    else:
        print(markdown_table(summary, cols), file=log)
    return 0
