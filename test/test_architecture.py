"""Architecture rules: no import cycles in ``metro_atc``, small plant modules, no private reads.

The import graph is read from the AST of every module, imports inside functions and under
``TYPE_CHECKING`` included (an import hidden in a function is still a dependency).
"""

from __future__ import annotations

import ast
import graphlib
import inspect
import textwrap
import types
from pathlib import Path
from typing import Any

import numpy as np

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


NAMEDTUPLE_API = {"_fields", "_asdict", "_replace", "_make", "_field_defaults"}
"""collections.namedtuple's documented public API (underscored to avoid field clashes)."""


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
                    and node.attr not in NAMEDTUPLE_API
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


def _pure_forward(fn: Any) -> bool:
    """``fn``'s body (less its docstring) is ``return self.<part>.<name>``."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    except (OSError, TypeError):
        return False
    body = [s for s in tree.body[0].body  # type: ignore[attr-defined]
            if not (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant))]
    if len(body) != 1 or not isinstance(body[0], ast.Return):
        return False
    v = body[0].value
    return (isinstance(v, ast.Attribute) and isinstance(v.value, ast.Attribute)
            and isinstance(v.value.value, ast.Name) and v.value.value.id == "self")


def forwarded_attributes(sim: Any, static: tuple[str, ...] = ()) -> list[str]:
    """Names by which a plant object hands out an attribute of one of its parts.

    A part is an attribute of ``sim`` holding an object of this package (``fleet``, ``atp``,
    ``geometry``, ...).  Forwarding is: an attribute hook (``__getattr__``...), a descriptor
    that is neither a method nor a property (the old ``_Alias``), a property whose body is
    ``return self.<part>.<name>``, or a name whose value (an array, list, dict or set) is the
    very object a part holds -- except the names of ``static``: the read-only copies of the
    static line's names that the plant keeps (``station_names``, ...: never written, rebuilt
    from the scenario, not checkpointed).
    """
    cls = type(sim)
    out = []
    for klass in cls.__mro__[:-1]:
        for name, obj in vars(klass).items():
            if name in ("__getattr__", "__getattribute__", "__setattr__"):
                out.append(f"{klass.__name__}.{name}")
            elif name.startswith("__"):
                continue
            elif isinstance(obj, property):
                if _pure_forward(obj.fget):
                    out.append(name)
            elif hasattr(type(obj), "__get__") and not isinstance(
                    obj, (staticmethod, classmethod, types.FunctionType)):
                out.append(name)
    parts = {k: v for k, v in vars(sim).items() if type(v).__module__.startswith("metro_atc.")}
    shared = {id(v): f"{k}.{a}" for k, p in parts.items() for a, v in _fields(p).items()
              if isinstance(v, (np.ndarray, list, dict, set))}
    for name in dir(sim):
        if name.startswith("__") or name in parts or name in static:
            continue
        try:
            v = getattr(sim, name)
        except Exception:  # noqa: BLE001 - a property that needs a state it lacks
            continue
        if isinstance(v, (np.ndarray, list, dict, set)) and id(v) in shared:
            out.append(f"{name} = {shared[id(v)]}")
    return sorted(set(out))


def _fields(obj: Any) -> dict[str, Any]:
    return dict(getattr(obj, "__dict__", {}))


def _mini_line(cls: type) -> Any:
    from metro_atc.core.line.scenario import load_scenario
    return cls(load_scenario("mini"), seed=0)


def test_line_sim_forwards_no_part_attribute() -> None:
    """LineSim has no alias of its parts' attributes: ``sim.fleet.x``, never ``sim.x``."""
    from metro_atc.core.plant.line import LineSim
    from metro_atc.core.plant.snapshot import STATIC_ATTRS
    assert forwarded_attributes(_mini_line(LineSim), STATIC_ATTRS) == []


def test_forwarding_is_seen() -> None:
    """Each form of forwarding is found (the test above can fail)."""
    from metro_atc.core.plant.line import LineSim
    from metro_atc.core.plant.snapshot import STATIC_ATTRS

    class Alias:
        def __get__(self, obj: Any, owner: Any = None) -> Any:
            return obj.fleet.v

    class Forwarding(LineSim):
        v = Alias()

        @property
        def x(self) -> Any:
            return self.fleet.x

        @property
        def n_done(self) -> int:
            """Trains out of service."""
            return self.fleet.n_done

        @property
        def done_twice(self) -> bool:
            return bool(self.done) and bool(self.done)

    sim = _mini_line(Forwarding)
    sim.act_arr = sim.stations.act_arr
    found = forwarded_attributes(sim, STATIC_ATTRS)
    assert found == ["act_arr = stations.act_arr", "n_done", "v", "v = fleet.v", "x",
                     "x = fleet.x"], found
    assert "station_names = service.station_names" in forwarded_attributes(sim)


def private_part_names() -> set[str]:
    """The ``_private`` names the classes of the plant and the static line define."""
    out = set()
    for f in sorted((PKG / "core" / "plant").glob("*.py")) + sorted(
            (PKG / "core" / "line").glob("*.py")):
        for c in ast.walk(ast.parse(f.read_text(), str(f))):
            if not isinstance(c, ast.ClassDef):
                continue
            for n in ast.walk(c):
                if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    out.add(n.name)
                elif isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store):
                    out.add(n.id)
            out |= _attributes(c)
    return {n for n in out if n.startswith("_") and not n.startswith("__") and len(n) > 1}


def private_part_reads(src: str, names: set[str]) -> list[str]:
    """``<expr>.<name>`` of ``names`` in ``src`` where ``<expr>`` is not ``self``/``cls``."""
    return [f"{n.lineno}: {ast.unparse(n)}" for n in ast.walk(ast.parse(src))
            if isinstance(n, ast.Attribute) and n.attr in names
            and not (isinstance(n.value, ast.Name) and n.value.id in ("self", "cls"))]


def test_no_module_outside_the_plant_reads_its_private_names() -> None:
    """No module of metro_atc outside core/plant reads a private name of the plant's parts."""
    names = private_part_names()
    assert "_t_next" in names and "_motion" in names
    assert private_part_reads("sim.fleet._motion\nself._motion\nsim._t_next", names) == [
        "1: sim.fleet._motion", "3: sim._t_next"]
    bad = [f"{f.relative_to(ROOT)}:{r}" for f in sorted(PKG.rglob("*.py"))
           if (PKG / "core" / "plant") not in f.parents
           for r in private_part_reads(f.read_text(), names)]
    assert not bad, bad
