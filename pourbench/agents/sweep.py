"""``pourbench sweep CONFIG.toml``: a grid or random search over ``pourbench train``
settings on Ray Tune (the ``ray`` extra).

Each trial is one :func:`pourbench.agents.train.train` run as a Tune function trainable.
Every periodic evaluation reports the run's average pouring error (``mean_abs_error_g``,
Table 6.2's liquids or ``eval_liquid``) through ``tune.report``, with the run's checkpoint
(model, curiosity module, state). A trial that fails or whose worker dies restarts from its
last report (``max_failures``; before its first report: from the last checkpoint its run
wrote, else afresh), and a sweep whose command was stopped resumes where it was when the
same command runs again; a sweep folder is resumed only with the config it was started with
(its ``sweep_config.json`` holds that config and its hash), and any other is refused, naming
the keys that changed. The sweep's folder (``<out>/<name>``, Tune's experiment
folder) ends with ``sweep.md`` and ``sweep.json`` (one row per trial) and ``sweep.png`` (each
trial's evaluation error against steps).

The config (``pourbench/assets/sweeps/icm_curriculum.toml`` is a sample):

* ``[sweep]``: ``name`` (the folder), ``samples`` (Tune's ``num_samples``: the grid is run
  that many times, each with fresh draws), ``seed`` (of the draws), ``cpus_per_trial``,
  ``max_failures``;
* ``[train]``: settings every trial shares (``pourbench train``'s flags, as TOML keys with
  underscores);
* ``[search]``: the settings searched. A list is a grid (every value); a table of one key
  draws a value per trial: ``{loguniform = [lo, hi]}``, ``{uniform = [lo, hi]}``,
  ``{randint = [lo, hi]}`` (hi excluded) or ``{choice = [a, b, …]}``.

Every setting is checked when the config is read, against :class:`TrainArgs` with each
grid value and each draw's bounds, then each trial's settings as the sweep makes them (every
grid combination, with each draw at its bounds or choices, and ``workers`` =
``cpus_per_trial``), so a bad config fails in a second, naming the file and the key. An
integer setting is searched by a grid, ``randint`` or ``choice``, not ``uniform`` or
``loguniform``, which draw floats. Ray starts on this machine's cores unless ``--address``
joins a cluster (docs/ray.md).
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import math
import shutil
import sys
import tempfile
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, get_type_hints

from pourbench.agents.train import TrainArgs
from pourbench.errors import InvalidParameterError

DISTRIBUTIONS = ("loguniform", "uniform", "randint", "choice")
RESERVED = ("out", "resume")
"""Settings a sweep sets itself: each trial's folder, and resuming from its checkpoint."""
CHECKPOINT_FILES = ("model.zip", "icm.pt", "state.json")
METRIC = "mean_abs_error_g"
SWEEP_KEYS = {"name": str, "samples": int, "seed": int, "cpus_per_trial": int, "max_failures": int}


@dataclass(frozen=True)
class Sweep:
    """A checked sweep config (:func:`load_sweep`)."""

    name: str
    train: dict[str, Any]
    search: dict[str, Any]
    samples: int = 1
    seed: int = 0
    cpus_per_trial: int = 1
    max_failures: int = 2
    path: Path = field(default=Path("sweep.toml"), compare=False)

    def param_space(self) -> dict[str, Any]:
        """Tune's ``param_space``: grid lists as ``grid_search``, tables as distributions."""
        from ray import tune

        space: dict[str, Any] = {}
        for key, value in self.search.items():
            if isinstance(value, list):
                space[key] = tune.grid_search(value)
            else:
                (kind, spec), = value.items()  # fmt: skip
                space[key] = tune.choice(spec) if kind == "choice" else getattr(tune, kind)(*spec)
        return space

    def trial_args(self, config: dict[str, Any], out: Path, resume: bool) -> TrainArgs:
        """The training settings of the trial whose searched values are ``config``."""
        settings = {"workers": self.cpus_per_trial, "threads": 1, **self.train, **config}
        return TrainArgs(**settings, out=str(out), resume=resume)


def _fail(path: Path, key: str, message: str) -> InvalidParameterError:
    return InvalidParameterError(f"{path}: {key}: {message}")


def _check_train(path: Path, key: str, settings: dict[str, Any]) -> None:
    from pourbench.envs.options import known_liquid

    try:
        TrainArgs(**settings)
        for name in ("liquid", "eval_liquid"):
            if settings.get(name):
                known_liquid(settings[name])
    except (TypeError, ValueError) as exc:
        raise _fail(path, key, str(exc)) from None


