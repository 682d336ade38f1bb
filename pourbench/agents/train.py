"""Train a PourNet policy on ``pourbench/Pour-v0`` (thesis §6.5–6.6): PPO with an MLP (FNN),
RecurrentPPO with an LSTM, or SAC on one liquid; with the curiosity module and the liquid
curriculum on by default; then compare it with a random policy on the same episodes.

``pourbench train --budget-steps 200000`` (or ``--budget-s 900``; ``python -m
pourbench.agents.train`` takes the same flags). One :class:`TrainArgs` holds every setting,
checked before any work.

The run's folder (``--out``) holds:

* ``model.zip``: the model, saved every ``--checkpoint-s`` seconds and at the end (through
  a temporary file: an interrupted run keeps its last checkpoint), with ``icm.pt`` (the
  curiosity module's weights and optimiser), ``replay_buffer.pkl`` (an off-policy learner's
  replay buffer) and ``state.json`` (settings, steps, seconds trained, and each session's
  command, git SHA, machine, date, steps and seconds) beside it;
* ``logs/<session>/``: SB3's ``progress.csv`` and TensorBoard events
  (``tensorboard --logdir <out>/logs``), one folder per session;
* ``training.png``: the training curves (:mod:`pourbench.agents.plots`);
* ``result.json``: the final evaluation against a random policy.

``--resume`` continues the latest checkpoint: model, ICM, replay buffer and step count; the
budget is the run's total (steps, or seconds over all sessions), so a resumed run trains
until it is spent and a finished one is resumed with a larger budget. A run into a folder
that already holds a model without ``--resume`` is refused rather than overwriting it.
"""

from __future__ import annotations

import json
import math
import os
import shlex
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from pourbench.agents.loading import LR_SCHEDULES, NO_SDE, OFF_POLICY, check_ent_coef
from pourbench.errors import (
    InvalidParameterError,
    PourbenchError,
    check_finite,
    check_int,
    check_positive,
)

ALGORITHMS = ("ppo", "recurrent_ppo", *OFF_POLICY)
POLICIES = ("mlp", "lstm")
_SAME_ON_RESUME = (
    "algorithm",
    "policy",
    "icm",
    "curriculum",
    "num_envs",
    "n_steps",
    "batch_size",
    "icm_eta",
    "learning_rate",
    "lr_schedule",
    "target_kl",
    "final_error_per_g",
    "residual",
    "sde",
    "rehearse",
    "eval_liquid",
    "target_g",
    "utd",
    "ent_coef",
    "shaping",
    "directed_tilt",
    "directed_approach",
    "tilt_target",
    "progress_per_g",
)
"""Settings a resume must keep: SB3 restores its own from model.zip (batch_size, n_steps,
learning_rate, ...), or they set the worlds, the ICM or every evaluation. ``liquid`` joins
them without the curriculum, where it is every episode's and evaluation's liquid."""


