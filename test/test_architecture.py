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


def _simulator_modules() -> list[Path]:
    """The line_simulator node's module and its collaborators' (``nodes/sim_*.py``)."""
    return [PKG / "nodes" / "line_simulator.py"] + sorted((PKG / "nodes").glob("sim_*.py"))


def test_no_private_reads_across_plant_modules() -> None:
    """Plant, line, bridge, plots and simulator node code reads no ``_private`` attribute of
    another object.

    ``self._x`` and ``cls._x`` are the module's own; anything else (``sim._c0``) is a read of
    another module's internals.
    """
    files = sorted((PKG / "core" / "plant").glob("*.py")) + sorted(
        (PKG / "core" / "line").glob("*.py")) + [PKG / "core" / "bridge.py", PKG / "plots.py"]
    files += _simulator_modules()
    bad = []
    for f in files:
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_")
                    and not node.attr.startswith("__")
                    and not (isinstance(node.value, ast.Name)
                             and node.value.id in ("self", "cls"))):
                bad.append(f"{f.name}:{node.lineno} .{node.attr}")
    assert not bad, bad


MAX_NODE_CLASS_ATTRIBUTES = 40
"""DEVELOPERS' rule: a class that needs ~50 attributes is several classes."""


def _attributes(cls: ast.ClassDef) -> set[str]:
    """The ``self.x`` names a class assigns."""
    out = set()
    for n in ast.walk(cls):
        if isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store) \
                and isinstance(n.value, ast.Name) and n.value.id == "self":
            out.add(n.attr)
    return out


def test_simulator_classes_have_one_job() -> None:
    """No class of the line_simulator node's modules assigns more than 40 attributes."""
    files = _simulator_modules()
    assert len(files) > 1
    seen, big = 0, []
    for f in files:
        for c in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(c, ast.ClassDef):
                seen += 1
                n = len(_attributes(c))
                if n > MAX_NODE_CLASS_ATTRIBUTES:
                    big.append(f"{f.name}:{c.name} {n}")
    assert seen and not big, big


def test_attribute_count_sees_assignments() -> None:
    """The count sees every ``self.x =`` form (the test above can fail)."""
    src = "class A:\n def f(self):\n  self.a = 1\n  self.b: int = 2\n  self.a += 1\n  x.c = 3\n"
    cls = next(n for n in ast.walk(ast.parse(src)) if isinstance(n, ast.ClassDef))
    assert _attributes(cls) == {"a", "b"}
