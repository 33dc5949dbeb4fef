"""Designs kept on disk: a value computed from picklable inputs, stored after the first time.

:func:`stored` is the one implementation behind the filter model of ``rovlab filter``
(rovlab.estimation.model.cached_filter_model) and the simulator's designs
(rovlab.sim.runner.stored_design). A file ``<cache>/design/<prefix><key>.pickle`` is keyed on the
inputs as loaded (every value), rovlab's sources and numpy's version, so any change computes
afresh; a value that raises is never stored (it raises every time); an unreadable, damaged or
foreign file is ignored and a cache that cannot be written costs only the time. Files unused for
weeks are removed with the other caches (rovlab.prune_caches).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")


def stored(prefix: str, inputs: Any, make: Callable[[], T], kind: type[T]) -> T:
    """The value ``make()`` for ``inputs``, from disk when it was stored before (an instance of
    ``kind``), else made and stored."""
    import hashlib
    import os
    import pickle

    import numpy as np

    from rovlab import cache_home, source_digest
    from rovlab.core.files import atomic_write_bytes

    digest = source_digest()
    try:
        key = hashlib.sha1(f"{digest} numpy {np.__version__}".encode()
                           + pickle.dumps(inputs, protocol=5)).hexdigest()
    except Exception:  # noqa: BLE001 -- inputs that do not pickle: made every time
        return make()
    if digest is None:
        return make()
    path = cache_home() / "design" / f"{prefix}{key[:32]}.pickle"
    try:
        with open(path, "rb") as f:
            kept = pickle.load(f)
        if isinstance(kept, tuple) and len(kept) == 2 and kept[0] == key and isinstance(kept[1], kind):
            try:
                os.utime(path)  # its last use (rovlab.prune_caches)
            except OSError:
                pass
            return kept[1]
    except Exception:  # noqa: BLE001 -- no file, or a damaged or foreign one: made afresh
        pass
    value = make()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, pickle.dumps((key, value), protocol=5))
    except Exception:  # noqa: BLE001 -- a cache that cannot be written costs only the time
        pass
    return value