@dataclass
class TrainArgs:
    """Training settings.

    Attributes:
        algorithm: ppo (with policy mlp: the FNN PourNet), recurrent_ppo (with policy lstm:
            the LSTM PourNet), or an off-policy learner with policy mlp and no ICM: sac,
            tqc or crossq (sb3-contrib), or td3.
        policy: mlp or lstm (see pourbench.agents.models for the architectures).
        icm: add the curiosity module's intrinsic reward (PPO and RecurrentPPO; off with
            --no-icm).
        shaping: scale of a potential-based shaping term added to the reward, toward the
            receiving container and the target (pourbench.envs.reward; 0: none): it keeps
            the optimal policies and gives a learner from scratch a gradient before its
            first pour reaches the scale.
        device: where the worlds' liquid is simulated: cpu, or cuda (cuda:N) where Warp
            sees a CUDA device; the networks train on the CPU either way.
        utd: the off-policy learners' gradient updates per environment step, the
            update-to-data ratio (0: one update per vector step, SB3's default;
            pourbench.agents.models.gradient_steps).
        ent_coef: SAC, TQC and CrossQ: a fixed entropy coefficient instead of SB3's automatic
            tuning toward its target entropy, which lets the policy's spread collapse once it
            holds (docs/training.md, "The tilt as a target"); 0: automatic.
        curriculum: draw liquids from the curriculum's lessons, switched at 25 % and 50 %
            of the budget; --no-curriculum pours --liquid in every episode.
        num_envs: parallel worlds in the one vector env (the thesis' 32).
        workers: processes the worlds are spread over (0: one per core, at most one per
            world).
        budget_steps: training budget in environment steps over all worlds and sessions.
        budget_s: training budget in wall-clock seconds over all sessions (when neither is
            given: 900 s; give one, not both).
        liquid: the liquid without curriculum, and of the evaluations.
        eval_liquid: the liquid of every evaluation ("": Table 6.2's six liquids with the
            curriculum, else liquid); the ablation evaluates every variant on water.
        target_g: target of every episode, g (0: drawn per episode from 50 to 200 g).
        n_steps: rollout length per world (PPO, RecurrentPPO).
        seq_len: LSTM sequence length; sb3-contrib bounds a sequence by n_steps, so a
            recurrent run needs seq_len == n_steps.
        batch_size: minibatch size, samples.
        icm_eta: scale of the intrinsic reward, eta.
        seed: seed of the model and of the worlds (a resumed run's k-th session seeds them
            with seed + 1000·k; evaluation uses seeds 1000…).
        eval_episodes: episodes of each evaluation: pours of liquid, or with the curriculum
            spread evenly over Table 6.2's six liquids (rounded up to a multiple of six).
        eval_every_steps: environment steps between evaluations during training (0: only
            at the end).
        threads: torch threads.
        out: folder of the run (model, logs, plot, result).
        checkpoint_s: seconds between checkpoints.
        resume: continue the run in out from its latest checkpoint.
        warm_start_steps: environment steps (over all worlds) of the PD baseline's
            demonstrations that a new PPO or RecurrentPPO model is cloned from before it
            trains (pourbench.agents.warmstart; 0: none, the thesis' start from scratch).
            They and the cloning count in a time budget, not in the step budget.
        clone_epochs: passes of the cloning over the demonstrations.
        dagger_rounds: after the cloning, rounds in which the clone acts for
            warm_start_steps steps, the PD labels the states it visits, and the clone is
            fitted again to everything labelled so far, with as many gradient steps as the
            first fit (DAgger; 0: cloning alone). Needs warm_start_steps.
        clone_std: the policy's standard deviation per action dimension after the cloning,
            or at the start of a residual policy (0: the fit's residual, at least 0.1; a
            residual policy without warm start: SB3's 1). Algorithm 4 keeps only the tilt rate's
            sign that its phase allows, so noise around a hold tilts on and over-pours: the
            smaller the spread, the closer PPO's noisy rollouts pour to its deterministic
            policy (docs/training.md). Needs warm_start_steps or residual.
        init_std: PPO and RecurrentPPO from scratch: the policy's standard deviation per
            action dimension at the start (0: SB3's 1). Algorithm 4 (and the directed maps'
            hold at the edge of the output range) turn noise into net forward tilt, so a
            policy trained under a large spread learns a mean that only pours with that
            noise (docs/training.md).
        warm_start_lessons: with the curriculum, "first": the demonstrations and DAgger
            rollouts pour the first lesson's liquids, where PPO starts; "all": each rollout
            is split evenly over the lessons (measured in docs/training.md).
        learning_rate: Adam's step size.
        lr_schedule: "constant", or "linear": the step size at step t of a budget of B
            steps is learning_rate × (1 − t / B), zero at the end (needs budget_steps; a
            resume with a larger budget goes on at its new line's value), so that the late
            updates move a policy that has found a pour less.
        target_kl: PPO and RecurrentPPO stop an update's epochs once the policy has moved
            this far (KL divergence) from the one that collected the rollout (0: no limit);
            a cloned policy's small spread makes its likelihood ratios steep, and a limit
            keeps PPO's first updates from undoing the clone.
        final_error_per_g: reward taken off per gram of error when an episode ends
            normally or at the step limit, a denser reward than the thesis' Algorithm 5 (0:
            Algorithm 5 alone; pourbench.envs.reward.RewardConfig).
        progress_per_g: reward per gram by which each step brings the pouring error down
            (charge per gram it raises it): every gram of the final error counts, as with
            final_error_per_g, but paid as the scale moves, so a discounted learner gains
            nothing by putting off its episode's end (0: none; RewardConfig).
        residual: S in (0, 1]: the policy's action, times S, is added to the PD baseline's,
            and its action head starts at zero, so training starts from the PD's pours
            (pourbench.agents.residual; 0: the policy acts alone). The warm start then fits
            the critic to the PD's returns and keeps the action at zero. PPO and
            RecurrentPPO, without DAgger.
        sde: explore with generalized state-dependent noise (gSDE, SB3's ``use_sde``): the
            noise is a function of the state, drawn anew once per rollout, so a correction
            held through a whole pour gets tried, where independent noise per step averages
            out over the pour's hundreds of steps. Not with a warm start (its cloning fits
            one spread per action dimension).
        directed_tilt: the policy's tilt output is the size of the tilt rate in the
            direction Algorithm 4 allows (forward before the target, backward after), a
            bijection onto the rates the handler applies, so that no half of the output
            range is dead (pourbench.agents.directed). The saved model keeps the map.
        directed_approach: the policy's approach output v becomes the speed toward the
            receiving container, (v + 1) / 2, so that it can no longer move the container
            away, which only delays the pour (pourbench.agents.directed). The saved model
            keeps the map.
        tilt_target: the policy's tilt output is the tilt the container turns toward,
            (u + 1) / 2 of the largest tilt, at the rate that reaches it within a step where
            the full rate allows; holding a tilt is then a constant output inside the range,
            not the squashed edge the rate maps put it at (pourbench.agents.directed). Not
            with directed_tilt. The saved model keeps the map.
        rehearse: with the curriculum, each episode of lesson k pours a liquid of a lesson
            drawn uniformly among lessons 0…k, so the water-like liquids stay in training
            through the honey-like lesson (why: docs/training.md).
    """

    algorithm: str = "ppo"
    policy: str = "mlp"
    icm: bool = True
    curriculum: bool = True
    num_envs: int = 32
    workers: int = 0
    budget_steps: int | None = None
    budget_s: float | None = None
    liquid: str = "water"
    eval_liquid: str = ""
    target_g: float = 0.0
    n_steps: int = 64
    seq_len: int = 64
    batch_size: int = 256
    icm_eta: float = 0.02
    seed: int = 0
    eval_episodes: int = 10
    eval_every_steps: int = 100_000
    threads: int = 1
    out: str = "runs/pournet"
    checkpoint_s: float = 60.0
    resume: bool = False
    warm_start_steps: int = 0
    clone_epochs: int = 30
    dagger_rounds: int = 0
    clone_std: float = 0.0
    init_std: float = 0.0
    warm_start_lessons: str = "first"
    learning_rate: float = 3e-4
    lr_schedule: str = "constant"
    target_kl: float = 0.0
    final_error_per_g: float = 0.0
    progress_per_g: float = 0.0
    residual: float = 0.0
    sde: bool = False
    rehearse: bool = False
    utd: float = 0.0
    ent_coef: float = 0.0
    shaping: float = 0.0
    directed_tilt: bool = False
    directed_approach: bool = False
    tilt_target: bool = False
    device: str = "cpu"

    def __post_init__(self) -> None:
        """Every setting checked at construction, before any training: a run that trains is
        not lost to a bad setting its evaluation would meet only at the end."""
        if self.algorithm not in ALGORITHMS:
            raise InvalidParameterError(
                f"algorithm must be one of {list(ALGORITHMS)}, got {self.algorithm!r}"
            )
        if self.policy not in POLICIES:
            raise InvalidParameterError(
                f"policy must be one of {list(POLICIES)}, got {self.policy!r}"
            )
        if (self.policy == "lstm") != (self.algorithm == "recurrent_ppo"):
            raise InvalidParameterError(
                f"policy {self.policy!r} does not go with algorithm {self.algorithm!r}: lstm "
                f"is trained by recurrent_ppo, mlp by ppo or {' / '.join(OFF_POLICY)}"
            )
        for name in (
            "icm",
            "curriculum",
            "resume",
            "sde",
            "rehearse",
            "directed_tilt",
            "directed_approach",
            "tilt_target",
        ):
            if not isinstance(getattr(self, name), bool):
                raise InvalidParameterError(
                    f"{name} must be True or False, got {getattr(self, name)!r}"
                )
        off_policy = self.algorithm in OFF_POLICY
        if off_policy and self.icm:
            raise InvalidParameterError(
                f"algorithm {self.algorithm!r} trains without the curiosity module, whose "
                "updates follow PPO's rollouts: give --no-icm"
            )
        check_finite("utd", self.utd, minimum=0.0)
        check_ent_coef(self.algorithm, check_finite("ent_coef", self.ent_coef, minimum=0.0))
        if self.utd and not off_policy:
            raise InvalidParameterError(
                f"utd={self.utd!r} sets an off-policy learner's updates ({', '.join(OFF_POLICY)}); "
                f"{self.algorithm} updates once per rollout"
            )
        if self.budget_steps is not None and self.budget_s is not None:
            raise InvalidParameterError(
                f"give one budget, steps or seconds, not both (budget_steps="
                f"{self.budget_steps!r}, budget_s={self.budget_s!r})"
            )
        if self.budget_steps is not None:
            check_int("budget_steps", self.budget_steps, minimum=1)
        elif self.budget_s is None:
            self.budget_s = 900.0
        if self.budget_s is not None:
            check_positive("budget_s", self.budget_s)
        for name in ("checkpoint_s", "icm_eta", "learning_rate"):
            check_positive(name, getattr(self, name))
        if self.lr_schedule not in LR_SCHEDULES:
            raise InvalidParameterError(
                f"lr_schedule must be one of {list(LR_SCHEDULES)}, got {self.lr_schedule!r}"
            )
        if self.lr_schedule != "constant" and self.budget_steps is None:
            raise InvalidParameterError(
                f"lr_schedule={self.lr_schedule!r} runs over the step budget: give "
                "--budget-steps (a time budget has no end step to decay to)"
            )
        for name in ("num_envs", "n_steps", "seq_len", "batch_size", "eval_episodes", "threads"):
            check_int(name, getattr(self, name), minimum=1)
        for name in ("seed", "workers", "eval_every_steps", "warm_start_steps", "dagger_rounds"):
            check_int(name, getattr(self, name), minimum=0)
        check_int("clone_epochs", self.clone_epochs, minimum=1)
        spreads_and_terms = (
            "target_kl",
            "clone_std",
            "init_std",
            "final_error_per_g",
            "progress_per_g",
            "shaping",
        )
        for name in spreads_and_terms:
            check_finite(name, getattr(self, name), minimum=0.0)
        if off_policy and self.target_kl:
            raise InvalidParameterError(
                f"target_kl={self.target_kl!r} limits PPO's updates; {self.algorithm} has none"
            )
        if off_policy and self.warm_start_steps:
            raise InvalidParameterError(
                f"warm_start_steps={self.warm_start_steps!r}: the PD warm start clones into "
                f"PPO or RecurrentPPO, not {self.algorithm}"
            )
        if self.algorithm in NO_SDE and self.sde:
            raise InvalidParameterError(
                f"sde: {NO_SDE[self.algorithm]} explores with its own noise only"
            )
        if self.dagger_rounds and not self.warm_start_steps:
            raise InvalidParameterError(
                f"dagger_rounds={self.dagger_rounds!r} relabels the clone's own rollouts: it "
                "needs warm_start_steps > 0"
            )
        if self.warm_start_lessons not in ("first", "all"):
            raise InvalidParameterError(
                f"warm_start_lessons must be 'first' or 'all', got {self.warm_start_lessons!r}"
            )
        check_finite("residual", self.residual, minimum=0.0)
        if self.residual > 1:
            raise InvalidParameterError(
                f"residual={self.residual!r}: the scale of the correction added to the PD's "
                "action (in [-1, 1]) must be in (0, 1], or 0 for none"
            )
        if self.residual and (off_policy or self.dagger_rounds):
            raise InvalidParameterError(
                f"residual={self.residual!r} trains PPO or RecurrentPPO on top of the PD, "
                f"without DAgger (algorithm={self.algorithm!r}, "
                f"dagger_rounds={self.dagger_rounds!r})"
            )
        if self.directed_tilt and self.tilt_target:
            raise InvalidParameterError(
                "directed_tilt=True and tilt_target=True both map the policy's tilt output; "
                "choose one"
            )
        for name in ("directed_tilt", "directed_approach", "tilt_target"):
            if getattr(self, name) and (self.residual or self.warm_start_steps):
                raise InvalidParameterError(
                    f"{name}=True maps the policy's own output; it does not go with a PD "
                    f"residual or warm start (residual={self.residual!r}, "
                    f"warm_start_steps={self.warm_start_steps!r})"
                )
        if self.sde and self.warm_start_steps:
            raise InvalidParameterError(
                f"sde=True with warm_start_steps={self.warm_start_steps!r}: the cloning fits "
                "one spread per action dimension, gSDE's spread is per feature; drop one of them"
            )
        if self.rehearse and not self.curriculum:
            raise InvalidParameterError(
                "rehearse=True draws from the curriculum's earlier lessons: it needs the curriculum"
            )
        if self.init_std and (self.warm_start_steps or self.residual or off_policy):
            raise InvalidParameterError(
                f"init_std={self.init_std!r} sets the spread of a PPO or RecurrentPPO policy "
                "from scratch (clone_std sets a cloned or residual one's; the off-policy "
                f"learners set their own): not with algorithm={self.algorithm!r}, "
                f"warm_start_steps={self.warm_start_steps!r}, residual={self.residual!r}"
            )
        if self.clone_std and not (self.warm_start_steps or self.residual):
            raise InvalidParameterError(
                f"clone_std={self.clone_std!r} is the cloned or residual policy's spread: it "
                "needs warm_start_steps > 0 or residual > 0"
            )
        if self.workers > self.num_envs:
            raise InvalidParameterError(
                f"workers={self.workers!r} is more than num_envs={self.num_envs!r}"
            )
        if isinstance(self.target_g, bool) or not isinstance(self.target_g, int | float):
            raise InvalidParameterError(f"target_g must be a number, got {self.target_g!r}")
        if self.target_g != 0:
            check_positive("target_g", self.target_g)
        # PPO's minibatch is min(batch_size, n_steps * num_envs) samples; SB3 needs two
        if not off_policy and self.n_steps * self.num_envs < 2:
            raise InvalidParameterError(
                "n_steps * num_envs (the PPO rollout, and its minibatch size up to batch_size) "
                f"must be >= 2, got n_steps={self.n_steps!r} and num_envs={self.num_envs!r}"
            )
        if self.algorithm == "recurrent_ppo" and self.seq_len != self.n_steps:
            longer = self.seq_len > self.n_steps
            cut = "" if longer else ", which sb3-contrib cannot cut"
            raise InvalidParameterError(
                f"seq_len={self.seq_len!r} is {'longer' if longer else 'shorter'} than the "
                f"rollout, n_steps={self.n_steps!r}{cut}; set n_steps to the LSTM sequence length"
            )
        if not isinstance(self.device, str) or not (
            self.device == "cpu" or self.device.startswith("cuda")
        ):
            raise InvalidParameterError(f"device must be 'cpu' or 'cuda', got {self.device!r}")
        if self.device != "cpu":
            from pourbench.fluids.solver import cuda_available

            if not cuda_available():
                raise InvalidParameterError(f"device={self.device!r}: Warp sees no CUDA device")
        if not isinstance(self.liquid, str) or not self.liquid:
            raise InvalidParameterError(f"liquid must be a liquid name, got {self.liquid!r}")
        if not isinstance(self.eval_liquid, str):
            raise InvalidParameterError(
                f"eval_liquid must be a liquid name or '', got {self.eval_liquid!r}"
            )
        if not isinstance(self.out, str | os.PathLike) or not os.fspath(self.out):
            raise InvalidParameterError(f"out must be a non-empty folder path, got {self.out!r}")
        self.out = os.fspath(self.out)  # a str, as result.json records it

    def eval_liquids(self) -> tuple[str, ...]:
        """The liquids of every evaluation: eval_liquid, else Table 6.2's six with the
        curriculum, else liquid."""
        from pourbench.agents.evaluate import TABLE_6_2

        if self.eval_liquid:
            return (self.eval_liquid,)
        return TABLE_6_2 if self.curriculum else (self.liquid,)


