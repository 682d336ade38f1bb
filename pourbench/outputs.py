"""Output files that a failed run cannot destroy.

:func:`check_output_path` checks a path before any work starts (not a folder; its folder
can be created), so a typo fails in a second with a clear message. :class:`AtomicOutput`
writes to a temporary sibling and moves it into place only when the writer finishes, so a
run that fails half-way leaves the previous file as it was.
"""

from __future__ import annotations

import os
from pathlib import Path

from pourbench.errors import InvalidParameterError


class OutputPathError(InvalidParameterError):
    """An output path that cannot be written."""


PARTIAL = ".partial"
"""Appended to an output's name for the file :class:`AtomicOutput` writes before the move."""


def _as_path(path: object, what: str, empty_ok: bool = False) -> Path:
    """``path`` (a ``str`` or ``os.PathLike``, non-empty unless ``empty_ok``: the current
    folder) as a :class:`~pathlib.Path`."""
    if not isinstance(path, str | os.PathLike) or isinstance(path, bytes):
        raise OutputPathError(f"{what} must be a path (str), got {path!r}")
    text = os.fspath(path)
    if not isinstance(text, str) or not (text or empty_ok):
        raise OutputPathError(f"{what} must be a non-empty path, got {path!r}")
    if "\0" in text:
        raise OutputPathError(f"{what} {text!r} contains a NUL character")
    return Path(text)


def check_output_path(path: str | Path) -> Path:
    """``path`` as a :class:`~pathlib.Path` whose folder exists (created if missing).

    Raises:
        OutputPathError: the path is not a non-empty path string, contains NUL, ends with a
            separator, is a folder or cannot be looked up (a name too long, also with
            ``.partial`` appended), or its folder cannot be created or written.
    """
    p = _as_path(path, "output path")
    text = os.fspath(path)
    try:
        is_dir = p.is_dir()
        p.with_name(p.name + PARTIAL).is_dir()  # the name AtomicOutput writes to first
    except OSError as exc:  # e.g. a name longer than the file system allows
        raise OutputPathError(f"output path {text!r}: {exc.strerror or exc}") from exc
    if is_dir:
        raise OutputPathError(f"output path {str(p)!r} is a folder; give a file name")
    if text.endswith(tuple(s for s in (os.sep, os.altsep) if s)):
        raise OutputPathError(f"output path {text!r} ends with a separator; give a file name")
    check_output_folder(p.parent)
    return p


def check_output_folder(path: str | Path) -> Path:
    """``path`` as a folder that exists (created if missing) and can be written.

    Raises:
        OutputPathError: the path is not a path string, contains NUL or is a file,
            or the folder cannot be created or written.
    """
    p = _as_path(path, "output folder", empty_ok=True)
    if p.exists() and not p.is_dir():
        raise OutputPathError(f"output folder {str(p)!r} is a file; give a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"cannot create the folder {str(p)!r}: {exc.strerror}") from exc
    if not os.access(p, os.W_OK):
        raise OutputPathError(f"cannot write to the folder {str(p)!r}: permission denied")
    return p


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a ``.partial`` sibling, so that a reader (or a run
    that fails while writing) never sees half a file."""
    out = AtomicOutput(path)
    try:
        out.partial.write_text(text)
    except OSError as exc:  # a name too long for the file system, a full disk, …
        out.discard()
        raise OutputPathError(f"cannot write {str(out.path)!r}: {exc.strerror or exc}") from exc
    except BaseException:
        out.discard()
        raise
    return out.commit()


class AtomicOutput:
    """A checked output path with a temporary sibling to write to (``.partial`` appended);
    :meth:`commit` moves it over the final path, :meth:`discard` removes it."""

    def __init__(self, path: str | Path) -> None:
        self.path = check_output_path(path)
        self.partial = self.path.with_name(self.path.name + PARTIAL)
        if self.partial.is_dir():  # (a leftover partial file is overwritten)
            raise OutputPathError(
                f"{str(self.partial)!r} is a folder: remove it to write {str(self.path)!r}"
            )

    def commit(self) -> Path:
        os.replace(self.partial, self.path)
        return self.path

    def discard(self) -> None:
        self.partial.unlink(missing_ok=True)