def load_sweep(path: str | Path) -> Sweep:
    """Read and check the sweep config at ``path`` (module docstring); every error names the
    file and the key."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidParameterError(f"{path}: cannot read the sweep config ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InvalidParameterError(f"{path}: not valid TOML ({exc})") from None
    for section in data:
        if section not in ("sweep", "train", "search"):
            raise _fail(path, section, "unknown section (sweep, train and search are known)")
        if not isinstance(data[section], dict):
            raise _fail(path, section, "must be a table ([section])")
    head, train, search = (data.get(k, {}) for k in ("sweep", "train", "search"))
    for key, value in head.items():
        kind = SWEEP_KEYS.get(key)
        if kind is None:
            raise _fail(path, f"sweep.{key}", f"unknown key (known: {', '.join(SWEEP_KEYS)})")
        if not isinstance(value, kind) or isinstance(value, bool):
            raise _fail(path, f"sweep.{key}", f"must be {kind.__name__}, got {value!r}")
    name = head.get("name", path.stem)
    if not name or "/" in name or name.startswith("."):
        raise _fail(path, "sweep.name", f"must be a folder name, got {name!r}")
    for key, low in (("samples", 1), ("cpus_per_trial", 1), ("max_failures", 0), ("seed", 0)):
        if head.get(key, low) < low:
            raise _fail(path, f"sweep.{key}", f"must be at least {low}, got {head[key]!r}")
    known = {f.name for f in fields(TrainArgs)}
    for section, table in (("train", train), ("search", search)):
        for key in table:
            if key not in known:
                raise _fail(path, f"{section}.{key}", "not a setting of pourbench train")
            if key in RESERVED:
                raise _fail(path, f"{section}.{key}", "set by the sweep for each trial")
    if not search:
        raise _fail(path, "search", "no setting to search")
    for key in search:
        if key in train:
            raise _fail(path, f"search.{key}", "also given in [train]")
    _check_train(path, "train", train)
    for key, value in search.items():
        for candidate in _candidates(path, key, value):
            _check_train(path, f"search.{key}", {**train, key: candidate})
    grid = math.prod(len(v) for v in search.values() if isinstance(v, list))
    if grid * head.get("samples", 1) > 10_000:
        raise _fail(path, "search", "more than 10,000 trials")
    sweep = Sweep(name=name, train=train, search=search, path=path,
                  **{k: head[k] for k in SWEEP_KEYS if k in head and k != "name"})  # fmt: skip
    _check_trials(sweep)
    return sweep


CONFIG_RECORD = "sweep_config.json"
"""File in a sweep's folder holding the config the sweep was started with and its hash."""


def config_record(sweep: Sweep) -> dict[str, Any]:
    """The sweep's settings that shape its trials (``sweep``, ``train`` and ``search``
    tables, defaults filled in) and the sha256 of their canonical JSON."""
    settings = {
        "sweep": {"name": sweep.name, **{k: getattr(sweep, k) for k in SWEEP_KEYS if k != "name"}},
        "train": sweep.train,
        "search": sweep.search,
    }
    text = json.dumps(settings, sort_keys=True)
    return {"sha256": hashlib.sha256(text.encode()).hexdigest(), "config": settings}


def _flat(settings: dict[str, Any]) -> dict[str, Any]:
    return {f"{table}.{key}": v for table, values in settings.items() for key, v in values.items()}


def check_resume(folder: Path, sweep: Sweep) -> None:
    """Refuse to resume the sweep folder ``folder`` with a config other than the one it was
    started with (Tune would restore the old search space and run it with the new shared
    settings): the error names the folder and the keys that differ. A folder with Tune's
    state but no record of its config is refused too, since it cannot be checked."""
    record = folder / CONFIG_RECORD
    if not record.is_file():
        raise InvalidParameterError(
            f"{folder} holds a sweep with no record of its config ({CONFIG_RECORD}), so it "
            "cannot be checked against this one: give the sweep another name, or remove the "
            "folder to start it again"
        )
    try:
        stored = json.loads(record.read_text(encoding="utf-8"))
        old, stored_hash = stored["config"], stored["sha256"]
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise InvalidParameterError(f"{record}: not a sweep config record ({exc})") from None
    new = config_record(sweep)
    if stored_hash == new["sha256"]:
        return
    before, after = _flat(old), _flat(new["config"])
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    raise InvalidParameterError(
        f"{folder} was started with another config: {', '.join(changed) or 'its hash'} "
        f"changed; resume it with the config it was started with, give the sweep another "
        f"name, or remove the folder to start it again"
    )


def _check_trials(sweep: Sweep) -> None:
    """Every trial's settings through :meth:`Sweep.trial_args`, as :func:`run_trial` makes
    them: each combination of the grids' values and the draws' bounds or choices."""
    keys = list(sweep.search)
    candidates = [_candidates(sweep.path, k, sweep.search[k]) for k in keys]
    implied = "workers" not in sweep.train and "workers" not in sweep.search
    for values in itertools.product(*candidates):
        config = dict(zip(keys, values, strict=True))
        try:
            sweep.trial_args(config, Path("trial"), resume=False)
        except (TypeError, ValueError) as exc:
            why = str(exc)
            if implied and "workers" in why:
                why += f" (each trial's workers is sweep.cpus_per_trial, {sweep.cpus_per_trial})"
            raise _fail(sweep.path, "search", f"the trial {config}: {why}") from None


