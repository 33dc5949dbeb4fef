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


CACHE_KEEP_DAYS = 14  # a cache folder of other sources unused this long is removed ...
CACHE_KEEP_RECENT = 4  # ... and beyond the most recently used few


def prune_caches(*, keep: Path | None = None, now: float | None = None) -> list[Path]:
    """Remove what older sources of rovlab left in its cache folder: folders of compiled kernels
    (numba/<sources>, aot/<sources>-<cpu>) and stored designs (design/*.pickle) not used for
    CACHE_KEEP_DAYS days, and kernel folders beyond the CACHE_KEEP_RECENT most recently used of
    each kind, the one in use included (each ~5-30 MB; every upgrade or edit of rovlab starts new
    ones). Never removed: ``keep`` (the numba folder in use) and the folders of the same sources,
    folders used in the last day, and folders whose background compile is still running. Runs when new
    sources first run; errors (a file another process holds, a read-only folder) are skipped.
    Returns what was removed."""
    import shutil
    import time

    now = time.time() if now is None else now
    cutoff = now - CACHE_KEEP_DAYS * 86400.0
    removed: list[Path] = []
    home = cache_home()
    mine = keep.name[:16] if keep is not None else None

    def last_use(path: Path) -> float:
        try:
            return path.stat().st_mtime
        except OSError:
            return now

    for kind in ("numba", "aot"):
        try:
            others = sorted((f for f in (home / kind).iterdir() if f.is_dir() and not f.name.startswith(".")
                             and not (mine is not None and f.name.startswith(mine))), key=last_use, reverse=True)
        except OSError:
            continue
        for i, f in enumerate(others):
            used = last_use(f)
            if used >= now - 86400.0 or _busy(f):
                continue  # used today, or a compile for it is under way: another process may be on it
            if used >= cutoff and i < CACHE_KEEP_RECENT - 1:
                continue
            shutil.rmtree(f, ignore_errors=True)
            if not f.exists():
                removed.append(f)
    try:
        designs = [f for f in (home / "design").iterdir() if f.suffix == ".pickle"]
    except OSError:
        designs = []
    for f in designs:
        if last_use(f) < cutoff:
            try:
                f.unlink()
                removed.append(f)
            except OSError:
                pass
    return removed


def _busy(folder: Path) -> bool:
    """Whether a background compile (rovlab._jit.start_detached) holds a lock in this cache folder
    and its process is alive."""
    for lock in folder.glob("rovlab-ready/*.lock"):
        try:
            os.kill(int(lock.read_text().strip()), 0)
            return True
        except PermissionError:
            return True
        except (OSError, ValueError):
            continue
    return False


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
        new = not folder.is_dir()
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return  # read-only home and the like: numba falls back to its own default
    if not new:
        try:
            os.utime(folder)  # its last use, for prune_caches
        except OSError:
            pass
    if new:  # first use of these sources (an upgrade, an edit): drop the caches nothing uses any more
        prune_caches(keep=folder)
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    # numba imported before rovlab has already read its environment: make it read it again
    # (otherwise the kernels decorated next would cache into the installed package folder).
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.reload_config()


_numba_cache_dir()
