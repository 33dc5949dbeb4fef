"""The layout tells the architecture (STYLE.md): dependencies point downward only.

    interfaces -> sim -> {control, estimation, allocation, ident} -> models -> {params, io}

The four middle siblings do not import each other, and heavy or optional packages (plotting,
web server, browser automation, MCAP, Dask) are imported only at the edges.
"""

from __future__ import annotations

import ast
from pathlib import Path

import rovlab

ROOT = Path(rovlab.__file__).parent
LAYER = {"params": 0, "io": 0, "models": 1, "allocation": 2, "estimation": 2, "control": 2, "ident": 2,
         "sim": 3, "interfaces": 4}
SIBLINGS = {"allocation", "estimation", "control", "ident"}
EDGE_ONLY = {"matplotlib", "aiohttp", "playwright", "mcap", "dask", "distributed"}
EDGE_PACKAGES = {"interfaces", "io"}  # plus ident/plots.py and io/report.py, which import lazily


def _imports(path: Path) -> list[tuple[str, int, bool]]:
    """(module, line, at top level) of every import in a file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = {id(n) for n in tree.body}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((a.name, node.lineno, id(node) in top) for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.module, node.lineno, id(node) in top))
    return out


def test_dependencies_point_downward():
    bad = []
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT)
        if len(rel.parts) < 2:
            continue
        pkg = rel.parts[0]
        for module, line, _ in _imports(path):
            parts = module.split(".")
            if parts[0] != "rovlab" or len(parts) < 2 or parts[1] not in LAYER or parts[1] == pkg:
                continue
            target = parts[1]
            if LAYER[target] > LAYER[pkg] or (pkg in SIBLINGS and target in SIBLINGS):
                bad.append(f"{rel}:{line} imports rovlab.{target}")
    assert not bad, "upward or sideways imports:\n" + "\n".join(bad)


def test_heavy_packages_only_at_the_edges():
    bad = []
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT)
        pkg = rel.parts[0] if len(rel.parts) > 1 else ""
        for module, line, top_level in _imports(path):
            if module.split(".")[0] in EDGE_ONLY and top_level and pkg not in EDGE_PACKAGES:
                bad.append(f"{rel}:{line} imports {module} at module level")
    assert not bad, "\n".join(bad)
