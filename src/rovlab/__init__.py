"""rovlab: model, identify, estimate, control and simulate small underwater vehicles.

Units are SI and radians inside; NED world frame, FRD body frame; SNAME names and signs.
See docs/conventions.md.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

__version__ = "0.1.0"


_digest: list[str | None] = []


def source_digest() -> str | None:
    """SHA-1 (hex) of the version and every source file of this package (None if unreadable):
    the key of what rovlab caches on disk (compiled kernels, designed filters)."""
    if not _digest:
        root = Path(__file__).resolve().parent
        digest = hashlib.sha1(__version__.encode())
        try:
            for path in sorted(root.rglob("*.py")):
                digest.update(f"{path.relative_to(root)}:".encode())
                digest.update(path.read_bytes())
            _digest.append(digest.hexdigest())
        except OSError:
            _digest.append(None)
    return _digest[0]


def cache_home() -> Path:
    """rovlab's folder of caches: $XDG_CACHE_HOME/rovlab or ~/.cache/rovlab."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rovlab"


def _numba_cache_dir() -> None:
    """Point numba's on-disk cache at a folder keyed by this package's sources.

    numba's ``cache=True`` invalidates a compiled function when *its own* file changes, not when
    a function it inlines or calls from another module does, so an edited kernel could keep
    running its old compiled callers. Keying the cache folder on the contents of every source
    file makes any change start from a clean cache (files touched but unchanged keep the folder;
    numba itself still checks each file's modification time). A NUMBA_CACHE_DIR set by the user
    wins; it holds whatever the import order (see below).
    """
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    digest = source_digest()
    if digest is None:
        return
    try:
        folder = cache_home() / "numba" / digest[:16]
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return  # read-only home and the like: numba falls back to its own default
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    # numba imported before rovlab has already read its environment: make it read it again
    # (otherwise the kernels decorated next would cache into the installed package folder).
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.reload_config()


_numba_cache_dir()
