"""Leaderboard writing shared by every benchmark suite.

Each suite produces rows (dicts of plain values) and hands them to :func:`write_report`,
which writes ``<out>/<suite>.json`` and ``<out>/<suite>.md`` stamped with the command line,
git SHA and machine, so every committed number says where it came from.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pourbench.errors import InvalidParameterError
from pourbench.provenance import git_sha as git_sha  # re-exported for the suites
from pourbench.provenance import provenance


def devices(choice: str, quick: bool = False) -> list[str]:
    """The devices a suite times for ``--device``: ``auto`` is the CPU plus CUDA when Warp sees
    a device (not in a quick run), ``cpu`` / ``cuda`` that device alone."""
    if choice not in ("auto", "cpu", "cuda"):
        raise InvalidParameterError(f"device must be 'auto', 'cpu' or 'cuda', got {choice!r}")
    if choice in ("cpu", "cuda"):
        return [choice]
    from pourbench.fluids.solver import cuda_available

    return ["cpu"] + (["cuda"] if not quick and cuda_available() else [])


def report_stem(suite: str, choice: str) -> str:
    """Leaderboard file stem: a CUDA-only run writes ``<suite>_cuda`` beside the CPU table."""
    return f"{suite}_cuda" if choice == "cuda" else suite


def accelerator(rows: Sequence[dict[str, Any]]) -> str | None:
    """Name of the CUDA device, when any row ran on one."""
    if not any(r.get("device") == "cuda" for r in rows):
        return None
    import warp as wp

    dev = wp.get_device("cuda")
    return f"{dev.name} (sm_{dev.arch}), Warp {wp.config.version}"


def markdown_table(rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None) -> str:
    """A GitHub markdown table of ``rows`` restricted to ``columns`` (None: the first row's
    keys, in their order)."""
    if columns is None:
        columns = list(rows[0]) if rows else []

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return "–" if v is None else str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


STAMP_KEYS = ("suite", "command", "git_sha", "machine", "load", "accelerator", "date", "rows")
"""The top-level fields :func:`write_report` writes itself (``suite``, the provenance, and
``rows``); ``extra`` may not set them."""

_STEM = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


def _plain(value: Any, where: str) -> Any:
    """``value`` with NumPy scalars and arrays made plain Python values, NaN made ``None``
    (JSON ``null``, as a missing value is written) and ±inf the strings ``"inf"`` /
    ``"-inf"`` (e.g. the clearance with no obstacle), so the file is strict JSON.

    Raises:
        InvalidParameterError: a value JSON cannot hold (named by ``where``).
    """
    if isinstance(value, np.ndarray | np.generic):
        value = value.tolist()
    if isinstance(value, float):  # JSON has no inf: "inf" / "-inf", and NaN as missing
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return value if value == value else None
    if value is None or isinstance(value, str | bool | int):
        return value
    if isinstance(value, Mapping):
        return {str(k): _plain(v, f"{where}[{k!r}]") for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    raise InvalidParameterError(f"{where} is not a JSON value: {value!r}")


def write_report(
    suite: str,
    rows: Sequence[dict[str, Any]],
    *,
    out: str | Path = "leaderboard",
    title: str,
    body_md: str,
    extra: dict[str, Any] | None = None,
    git_sha_at_start: str | None = None,
) -> tuple[Path, Path]:
    """Write ``<out>/<suite>.json`` (rows + provenance) and ``<out>/<suite>.md``.

    Everything is checked and both texts are rendered before either file is written, and
    both files are written through temporary siblings and moved into place together, so bad
    input leaves an earlier pair as it was. NumPy scalars are written as plain numbers, a
    NaN as ``null`` (a missing value, as rows write ``None``) and ±inf as ``"inf"`` /
    ``"-inf"``, so the JSON is strict.

    Args:
        suite: file stem, e.g. ``"fluids"`` (letters, digits, ``_``, ``-`` and ``.``, no
            folders).
        rows: one dict per measured case.
        out: folder to write into (created if missing).
        title: markdown heading.
        body_md: the suite's tables and notes in markdown (provenance is added here).
        extra: more top-level JSON fields, none of :data:`STAMP_KEYS`.
        git_sha_at_start: the SHA a long run started at (:func:`git_sha` then), stamped in
            place of the SHA at writing, which later commits during the run would move.

    Raises:
        InvalidParameterError: a bad suite name, rows that are not a list of dicts, a title
            or body that is not text, an ``extra`` field named as one the report writes
            itself, or a value JSON cannot hold; an output path that is a folder
            (``OutputPathError``).
    """
    from pourbench.outputs import AtomicOutput, check_output_folder

    if not isinstance(suite, str) or not _STEM.fullmatch(suite):
        raise InvalidParameterError(
            f"suite must be a plain file stem (letters, digits, _ - .), got {suite!r}"
        )
    if isinstance(rows, str | bytes | Mapping) or not isinstance(rows, Sequence):
        raise InvalidParameterError(f"rows must be a list of dicts, got {rows!r}")
    rows = list(rows)
    for i, r in enumerate(rows):
        if not isinstance(r, Mapping):
            raise InvalidParameterError(f"rows[{i}] must be a dict, got {r!r}")
    for name, text in (("title", title), ("body_md", body_md)):
        if not isinstance(text, str):
            raise InvalidParameterError(f"{name} must be a str, got {text!r}")
    if extra is not None and not isinstance(extra, Mapping):
        raise InvalidParameterError(f"extra must be a dict or None, got {extra!r}")
    clash = sorted(str(k) for k in extra or {} if str(k) in STAMP_KEYS)
    if clash:
        raise InvalidParameterError(
            f"extra must not set the report's own fields {clash} (they are {list(STAMP_KEYS)})"
        )
    plain_rows = _plain(rows, "rows")
    plain_extra = _plain(dict(extra or {}), "extra")

    out = check_output_folder(out)
    outputs = [AtomicOutput(out / f"{suite}.json"), AtomicOutput(out / f"{suite}.md")]
    prov = provenance()
    if git_sha_at_start is not None:
        prov["git_sha"] = git_sha_at_start
    gpu = accelerator(rows)
    if gpu:
        prov["accelerator"] = gpu
    doc = {"suite": suite, **prov, **plain_extra, "rows": plain_rows}
    md = [
        f"# {title}",
        "",
        f"- command: `{prov['command']}`",
        f"- git SHA: `{prov['git_sha']}`",
        f"- machine: {prov['machine']}",
        f"- load at writing: {prov['load']}",
        *([f"- accelerator: {gpu}"] if gpu else []),
        f"- date: {prov['date']}",
        "",
        body_md.strip(),
        "",
    ]
    texts = [json.dumps(doc, indent=2, allow_nan=False) + "\n", "\n".join(md)]
    try:
        for o, text in zip(outputs, texts, strict=True):
            o.partial.write_text(text)
    except BaseException:
        for o in outputs:
            o.discard()
        raise
    json_path, md_path = (o.commit() for o in outputs)
    return json_path, md_path