def _save(model: Any, path: Path) -> None:
    """``model`` to ``path`` (``.zip``) through a temporary file."""
    partial = path.with_name(path.stem + ".partial.zip")
    model.save(partial)
    os.replace(partial, path)


def _save_buffer(model: Any, path: Path) -> None:
    """An off-policy ``model``'s replay buffer to ``path`` (``.pkl``) through a temporary
    file."""
    partial = path.with_name(path.stem + ".partial.pkl")
    model.save_replay_buffer(partial)
    os.replace(partial, path)


def _read_state(out: Path, args: TrainArgs) -> dict[str, Any]:
    """The run's ``state.json`` for a resume, checked against ``args``.

    Raises:
        OutputPathError: no ``model.zip`` in ``out``.
        InvalidParameterError: ``state.json`` missing, unreadable or not what a checkpoint
            writes (an object with ``args``, ``timesteps``, ``train_s`` and ``sessions``), or
            a setting of :data:`_SAME_ON_RESUME` that differs from the run's.
    """
    from pourbench.outputs import OutputPathError

    model_path, state_path = out / "model.zip", out / "state.json"
    if not model_path.exists():
        raise OutputPathError(f"--resume: no model to resume from at {str(model_path)!r}")

    def bad(problem: str) -> InvalidParameterError:
        return InvalidParameterError(
            f"--resume: {str(state_path)!r} is missing or unreadable ({problem}); it is "
            "written with every checkpoint"
        )

    try:
        state = json.loads(state_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: not JSON, not UTF-8
        raise bad(f"{type(exc).__name__}: {exc}") from None
    if not isinstance(state, dict):
        raise bad(f"holds a {type(state).__name__}, not an object")
    if not isinstance(state.get("args"), dict):
        raise bad(f"'args' must be an object, got {state.get('args')!r}")
    try:
        check_int("timesteps", state.get("timesteps"), minimum=0)
        check_int("sessions", state.get("sessions"), minimum=0)
        check_finite("train_s", state.get("train_s"), minimum=0.0)
    except InvalidParameterError as exc:
        raise bad(str(exc)) from None
    if not isinstance(state.get("history", []), list):
        raise bad(f"'history' must be a list, got {state['history']!r}")
    best = state.get("best")
    if best is not None and not (
        isinstance(best, dict) and isinstance(best.get("eval_mean_abs_error_g"), int | float)
    ):
        raise bad(f"'best' must be an object with eval_mean_abs_error_g, got {best!r}")
    saved = state["args"]
    defaults = {f.name: f.default for f in fields(TrainArgs)}
    same = (*_SAME_ON_RESUME, *(() if args.curriculum else ("liquid",)))
    for name in same:  # a setting newer than the run has its default there
        had = saved.get(name, defaults[name])
        if had != getattr(args, name):
            raise InvalidParameterError(
                f"--resume: the run in {str(out)!r} has {name}={had!r}, not {getattr(args, name)!r}"
            )
    return state


def lesson_rollout(env: Any, steps: int, lessons: list[int], learner: Any = None) -> Any:
    """:func:`pourbench.agents.warmstart.demonstrate` for ``steps`` vector steps in each of
    ``lessons`` (set on every world of the SB3 VecEnv ``env`` in turn), joined; the worlds
    are left in the first lesson. No lessons: one rollout in the env as it is."""
    from pourbench.agents.models import GAMMA
    from pourbench.agents.warmstart import demonstrate, join

    parts = []
    for k in lessons or [None]:
        if k is not None:
            env.env_method("set_lesson", k)
        parts.append(demonstrate(env, steps, GAMMA, progress=True, learner=learner))
    if lessons:
        env.env_method("set_lesson", lessons[0])
    return join(*parts)


def _warm_start(model: Any, env: Any, args: TrainArgs) -> dict[str, Any]:
    """Clone the PD baseline into ``model`` (:mod:`pourbench.agents.warmstart`) from
    ``args.warm_start_steps`` environment steps of ``env``, then ``args.dagger_rounds``
    DAgger rounds; what it measured (logged under ``clone/`` and kept in ``state.json``;
    ``dagger_mean_abs_error_g``: the clone's own error in each round's rollout). With the
    curriculum and ``args.warm_start_lessons == "all"``, each rollout is split evenly over
    its lessons, so the clone has seen every lesson's liquids before PPO meets them; the
    worlds are left in the first lesson."""
    from pourbench.agents.warmstart import clone, join
    from pourbench.envs.curriculum import load_curriculum

    t0 = time.perf_counter()
    every = args.curriculum and args.warm_start_lessons == "all"
    lessons = list(range(len(load_curriculum()))) if every else []
    steps = -(-args.warm_start_steps // (args.num_envs * max(len(lessons), 1)))
    total = steps * args.num_envs * max(len(lessons), 1)
    print(f"warm start: {total} steps of the PD baseline's demonstrations")
    demos = lesson_rollout(env, steps, lessons)
    if args.residual:  # the PD itself is the residual policy's zero action
        demos = replace(demos, actions=np.zeros_like(demos.actions))
    print(
        f"warm start: the PD poured {len(demos.errors_g)} episodes, mean error "
        f"{demos.mean_abs_error_g:.2f} g; cloning for {args.clone_epochs} epochs"
    )
    std = args.clone_std or None
    stats = clone(model, demos, args.clone_epochs, seed=args.seed, std=std, progress=True)
    out: dict[str, Any] = {
        "steps": total,
        "episodes": len(demos.errors_g),
        "pd_mean_abs_error_g": demos.mean_abs_error_g,
        **stats,
    }
    rounds: list[float] = []
    for k in range(1, args.dagger_rounds + 1):
        new = lesson_rollout(env, steps, lessons, learner=model)
        rounds.append(new.mean_abs_error_g)
        demos = join(demos, new)
        print(
            f"DAgger round {k}: the clone poured {len(new.errors_g)} episodes, mean error "
            f"{new.mean_abs_error_g:.2f} g; fitting to {k + 1} rollouts"
        )
        # as many gradient steps as the first fit, over all the labelled rollouts
        epochs = max(1, round(args.clone_epochs / (k + 1)))
        out.update(clone(model, demos, epochs, seed=args.seed + k, std=std, progress=True))
    if rounds:
        out["dagger_mean_abs_error_g"] = rounds
    out["seconds"] = time.perf_counter() - t0
    for key, value in out.items():
        if not isinstance(value, list):
            model.logger.record(f"clone/{key}", value)
    model.logger.dump(0)
    return out


def train(
    args: TrainArgs,
    command: str | None = None,
    report: Callable[[dict[str, Any], Path], None] | None = None,
) -> dict:
    """Train until the budget is spent, write the plot, evaluate against a random policy;
    the result (also written to ``<out>/result.json``). ``command`` is recorded as the
    session's command line (None: this process's ``pourbench …`` arguments). ``report``
    is called with each periodic evaluation's metrics (``timesteps``, ``mean_abs_error_g``,
    ``success_rate``, ``train_s``) and the run's folder once the checkpoint beside them is
    written, and with the final evaluation's (``finished`` True) at the end: a sweep's trial
    passes them to Ray Tune (:mod:`pourbench.agents.sweep`)."""
    from pourbench.envs.options import known_liquid
    from pourbench.outputs import OutputPathError, check_output_folder, write_text_atomic

    for name in filter(None, (args.liquid, args.eval_liquid)):
        known_liquid(name)  # before any work: a typo fails in a second
    out = check_output_folder(args.out)
    model_path, icm_path, best_path = out / "model.zip", out / "icm.pt", out / "best_model.zip"
    buffer_path = out / "replay_buffer.pkl"
    off_policy = args.algorithm in OFF_POLICY
    state: dict[str, Any] = {"timesteps": 0, "train_s": 0.0, "sessions": 0, "history": []}
    if args.resume:
        state = _read_state(out, args)
    elif model_path.exists():
        raise OutputPathError(
            f"{str(model_path)!r} exists; pass --resume to continue it or another --out"
        )
    left_s = None if args.budget_s is None else args.budget_s - state["train_s"]
    left_steps = None if args.budget_steps is None else args.budget_steps - state["timesteps"]
    if (left_s is not None and left_s <= 0) or (left_steps is not None and left_steps <= 0):
        raise InvalidParameterError(
            f"--resume: the run in {str(out)!r} has spent its budget ({state['timesteps']} "
            f"steps, {state['train_s']:.0f} s); give a larger --budget-steps or --budget-s"
        )

    import torch
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecMonitor
    from tqdm import TqdmExperimentalWarning

    from pourbench.agents import directed
    from pourbench.agents.callbacks import BudgetCallback, EvalCallback, PourStatsCallback
    from pourbench.agents.evaluate import EvalResult, evaluate
    from pourbench.agents.icm import ICMConfig, ICMVecEnv
    from pourbench.agents.loading import load_model, model_policy
    from pourbench.agents.models import make_model, set_policy_std
    from pourbench.agents.plots import plot_training
    from pourbench.agents.residual import ResidualVecEnv, start_residual
    from pourbench.agents.sb3 import SB3PourVecEnv
    from pourbench.agents.schedule import CurriculumCallback
    from pourbench.envs.curriculum import lesson_at, load_curriculum
    from pourbench.provenance import provenance

    torch.set_num_threads(args.threads)
    env_kw: dict[str, Any] = {"liquid": None if args.curriculum else args.liquid}
    if args.curriculum:  # a resumed run's first episodes are already in its lesson
        if args.budget_steps is not None:
            done = state["timesteps"] / args.budget_steps
        else:
            done = state["train_s"] / float(args.budget_s)  # type: ignore[arg-type]
        env_kw["lesson"] = lesson_at(done, load_curriculum())
        env_kw["rehearse"] = args.rehearse
    if args.target_g:
        env_kw["target_range_g"] = (args.target_g, args.target_g)
    if args.device != "cpu":
        from pourbench.envs import default_solver_config

        env_kw["solver"] = replace(default_solver_config(), device=args.device)
    if args.final_error_per_g or args.progress_per_g or args.shaping:
        from pourbench.agents.models import GAMMA
        from pourbench.envs.reward import RewardConfig

        env_kw["reward"] = RewardConfig(
            final_error_per_g=args.final_error_per_g,
            progress_per_g=args.progress_per_g,
            shaping=args.shaping,
            shaping_gamma=GAMMA,
        )
    base = SB3PourVecEnv(
        args.num_envs, seed=args.seed + 1000 * state["sessions"], workers=args.workers or None,
        **env_kw,
    )  # fmt: skip
    venv: Any = VecMonitor(base)
    if args.residual:
        venv = ResidualVecEnv(venv, args.residual)
    tolerance_g = base.venv.config.tolerance_g if args.directed_tilt else None
    tilt_target = directed.TiltTarget.of(base.venv.config) if args.tilt_target else None
    if args.directed_tilt or args.directed_approach or args.tilt_target:
        venv = directed.DirectedTiltVecEnv(venv, tolerance_g, args.directed_approach, tilt_target)
    icm = None
    if args.icm:
        icm = venv = ICMVecEnv(venv, ICMConfig(eta=args.icm_eta, update_every=args.n_steps))
    try:
        if args.resume:
            model = load_model(model_path, env=venv)
            if icm is not None:
                icm.load(icm_path)
            if off_policy and buffer_path.exists():
                model.load_replay_buffer(buffer_path)
            elif off_policy:
                print(f"no replay buffer at {buffer_path}: the resumed run starts with none")
            print(f"resuming {model_path} at {model.num_timesteps} timesteps")
        else:
            model = make_model(
                args.algorithm,
                venv,
                n_steps=args.n_steps,
                batch_size=args.batch_size,
                seed=args.seed,
                learning_rate=args.learning_rate,
                lr_schedule=args.lr_schedule,
                target_kl=args.target_kl or None,
                sde=args.sde,
                utd=args.utd,
                ent_coef=args.ent_coef,
            )
            if args.residual:  # with a warm start, the cloning then sets the spread anew
                start_residual(model, args.residual, args.clone_std or None)
            if args.init_std:
                set_policy_std(model, args.init_std)
            directed.mark(model, tolerance_g, args.directed_approach, tilt_target)
        directed.mark(model, None, False, handler_tolerance_g=base.venv.config.tolerance_g)
        log_dir = out / "logs" / str(state["sessions"])
        model.set_logger(configure(str(log_dir), ["stdout", "csv", "tensorboard"]))
        t_start = time.perf_counter()
        liquids = args.eval_liquids()
        per_liquid = -(-args.eval_episodes // len(liquids))
        eval_kw = {"target_g": args.target_g or None, "seed": 1000}

        def evaluate_all(policy: Any, log: bool = False) -> EvalResult:
            """``policy`` on the evaluation's liquids; ``log``: record each liquid's mean
            error (``eval/<liquid>/mean_abs_error_g``) where there are several."""
            runs = {name: evaluate(policy, per_liquid, progress=True, liquid=name, **eval_kw)
                    for name in liquids}  # fmt: skip
            if log and len(runs) > 1:
                for name, res in runs.items():
                    model.logger.record(f"eval/{name}/mean_abs_error_g", res.mean_abs_error_g)
            return EvalResult.join(*runs.values())

        def spent_s() -> float:
            return state["train_s"] + time.perf_counter() - t_start

        def evaluate_now() -> Any:
            """Evaluate the model (its training wall time so far logged beside, as
            ``eval/train_s``); keep it as ``best_model.zip`` when no evaluation of this run
            (the clone's included) has had a smaller mean error."""
            model.logger.record("eval/train_s", spent_s())
            result = evaluate_all(model_policy(model), log=True)
            best, error = state.get("best"), result.mean_abs_error_g
            if not math.isnan(error) and (best is None or error < best["eval_mean_abs_error_g"]):
                _save(model, best_path)
                state["best"] = {
                    "timesteps": int(model.num_timesteps),
                    "eval_mean_abs_error_g": result.mean_abs_error_g,
                    "eval_success_rate": result.success_rate,
                }
            return result

        if args.warm_start_steps and not args.resume:
            state["warm_start"] = _warm_start(model, base, args)
            if args.eval_every_steps:  # the clone, on the episodes every evaluation uses
                cloned = evaluate_now()
                state["warm_start"]["eval_mean_abs_error_g"] = cloned.mean_abs_error_g
                state["warm_start"]["eval_success_rate"] = cloned.success_rate
                print(f"evaluation of the clone: {cloned.summary()}")
                model.logger.dump(0)  # its rows per liquid, at step 0
            if left_s is not None:
                left_s -= time.perf_counter() - t_start

        stamp = provenance()  # this session's, for state.json's history
        if command is not None:
            stamp["command"] = command

        def checkpoint() -> None:
            _save(model, model_path)
            if icm is not None:
                icm.save(icm_path)
            if off_policy:
                _save_buffer(model, buffer_path)
            steps, total_s = int(model.num_timesteps), spent_s()
            session = {**stamp, "timesteps": steps, "session_s": total_s - state["train_s"]}
            now = {
                "args": asdict(args),
                "timesteps": steps,
                "train_s": total_s,
                "sessions": state["sessions"] + 1,
                "history": [*state.get("history", []), session],
                **{k: state[k] for k in ("warm_start", "best") if k in state},
            }
            write_text_atomic(out / "state.json", json.dumps(now, indent=2) + "\n")

        def progress(steps: int) -> float:
            if args.budget_steps is not None:
                return steps / args.budget_steps
            return spent_s() / float(args.budget_s)  # type: ignore[arg-type]

        def metrics(result: EvalResult, **more: Any) -> dict[str, Any]:
            return {
                "timesteps": int(model.num_timesteps),
                "mean_abs_error_g": result.mean_abs_error_g,
                "success_rate": result.success_rate,
                "train_s": spent_s(),
                **more,
            }

        def evaluate_and_report() -> EvalResult:
            result = evaluate_now()
            if report is not None:
                checkpoint()
                report(metrics(result, finished=False), out)
            return result

        callbacks: list[Any] = [
            PourStatsCallback(icm),
            BudgetCallback(left_s, args.checkpoint_s, checkpoint),
        ]
        if args.curriculum:
            callbacks.append(CurriculumCallback(progress, verbose=1))
        if args.eval_every_steps:
            callbacks.append(EvalCallback(args.eval_every_steps, evaluate_and_report))
        # SB3's progress bar is tqdm.rich, which warns that it is experimental
        warnings.filterwarnings("ignore", category=TqdmExperimentalWarning)
        model.learn(
            total_timesteps=left_steps if left_steps is not None else 10**12,
            callback=callbacks,
            reset_num_timesteps=not args.resume,
            progress_bar=left_steps is not None,
        )
        checkpoint()
    finally:
        venv.close()
    train_s = time.perf_counter() - t_start
    plot = plot_training(out)
    print(f"wrote {plot}")
    final = evaluate_now()
    saved = json.loads((out / "state.json").read_text())  # with the final evaluation's best
    write_text_atomic(
        out / "state.json", json.dumps({**saved, "best": state.get("best")}, indent=2) + "\n"
    )
    rnd, pd = evaluate_all("random"), evaluate_all("pd")
    result = {
        "args": asdict(args),
        "train_s": train_s,
        "total_train_s": state["train_s"] + train_s,
        "timesteps": int(model.num_timesteps),
        "mean_abs_error_g": final.mean_abs_error_g,
        "random_mean_abs_error_g": rnd.mean_abs_error_g,
        "pd_mean_abs_error_g": pd.mean_abs_error_g,
        "policy": final.summary(),
        "random": rnd.summary(),
        "pd": pd.summary(),
        "plot": str(plot),
        "warm_start": state.get("warm_start"),
        "best": state.get("best"),
        "provenance": stamp,
    }
    write_text_atomic(out / "result.json", json.dumps(result, indent=2) + "\n")
    if report is not None:
        pd_g, random_g = pd.mean_abs_error_g, rnd.mean_abs_error_g
        report(metrics(final, pd_mean_abs_error_g=pd_g, random_mean_abs_error_g=random_g,
                       finished=True), out)  # fmt: skip
    return result


DESCRIPTION = (
    "Train PourNet on Pour-v0 (PPO with an MLP, RecurrentPPO with an LSTM, or the off-policy "
    "SAC, TQC, CrossQ or TD3; curiosity module and liquid curriculum on by default) and compare it "
    "with a random policy."
)


@dataclass
class _Flags(TrainArgs):
    """TrainArgs as tyro parses them: checked when :func:`parse_args` makes them TrainArgs,
    so that a bad setting is refused in pourbench's one line."""

    def __post_init__(self) -> None:
        pass


def parse_args(argv: Sequence[str] | None, prog: str) -> TrainArgs:
    """:class:`TrainArgs` from command-line flags: one ``--flag`` per field, its help from the
    field's line above, switches as ``--icm`` / ``--no-icm`` (tyro). A flag that does not
    parse exits with tyro's message; a bad setting raises the :class:`PourbenchError` of
    TrainArgs' checks."""
    import tyro

    flags = tyro.cli(_Flags, args=argv, prog=prog, description=DESCRIPTION)
    return TrainArgs(**asdict(flags))


def main(argv: Sequence[str] | None = None, prog: str = "python -m pourbench.agents.train") -> int:
    """Train with the flags ``argv`` and print the result JSON; bad input is one line on
    stderr and exit status 2, before any work."""
    words = list(sys.argv[1:] if argv is None else argv)
    try:
        result = train(parse_args(words, prog), shlex.join([*prog.split(), *words]))
    except PourbenchError as exc:  # bad input: one clear line, no traceback
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