def _candidates(path: Path, key: str, value: Any) -> list[Any]:
    """The values of a ``[search]`` entry to check against TrainArgs: a grid's values, a
    draw's bounds or choices."""
    where = f"search.{key}"
    if isinstance(value, list):
        if not value:
            raise _fail(path, where, "an empty grid")
        return value
    if not isinstance(value, dict) or len(value) != 1:
        raise _fail(path, where, "must be a list (a grid) or a table of one distribution")
    (kind, spec), = value.items()  # fmt: skip
    if kind not in DISTRIBUTIONS:
        raise _fail(path, where, f"unknown distribution {kind!r} (known: {DISTRIBUTIONS})")
    if not isinstance(spec, list) or not spec:
        raise _fail(path, where, f"{kind} takes a list, got {spec!r}")
    if kind == "choice":
        return spec
    if kind in ("uniform", "loguniform") and get_type_hints(TrainArgs)[key] in (int, int | None):
        raise _fail(path, where, f"{kind} draws floats; {key} is an integer: use randint or a grid")
    if len(spec) != 2 or not all(isinstance(v, int | float) for v in spec):
        raise _fail(path, where, f"{kind} takes [low, high], got {spec!r}")
    low, high = spec
    if not low < high:
        raise _fail(path, where, f"{kind} needs low < high, got {spec!r}")
    if kind == "loguniform" and low <= 0:
        raise _fail(path, where, f"loguniform needs low > 0, got {spec!r}")
    if kind == "randint":
        if not all(isinstance(v, int) for v in spec):
            raise _fail(path, where, f"randint takes integers, got {spec!r}")
        return [low, high - 1]
    return [low, high]


def _resumes(out: Path, restored: bool) -> bool:
    """Whether the trial's run in ``out`` resumes: from Tune's checkpoint (``restored``, copied
    there), or from the run's own checkpoint when it died before its first report (its
    ``state.json`` is written with every checkpoint); otherwise it starts afresh, and what a
    run that died before its first checkpoint left in ``out`` is removed."""
    if restored or (out / "state.json").is_file():
        return True
    if out.exists():
        shutil.rmtree(out)
    return False


def run_trial(config: dict[str, Any], sweep: Sweep) -> None:
    """Tune's function trainable: train with the trial's ``config``, resuming when the trial
    restarts (:func:`_resumes`), and report each evaluation with its checkpoint."""
    from ray import tune

    out = Path(tune.get_context().get_trial_dir()) / "run"
    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:
        out.mkdir(parents=True, exist_ok=True)
        with checkpoint.as_directory() as saved:
            for name in CHECKPOINT_FILES:
                if (Path(saved) / name).is_file():
                    shutil.copy2(Path(saved) / name, out / name)
    resume = _resumes(out, restored=checkpoint is not None)

    def report(metrics: dict[str, Any], run: Path) -> None:
        with tempfile.TemporaryDirectory() as folder:
            for name in CHECKPOINT_FILES:
                if (run / name).is_file():
                    shutil.copy2(run / name, folder)
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(folder))

    from pourbench.agents.train import train

    args = sweep.trial_args(config, out, resume=resume)
    train(args, command=f"pourbench sweep {sweep.path} (trial {config})", report=report)


def trial_rows(grid: Any, sweep: Sweep) -> tuple[list[dict[str, Any]], dict[str, list]]:
    """One row per trial of Tune's ``ResultGrid`` (its searched values, last and best
    evaluation, steps, status), and each trial's (steps, error) evaluation curve."""
    rows, curves = [], {}
    for result in grid:
        config = {k: result.config.get(k) for k in sweep.search}
        label = ", ".join(f"{k}={_short(v)}" for k, v in config.items())
        if label in curves:  # a grid point's repeat (samples > 1)
            label += f" (#{sum(lab.startswith(label) for lab in curves) + 1})"
        frame = result.metrics_dataframe
        evaluations = [] if frame is None or METRIC not in frame else frame[METRIC].tolist()
        steps = [] if frame is None or "timesteps" not in frame else frame["timesteps"].tolist()
        metrics = result.metrics or {}
        status = "done" if metrics.get("finished") else "stopped"
        rows.append(
            {
                "trial": label,
                **config,
                "timesteps": metrics.get("timesteps"),
                "final_error_g": metrics.get(METRIC),
                "best_error_g": min(evaluations) if evaluations else None,
                "pd_error_g": metrics.get("pd_mean_abs_error_g"),
                "random_error_g": metrics.get("random_mean_abs_error_g"),
                "status": "error" if result.error else status,
            }
        )
        curves[label] = list(zip(steps, evaluations, strict=True))
    rows.sort(key=lambda r: math.inf if r["final_error_g"] is None else r["final_error_g"])
    return rows, curves


