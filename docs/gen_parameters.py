"""Write ``docs/parameters.md`` from the nodes' own parameter declarations.

Every node parameter is declared through ``metro_atc.nodes.common.declare`` (directly, via
``static`` or via ``RuntimeParams.dynamic``). This script builds each node of the graph
in-process on the small ``mini`` scenario with that function wrapped, records every call
(name, default, description, range, read-only, choices) and renders one table per node.
Nothing is copied by hand: re-run it after changing a declaration::

    source env.sh && python docs/gen_parameters.py          # rewrite docs/parameters.md
    source env.sh && python docs/gen_parameters.py --check  # exit 1 if it is out of date

``test/test_docs.py`` checks that the document lists exactly the parameters the nodes
declare.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

DOC = Path(__file__).resolve().parent / "parameters.md"

NODES = ("line_simulator", "ats_regulator", "ato_controller", "brake_diagnostic",
         "bag_recorder", "foxglove_bridge")
"""The executables, in the order of the document."""

RCLPY_OWN = ("use_sim_time", "start_type_description_service")
"""Parameters rclpy declares on every node (not ours; listed once in the document)."""

SCENARIO = "mini"
"""Scenario the nodes are built on (the declarations do not depend on it)."""

CITATIONS = {
    "brake_diagnostic": {"000": "Lin 2010b"},
    "": {"000": "Lin 2010a", "001": "Ke 2010", "002": "ACTP n.d.", "003": "Sheu 2011",
         "004": "Li n.d."},
}
"""Source file numbers still used in some descriptions ("seed" and the number) -> citation
keys of docs/references.md, per node ("" for all); a no-op once the code cites by key."""


@dataclass(frozen=True)
class Declared:
    """One parameter declaration as the node made it."""

    node: str
    name: str
    default: Any
    description: str
    lo: float | int | None
    hi: float | int | None
    read_only: bool
    dynamic: bool
    choices: tuple[str, ...] | None


def _record(calls: list[tuple[Any, ...]]) -> Callable[[], None]:
    """Wrap ``common.declare`` so each call is appended to ``calls``; return the undo."""
    from metro_atc.nodes import common

    original = common.declare

    def recording(node: Any, name: str, default: Any, description: str,
                  lo: float | int | None = None, hi: float | int | None = None,
                  step: float | int | None = None, read_only: bool = False,
                  choices: Sequence[str] | None = None) -> Any:
        calls.append((node, name, default, description, lo, hi, read_only, choices))
        return original(node, name, default, description, lo, hi, step, read_only, choices)

    common.declare = recording  # type: ignore[assignment]

    def undo() -> None:
        common.declare = original  # type: ignore[assignment]
    return undo


def _build(ctx: Any, kind: str, tmp: Path) -> Any:
    """Construct the node of executable ``kind`` on :data:`SCENARIO`."""
    from rclpy.parameter import Parameter

    over = [Parameter("scenario", value=SCENARIO)]
    if kind == "line_simulator":
        from metro_atc.nodes.line_simulator import LineSimulator
        return LineSimulator(context=ctx, parameter_overrides=over)
    if kind == "ats_regulator":
        from metro_atc.nodes.ats_regulator import AtsRegulator
        return AtsRegulator(context=ctx, parameter_overrides=over)
    if kind == "ato_controller":
        from metro_atc.nodes.ato_controller import AtoController
        return AtoController("train_01", context=ctx, parameter_overrides=over)
    if kind == "brake_diagnostic":
        from metro_atc.nodes.brake_diagnostic import BrakeDiagnostic
        return BrakeDiagnostic(context=ctx, parameter_overrides=over)
    if kind == "bag_recorder":
        from metro_atc.nodes.bag_recorder import BagRecorder
        over.append(Parameter("output", value=str(tmp / "bag")))
        return BagRecorder(context=ctx, parameter_overrides=over)
    if kind == "foxglove_bridge":
        from metro_atc.nodes.foxglove_bridge import FoxgloveBridge
        over.append(Parameter("port", value=0))  # any free port
        return FoxgloveBridge(context=ctx, parameter_overrides=over)
    raise ValueError(kind)


def node_parameters(domain_id: int) -> Iterator[tuple[str, list[Declared], list[str]]]:
    """Per executable: its declarations and the names the live node holds.

    The second list (``node.list_parameters``, rclpy's own parameters removed) lets a
    caller see a parameter declared without ``declare``.
    """
    import rclpy
    from rclpy.context import Context

    with tempfile.TemporaryDirectory() as tmp:
        for kind in NODES:
            calls: list[tuple[Any, ...]] = []
            undo = _record(calls)
            ctx = Context()
            rclpy.init(context=ctx, domain_id=domain_id)
            node = None
            try:
                node = _build(ctx, kind, Path(tmp) / kind)
                held = sorted(n for n in node.list_parameters([], 0).names
                              if n not in RCLPY_OWN and not n.startswith("qos_overrides."))
                dyn = set(getattr(getattr(node, "rt", None), "_setters", {}) or {})
                if hasattr(node, "params"):  # the simulator keeps them on a collaborator
                    dyn |= set(getattr(getattr(node.params, "rt", None), "_setters", {}) or {})
                decls = []
                seen: set[str] = set()
                for (owner, name, default, desc, lo, hi, ro, choices) in calls:
                    if owner is not node or name in seen:
                        continue
                    seen.add(name)
                    decls.append(Declared(kind, name, default, desc, lo, hi, bool(ro),
                                          name in dyn, tuple(choices) if choices else None))
                yield kind, decls, held
            finally:
                undo()
                if node is not None:
                    node.destroy_node()
                ctx.try_shutdown()


def _cite(kind: str, text: str) -> str:
    """``text`` with old-style source numbers replaced by citation keys."""
    table = {**CITATIONS[""], **CITATIONS.get(kind, {})}
    text = re.sub(r"\bseed (\d{3})\b", lambda m: table.get(m.group(1), m.group(0)), text)
    return re.sub(r"(\d{4}[ab]?|n\.d\.) eq\.", r"\1, eq.", text)


def _type(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "double"
    if isinstance(value, list):
        return "string[]"
    return "string"


def _fmt(value: Any) -> str:
    if isinstance(value, str):
        return f"`'{value}'`"
    if isinstance(value, list):
        return "`[" + ", ".join(f"'{v}'" for v in value) + "]`"
    return f"`{str(value).lower() if isinstance(value, bool) else value}`"


def _range(d: Declared) -> str:
    if d.choices:
        return "one of " + ", ".join(f"`{c}`" for c in d.choices)
    if d.lo is not None and d.hi is not None and not isinstance(d.default, bool):
        return f"[{d.lo}, {d.hi}]"
    return ""


def render(tables: Sequence[tuple[str, list[Declared]]]) -> str:
    """Render the Markdown document of ``tables`` (node, declarations)."""
    out = ["# Node parameters", "",
           "Generated by `docs/gen_parameters.py` from the nodes' declarations (do not edit "
           "by hand; `test/test_docs.py` checks that this file lists exactly the declared "
           "parameters). Every parameter has a descriptor (description, type, range or "
           "allowed values) that `ros2 param describe` shows, and a YAML file in `config/`.",
           "",
           "- **static**: read at start-up; `ros2 param set` is refused with a reason.",
           "- **dynamic**: applied at once by the node's on-set callback.",
           "- A value outside the range or the allowed values, a malformed params file, an "
           "unknown parameter name in a section naming the node, or a value where a single "
           "value is expected ends the node with exit status 2 and one line naming it.",
           f"- rclpy adds {', '.join(f'`{n}`' for n in RCLPY_OWN)} to every node "
           "(`use_sim_time` is set by the launcher; the ATO processes run without it).",
           ""]
    for kind, decls in tables:
        out += [f"## `{kind}`", "",
                "| name | type | default | range | when | meaning |",
                "|---|---|---|---|---|---|"]
        for d in decls:
            when = "dynamic" if d.dynamic else ("static" if d.read_only else "start-up")
            desc = _cite(kind, " ".join(d.description.split())).replace("|", "\\|")
            out.append(f"| `{d.name}` | {_type(d.default)} | {_fmt(d.default)} | "
                       f"{_range(d)} | {when} | {desc} |")
        out.append("")
    return "\n".join(out)


def documented(text: str) -> dict[str, set[str]]:
    """Parameter names per node section of a rendered document."""
    result: dict[str, set[str]] = {}
    section = None
    for line in text.splitlines():
        m = re.match(r"^## `([a-z_]+)`", line)
        if m:
            section = m.group(1)
            result[section] = set()
            continue
        m = re.match(r"^\| `([A-Za-z0-9_.]+)` \|", line)
        if m and section is not None:
            result[section].add(m.group(1))
    return result


def main(argv: Sequence[str] | None = None) -> int:
    """Write (or ``--check``) docs/parameters.md; return the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if the file is stale")
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")),
                    help="ROS domain to build the nodes on (default: $ROS_DOMAIN_ID)")
    args = ap.parse_args(argv)
    tables = [(kind, decls) for kind, decls, _ in node_parameters(args.domain)]
    text = render(tables) + "\n"
    if args.check:
        if DOC.read_text() != text:
            print(f"{DOC} is out of date: run python docs/gen_parameters.py", file=sys.stderr)
            return 1
        return 0
    DOC.write_text(text)
    print(f"wrote {DOC} ({sum(len(d) for _, d in tables)} parameters)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
