"""Assistive teleoperation under network drops: HSMM, LQT, CPD and Skill-CPD (thesis ch. 5).

Everything here is written by hand in numpy/scipy (no maintained library provides HSMM with
an online forward variable, finite-horizon LQT from HSMM step-wise Gaussians, or CPD):

* :mod:`~pourbench.teleop.hsmm`: Gaussian-duration HSMM, EM training, forward variable;
* :mod:`~pourbench.teleop.lqt`: discrete LQT on a double integrator (Eq. 2.45-2.49);
* :mod:`~pourbench.teleop.cpd`: rigid and non-rigid Coherent Point Drift, with the Fast
  Gauss Transform and low-rank kernel accelerations;
* :mod:`~pourbench.teleop.network`: packets every 33 ms, outages, 50 ms deadline detector;
* :mod:`~pourbench.teleop.skills`: skill library (HSMM + LQT per skill, recognition);
* :mod:`~pourbench.teleop.shape`: the shape recognizer (step directions against a mean path);
* :mod:`~pourbench.teleop.confidence`: the calibrated open-set recognition confidence;
* :mod:`~pourbench.teleop.skill_cpd`: the arbitration state machine (Algorithms 2 and 3);
* :mod:`~pourbench.teleop.demos`: generated letter and feeding demonstrations.
"""

from __future__ import annotations

from pourbench.teleop.confidence import (
    WINDOWS,
    CalibrationExample,
    NoneModel,
    fit_none_model,
    open_set_posterior,
)
from pourbench.teleop.cpd import (
    NonRigidResult,
    RigidResult,
    gauss_transform,
    register_nonrigid,
    register_rigid,
)
from pourbench.teleop.demos import (
    DT_S,
    FEEDING_DURATION_S,
    FEEDING_TARGETS,
    LETTER_DURATION_S,
    LETTERS,
    Demo,
    delta_sample,
    feeding_demos,
    feeding_template,
    letter_demos,
    letter_template,
)
from pourbench.teleop.hsmm import HSMM, Progress, trajectory_features
from pourbench.teleop.lqt import LQTResult, double_integrator, lqt_track
from pourbench.teleop.network import (
    DeadlineDetector,
    NetworkModel,
    Outage,
    random_outages,
    task_outage,
)
from pourbench.teleop.shape import ShapeMatch, ShapeModel, match_shape
from pourbench.teleop.skill_cpd import (
    MODES,
    Registration,
    SkillCPD,
    SkillCPDConfig,
    closest_step,
    register_skill,
)
from pourbench.teleop.skills import RECOGNIZERS, Recognition, Skill, SkillLibrary

__all__ = [
    "DT_S",
    "FEEDING_DURATION_S",
    "FEEDING_TARGETS",
    "HSMM",
    "LETTERS",
    "LETTER_DURATION_S",
    "MODES",
    "RECOGNIZERS",
    "WINDOWS",
    "CalibrationExample",
    "DeadlineDetector",
    "Demo",
    "LQTResult",
    "NetworkModel",
    "NonRigidResult",
    "NoneModel",
    "Outage",
    "Progress",
    "Recognition",
    "Registration",
    "RigidResult",
    "ShapeMatch",
    "ShapeModel",
    "Skill",
    "SkillCPD",
    "SkillCPDConfig",
    "SkillLibrary",
    "closest_step",
    "delta_sample",
    "double_integrator",
    "feeding_demos",
    "feeding_template",
    "fit_none_model",
    "gauss_transform",
    "letter_demos",
    "letter_template",
    "lqt_track",
    "match_shape",
    "open_set_posterior",
    "random_outages",
    "register_nonrigid",
    "register_rigid",
    "register_skill",
    "task_outage",
    "trajectory_features",
]
