"""The layout tells the architecture (STYLE.md): dependencies point downward only.

    interfaces -> sim -> {control, estimation, ident} -> allocation -> models -> io -> params -> core

The three middle siblings do not import each other; the allocation (what the thrusters can give)
sits below them, so a controller that bounds its integral by the thrust capacity and a planner
that sizes an excitation to it ask the allocation itself instead of solving it again (io may read params' errors, never the other
way round; core, the shared helpers, imports no other rovlab package). Relative imports count
like absolute ones. Heavy or optional packages (plotting, web server, browser automation, MCAP,
Dask) are imported only at the edges.
"""

from __future__ import annotations

import ast
from pathlib import Path

import rovlab

ROOT = Path(rovlab.__file__).parent
LAYER = {"core": 0, "params": 1, "io": 2, "models": 3, "allocation": 4, "estimation": 5, "control": 5,
         "ident": 5, "sim": 6, "interfaces": 7}
SIBLINGS = {"estimation", "control", "ident"}
EDGE_ONLY = {"matplotlib", "aiohttp", "playwright", "mcap", "dask", "distributed", "pymavlink"}
EDGE_PACKAGES = {"interfaces", "io"}  # plus ident/plots.py and io/report.py, which import lazily


def _imports(path: Path, package: list[str] | None = None) -> list[tuple[str, int, bool]]:
    """(module, line, at top level) of every import in a file; relative imports resolved
    against the file's package (by default its place under rovlab/)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = {id(n) for n in tree.body}
    package = package or ["rovlab", *path.relative_to(ROOT).parts[:-1]]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((a.name, node.lineno, id(node) in top) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                module = node.module or ""
            else:
                base = package[:len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            if module:
                out.append((module, node.lineno, id(node) in top))
    return out


def test_relative_imports_are_resolved(tmp_path):
    """The checker sees through `from ..x import y` (a relative import cannot slip past it)."""
    probe = tmp_path / "probe.py"
    probe.write_text("from ..sim import runner\nfrom . import sibling\nfrom .kinetics import pack\n",
                     encoding="utf-8")
    found = [m for m, _, _ in _imports(probe, ["rovlab", "models"])]
    assert found == ["rovlab.sim", "rovlab.models", "rovlab.models.kinetics"]


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


def test_pymavlink_is_imported_lazily():
    """`import rovlab` and one-shot commands must not pay for pymavlink: it is imported only inside
    functions of rovlab.interfaces.mavlink (through rovlab.interfaces.mavlink.mavutil)."""
    bad = []
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT)
        for module, line, top_level in _imports(path):
            if module.split(".")[0] != "pymavlink":
                continue
            if top_level or rel.parts[:2] != ("interfaces", "mavlink"):
                bad.append(f"{rel}:{line} imports {module}")
    assert not bad, "\n".join(bad)


def _module_graph() -> dict[str, set[str]]:
    """rovlab module -> the rovlab modules it imports, function-local imports included (an import
    circle hidden in a function is still a circle); ``from package import submodule`` counts as
    an import of the submodule only."""
    modules = {}
    for path in ROOT.rglob("*.py"):
        parts = ["rovlab", *path.relative_to(ROOT).with_suffix("").parts]
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for name, path in modules.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or "" if node.level == 0 else \
                    ".".join(package[:len(package) - (node.level - 1)] + ([node.module] if node.module else []))
                subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in modules]
                targets = subs if len(subs) == len(node.names) else [base, *subs]
            else:
                continue
            graph[name].update(t for t in targets if t in modules and t not in (name, "rovlab"))
    return graph


def test_no_import_circles():
    """Modules import each other one way only (STYLE.md; issue 26): no circle, not even through
    an import inside a function."""
    graph = _module_graph()
    seen: dict[str, int] = {}  # 1 on the current path, 2 done
    circles: list[list[str]] = []

    def visit(m: str, path: list[str]) -> None:
        seen[m] = 1
        for n in sorted(graph[m]):
            if seen.get(n) == 1:
                circles.append(path[path.index(n):] + [n])
            elif n not in seen:
                visit(n, [*path, n])
        seen[m] = 2

    for m in sorted(graph):
        if m not in seen:
            visit(m, [m])
    assert not circles, "import circles:\n" + "\n".join(" -> ".join(c) for c in circles)
