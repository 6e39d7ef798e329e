"""Architecture rules: no import cycles in ``metro_atc``, small plant modules, no private reads.

The import graph is read from the AST of every module, imports inside functions and under
``TYPE_CHECKING`` included (an import hidden in a function is still a dependency).
"""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "metro_atc"
MAX_PLANT_LINES = 400


def _modules() -> dict[str, Path]:
    out = {}
    for f in sorted(PKG.rglob("*.py")):
        parts = list(f.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def _is_package(mod: str, mods: dict[str, Path]) -> bool:
    return mods[mod].name == "__init__.py"


def import_graph() -> dict[str, set[str]]:
    """Module -> metro_atc modules it imports (parent packages included)."""
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        base = mod if _is_package(mod, mods) else mod.rpartition(".")[0]
        targets: list[str] = []
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets += [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    pkg = base.split(".")
                    pkg = pkg[:len(pkg) - (node.level - 1)]
                    src = ".".join(pkg + ([node.module] if node.module else []))
                else:
                    src = node.module or ""
                targets.append(src)
                targets += [f"{src}.{a.name}" for a in node.names if f"{src}.{a.name}" in mods]
        for tgt in targets:
            parts = tgt.split(".")
            for k in range(1, len(parts) + 1):
                name = ".".join(parts[:k])
                if name in mods and name != mod:
                    graph[mod].add(name)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    try:
        tuple(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as exc:
        return list(exc.args[1])
    return None


def test_import_graph_is_read() -> None:
    """The walker sees known edges, function-level ones included (the test can fail)."""
    g = import_graph()
    assert "metro_atc.core.plant.atp" in g["metro_atc.core.plant.line"]
    assert "metro_atc.core.line.scenario" in g["metro_atc.core.bridge"]
    assert "metro_atc.core.ato.envelope" in g["metro_atc.core.bridge"]  # inside a function
    bad = {k: set(v) for k, v in g.items()}
    bad["metro_atc.core.line.scenario"].add("metro_atc.core.plant.line")
    assert _cycle(bad) is not None


def test_no_import_cycles() -> None:
    """No module of metro_atc imports (transitively) itself."""
    cyc = _cycle(import_graph())
    assert cyc is None, "import cycle: " + " -> ".join(cyc or [])


def test_static_line_description_does_not_import_the_plant() -> None:
    """core.line (geometry, rolling stock, timetable) and the ATS/ATO cores never need the
    plant; the KPIs are computed from a run log without it."""
    g = import_graph()
    free = [m for m in g if m.startswith(("metro_atc.core.line", "metro_atc.core.atr",
                                          "metro_atc.core.ato", "metro_atc.core.bridge"))]
    free.append("metro_atc.core.plant.kpi")
    for m in free:
        seen, todo = set(), [m]
        while todo:
            cur = todo.pop()
            for nxt in g[cur] - seen:
                seen.add(nxt)
                todo.append(nxt)
        plant = sorted(x for x in seen if x.startswith("metro_atc.core.plant.")
                       and x != "metro_atc.core.plant")
        assert not plant, f"{m} imports the plant: {plant}"


def test_plant_modules_are_small() -> None:
    """No file under metro_atc/core/plant/ is over 400 lines."""
    for f in sorted((PKG / "core" / "plant").glob("*.py")):
        n = len(f.read_text().splitlines())
        assert n <= MAX_PLANT_LINES, f"{f.name}: {n} lines"


def test_no_private_reads_across_plant_modules() -> None:
    """Plant, line, bridge and plots code reads no ``_private`` attribute of another object.

    ``self._x`` and ``cls._x`` are the module's own; anything else (``sim._c0``) is a read of
    another module's internals.
    """
    files = sorted((PKG / "core" / "plant").glob("*.py")) + sorted(
        (PKG / "core" / "line").glob("*.py")) + [PKG / "core" / "bridge.py", PKG / "plots.py"]
    bad = []
    for f in files:
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_")
                    and not node.attr.startswith("__")
                    and not (isinstance(node.value, ast.Name)
                             and node.value.id in ("self", "cls"))):
                bad.append(f"{f.name}:{node.lineno} .{node.attr}")
    assert not bad, bad