def _short(value: Any) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def plot_curves(curves: dict[str, list], path: Path, title: str) -> Path:
    """Each trial's evaluation error against steps, as one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label, points in curves.items():
        if points:
            xs, ys = zip(*points, strict=True)
            ax.plot(xs, ys, marker="o", label=label)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("evaluation mean abs error, g")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def run_sweep(config: str | Path, out: str | Path = "runs/sweeps", address: str | None = None):
    """Run (or resume) the sweep of ``config`` into ``<out>/<name>`` on a local Ray, or on the
    cluster at ``address``; write its table and plot there. Returns the table's rows."""
    from pourbench.bench._jobs import import_ray, init_ray
    from pourbench.bench._report import markdown_table, write_report
    from pourbench.outputs import check_output_folder

    sweep = load_sweep(config)
    import_ray()
    from ray import tune
    from ray.tune.search.basic_variant import BasicVariantGenerator

    storage = check_output_folder(out).resolve()
    folder = storage / sweep.name
    resuming = tune.Tuner.can_restore(str(folder))
    if resuming:
        check_resume(folder, sweep)
    started = init_ray(address or "local")
    try:
        trainable = tune.with_resources(
            tune.with_parameters(run_trial, sweep=sweep), {"cpu": sweep.cpus_per_trial}
        )
        if resuming:
            print(f"sweep: resuming {folder}", file=sys.stderr)
            tuner = tune.Tuner.restore(str(folder), trainable, resume_errored=True)
        else:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / CONFIG_RECORD).write_text(json.dumps(config_record(sweep), indent=1))
            tuner = tune.Tuner(
                trainable,
                param_space=sweep.param_space(),
                tune_config=tune.TuneConfig(
                    metric=METRIC,
                    mode="min",
                    num_samples=sweep.samples,
                    search_alg=BasicVariantGenerator(random_state=sweep.seed),
                ),
                run_config=tune.RunConfig(
                    name=sweep.name,
                    storage_path=str(storage),
                    failure_config=tune.FailureConfig(max_failures=sweep.max_failures),
                    checkpoint_config=tune.CheckpointConfig(num_to_keep=2),
                    verbose=1,
                ),
            )
        grid = tuner.fit()
    finally:
        if started:
            import_ray().shutdown()
    rows, curves = trial_rows(grid, sweep)
    plot = plot_curves(curves, folder / "sweep.png", f"sweep {sweep.name}")
    columns = ["trial", *sweep.search, "timesteps", "final_error_g", "best_error_g",
               "pd_error_g", "random_error_g", "status"]  # fmt: skip
    body = "\n".join(
        [
            f"Config: `{sweep.path}`. Shared settings: "
            + ", ".join(f"`{k}` = {v!r}" for k, v in sweep.train.items())
            + ". Searched: "
            + ", ".join(f"`{k}` {v!r}" for k, v in sweep.search.items())
            + f"; {sweep.samples} sample(s), seed {sweep.seed}.",
            "",
            "Columns: `final_error_g`, the mean absolute pouring error of the trial's final "
            "evaluation, g; `best_error_g`, its best evaluation; `pd_error_g` / "
            "`random_error_g`, the PD baseline and a random policy on the same episodes. "
            f"Curves: [{plot.name}]({plot.name}).",
            "",
            markdown_table(rows, columns),
        ]
    )
    write_report("sweep", rows, out=folder, title=f"Sweep {sweep.name}", body_md=body,
                 extra={"search": sweep.search, "train": sweep.train})  # fmt: skip
    print(markdown_table(rows, columns))
    print(f"wrote {folder / 'sweep.md'} and {plot}", file=sys.stderr)
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="the sweep's TOML config (pourbench.agents.sweep)")
    parser.add_argument("--out", default="runs/sweeps", help="folder holding the sweep's folder")
    parser.add_argument(
        "--address",
        default=None,
        help="join the Ray cluster at this address (auto: the one `ray start` began here); "
        "default: a local Ray on this machine's cores",
    )


def run(args: argparse.Namespace) -> int:
    rows = run_sweep(args.config, args.out, args.address)
    failed = [r["trial"] for r in rows if r["status"] == "error"]
    if failed:
        print(f"sweep: {len(failed)} trial(s) failed: {'; '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


def sample_config() -> Path:
    """The shipped sample sweep config."""
    return Path(__file__).resolve().parent.parent / "assets" / "sweeps" / "icm_curriculum.toml"
