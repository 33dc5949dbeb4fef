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
    root = Path(__file__).resolve().parent
    digest = hashlib.sha1(__version__.encode())
    try:
        for path in sorted(root.rglob("*.py")):
            digest.update(f"{path.relative_to(root)}:".encode())
            digest.update(path.read_bytes())
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rovlab" / "numba"
        folder = base / digest.hexdigest()[:16]
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
