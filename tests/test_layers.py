"""The package layers of signsplat (../shared STYLE: imports only go down) and the tables
every stage registers, checked on the source and on a fresh interpreter."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "signsplat"

# Floors, bottom first. A module may import from its own package or from a lower floor.
FLOORS = [
    {"errors"},
    {"io", "config", "device", "geometry", "numba_cache"},
    {"render", "body", "motion"},
    {"synth", "perception", "fit", "colmap", "avatar"},
    {"stitch", "report"},
    {"cli", "plan", "__init__"},
    {"__main__"},
]
FLOOR = {name: i for i, names in enumerate(FLOORS) for name in names}


def _unit(module: str) -> str:
    """'signsplat.avatar.train' -> 'avatar'; 'signsplat.cli' -> 'cli'."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def package_imports(root: Path = PKG) -> dict[tuple[str, str], list[str]]:
    """(importer unit, imported unit) -> the files where it happens, every import statement
    (also those inside functions) of every module under ``root``."""
    edges: dict[tuple[str, str], list[str]] = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent).with_suffix("")
        me = _unit(".".join(rel.parts))
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names
                                         if node.module == "signsplat"]
            for name in names:
                if name.startswith("signsplat.") and _unit(name) != me:
                    edges.setdefault((me, _unit(name)), []).append(str(rel))
    return edges


def cycles(edges) -> list[list[str]]:
    """Strongly connected groups of more than one unit (Tarjan)."""
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        graph.setdefault(a, set()).add(b)
        graph.setdefault(b, set())
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle_between_packages():
    assert cycles(package_imports()) == []


def test_every_import_goes_down_a_floor():
    edges = package_imports()
    unknown = sorted({u for e in edges for u in e} - set(FLOOR))
    assert not unknown, f"packages without a floor in this test: {unknown}"
    up = {f"{a} -> {b}": files for (a, b), files in edges.items() if FLOOR[b] >= FLOOR[a]}
    assert up == {}


def test_the_checks_see_a_cycle_and_an_upward_import(tmp_path):
    pkg = tmp_path / "signsplat"
    for name, text in {"synth/scene.py": "from signsplat.stitch.motion import x\n",
                       "stitch/motion.py": "def f():\n    import signsplat.synth.glosses\n",
                       "io/tables.py": "from signsplat import errors\n"}.items():
        (pkg / name).parent.mkdir(parents=True, exist_ok=True)
        (pkg / name).write_text(text)
    edges = package_imports(pkg)
    assert set(edges) == {("synth", "stitch"), ("stitch", "synth"), ("io", "errors")}
    assert cycles(edges) == [["stitch", "synth"]]


def test_every_table_is_documented_once_every_module_is_imported():
    """Import every module in a fresh interpreter (so that the order in which tests import
    modules cannot hide a stage's table), then every registered table has a description and
    described columns, and the stage tables are among them."""
    script = (
        "import importlib, json, pkgutil, signsplat\n"
        "for m in pkgutil.walk_packages(signsplat.__path__, 'signsplat.'):\n"
        "    if not m.name.endswith('__main__'):\n"
        "        importlib.import_module(m.name)\n"
        "from signsplat.io.tables import TABLES\n"
        "print(json.dumps({n: [bool(t.doc), [c for c, d in t.columns.items() if not d]]"
        " for n, t in TABLES.items()}))\n")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=300, cwd=PKG.parent)
    assert res.returncode == 0, res.stderr[-3000:]
    tables = json.loads(res.stdout.strip().splitlines()[-1])
    registered = set()
    for path in PKG.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "Table" \
                    and node.args and isinstance(node.args[0], ast.Constant):
                registered.add(node.args[0].value)
    assert registered and registered <= set(tables), registered - set(tables)
    assert {n: v for n, v in tables.items() if not v[0] or v[1]} == {}
