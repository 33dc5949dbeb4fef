"""Atomic file writes: a reader never sees a half-written file, and a failed write (full disk,
Ctrl-C) leaves the old file, if any, and no temporary file behind.

:func:`atomic_open` is the one implementation (a temporary file in the same folder, flushed and
``os.replace``d over the target; an existing file keeps its permission bits);
:func:`atomic_write_text` and :func:`atomic_write_bytes` are its one-shot forms, and
:func:`write_figure` writes a matplotlib figure through it.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "w", *, encoding: str | None = "utf-8") -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path`` for writing ("w" text or "wb" binary); on a clean
    exit it replaces ``path``, on an exception it is removed and the exception propagates."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes only ('w' or 'wb'), got {mode!r}")
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    keep_mode = path.stat().st_mode & 0o777 if path.exists() else None
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        fh: IO[Any] = os.fdopen(fd, "wb") if mode == "wb" else os.fdopen(fd, "w", encoding=encoding, newline="")
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        if keep_mode is None:
            umask = os.umask(0)
            os.umask(umask)
            keep_mode = 0o666 & ~umask
        os.chmod(tmp, keep_mode)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    with atomic_open(path, "w") as fh:
        fh.write(text)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_open(path, "wb") as fh:
        fh.write(data)


def write_figure(fig: Any, path: str | Path, **savefig: Any) -> Path:
    """A matplotlib figure into ``path`` atomically, in the format its suffix names: a full disk
    leaves no empty or partial image (``identify --plot`` left a 0-byte PNG), and an earlier one as it was."""
    path = Path(path)
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format=path.suffix.lower()[1:] or "png", **savefig)
    return path
