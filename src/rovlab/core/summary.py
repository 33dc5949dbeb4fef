"""A component's design summary (rovlab.core.components.ComponentInfo.summary) as text: what
``rovlab design`` prints for a component that does not describe itself. Named numbers, lists and
matrices (SI units), nested tables indented under their name."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np


def render(summary: Mapping[str, Any], indent: str = "  ") -> list[str]:
    """Lines of text for a summary: ``name = value``, a list on one line, a matrix row by row."""
    lines: list[str] = []
    for key, value in summary.items():
        if isinstance(value, Mapping) and value and all(_number(v) or isinstance(v, str) for v in value.values()):
            lines.append(f"{indent}{key}: " + ", ".join(f"{k} {_text(v)}" for k, v in value.items()))
            continue
        if isinstance(value, Mapping):
            lines.append(f"{indent}{key}:")
            lines.extend(render(value, indent + "  "))
            continue
        if isinstance(value, (list, tuple, np.ndarray)):
            a = np.asarray(value, dtype=object)
            if a.ndim == 2 and a.size and all(_number(v) for v in a.ravel()):
                lines.append(f"{indent}{key} =")
                lines.extend(indent + "  [" + "  ".join(f"{float(v): .6g}" for v in row) + "]" for row in a)
                continue
            lines.append(f"{indent}{key} = [" + ", ".join(_text(v) for v in a.ravel()) + "]")
            continue
        lines.append(f"{indent}{key} = {_text(value)}")
    return lines


def table_values(table: Any) -> dict[str, Any]:
    """A component's table (a dataclass, rovlab.params.design.DesignConfig.table) as plain values."""
    import dataclasses

    if dataclasses.is_dataclass(table) and not isinstance(table, type):
        return {f.name: _plain(getattr(table, f.name)) for f in dataclasses.fields(table)}
    return {}


def _plain(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, Mapping):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def _number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def _text(v: Any) -> str:
    if _number(v):
        return f"{float(v):.6g}"
    return str(v)
