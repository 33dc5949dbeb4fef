"""numba kernels compiled on first use, so that importing a module does not import numba.

A kernel module is plain Python written in numba's subset (no numba import). The module that
publishes the kernels makes a :class:`LazyKernels` of it and exposes the compiled versions as
module attributes through PEP 562's ``__getattr__``::

    from rovlab.models import thruster_kernels as _plain
    _kernels = LazyKernels(_plain, ("bank_force", "bank_pwm", ...), cache=True)
    __getattr__ = _kernels.module_getattr(__name__)

``from rovlab.models.thrusters import bank_pwm`` then returns a numba dispatcher (what njit code
such as the simulator's loop needs), while one-shot commands call ``_plain.bank_pwm`` directly
and never pay numba's import (~0.3 s) or a compilation. The compiled copies resolve each other
through their own namespace (a copy of the plain module's, with every kernel replaced by its
dispatcher), so a compiled kernel never calls a plain one.
"""

from __future__ import annotations

import types
from collections.abc import Callable, Iterable
from typing import Any


class LazyKernels:
    """The plain functions ``names`` of ``module``, compiled together with numba on first use."""

    def __init__(self, module: types.ModuleType, names: Iterable[str], **options: Any) -> None:
        self.module = module
        self.names = tuple(names)
        self.options = dict(options)
        self._compiled: dict[str, Any] | None = None

    def plain(self, name: str) -> Callable:
        return getattr(self.module, name)

    def compiled(self) -> dict[str, Any]:
        """{name: numba dispatcher}; creating them imports numba (compilation itself is lazy)."""
        if self._compiled is None:
            import numba

            use_user_cache_folder()
            namespace = dict(vars(self.module))
            out = {}
            for name in self.names:
                f = namespace[name]
                copy = types.FunctionType(f.__code__, namespace, f.__name__, f.__defaults__, f.__closure__)
                copy.__qualname__, copy.__module__, copy.__doc__ = f.__qualname__, f.__module__, f.__doc__
                out[name] = namespace[name] = numba.njit(**self.options)(copy)
            self._compiled = out
        return self._compiled

    def module_getattr(self, module_name: str) -> Callable[[str], Any]:
        def __getattr__(name: str) -> Any:
            if name in self.names:
                return self.compiled()[name]
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")

        return __getattr__


def use_user_cache_folder() -> None:
    """Make an already imported numba pick up the NUMBA_CACHE_DIR that rovlab set.

    numba reads its environment variables when ``numba.core.config`` is imported and again only
    when it compiles; a ``cache=True`` function picks its cache folder when it is *decorated*.
    So if numba was imported before rovlab (a user script doing ``import numba`` first), every
    kernel decorated before the first compilation would cache into ``__pycache__`` next to the
    installed sources. Reloading the configuration here closes that window.
    """
    import sys

    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.reload_config()
