"""Parameter-file checks rclpy does not make (ROS-free: plain YAML and names).

rclpy reads ``--params-file`` with an unbounded ``yaml.safe_load`` (a binary file raises
``UnicodeDecodeError``) and silently ignores a value it cannot use: ``seed: {a: 1}`` becomes
a parameter ``seed.a`` that no node declares, and ``seed`` keeps its default.  This module
loads parameter files with the limits of :mod:`metro_atc.core.safe_yaml` and finds
overrides that no parameter of a node takes.  rclpy also ignores ``-p no_such_param:=1`` (no
node declares it) and a params file whose sections name no node of the process (a typo in
the node name): :func:`unknown_problem` refuses both.
"""

from __future__ import annotations

import re
from typing import Any, Callable, Iterator, Sequence

from metro_atc.core.safe_yaml import YamlLimitError, load_yaml_file, one_line, short_repr

__all__ = ["load_params_file", "params_files", "node_sections", "override_problem",
           "cli_params", "unknown_problem"]

_BUILTIN_PREFIXES = ("qos_overrides.",)
"""Parameter namespaces rclpy itself reads without declaring them."""


def load_params_file(path: str) -> tuple[Any, str | None]:
    """Parse a ``--params-file`` within the YAML limits; return (document, error line)."""
    shown = short_repr(path) if len(path) > 80 or not path.isprintable() else path
    try:
        return load_yaml_file(path), None
    except YamlLimitError as exc:
        return None, one_line(f"params file {shown}: {exc}", 260)


def params_files(argv: Sequence[str]) -> list[str]:
    """Every path given after ``--params-file`` in a ROS argument list."""
    return [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--params-file"]


def _pattern(key: str) -> re.Pattern[str]:
    """Regex for a ROS params-file node key (``/**``, ``*``, relative names)."""
    k = key if key.startswith("/") else "/" + key
    out = ""
    i = 0
    while i < len(k):
        if k.startswith("/**", i):
            out += "(/[^/]+)*"
            i += 3
        elif k[i] == "*":
            out += "[^/]*"
            i += 1
        else:
            out += re.escape(k[i])
            i += 1
    return re.compile(out + "$")


def _sections(doc: Any, prefix: str = "") -> Iterator[tuple[str, dict[str, Any]]]:
    """(node key, ros__parameters mapping) of a params document (nested namespaces too)."""
    if not isinstance(doc, dict):
        return
    for key, val in doc.items():
        if not isinstance(val, dict):
            continue
        name = f"{prefix}/{str(key).strip('/')}" if prefix else str(key)
        params = val.get("ros__parameters")
        if isinstance(params, dict):
            yield name, params
        else:
            yield from _sections(val, name)


def _flatten(params: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    """Dotted parameter names of a ros__parameters mapping (nested mappings -> a.b)."""
    for k, v in params.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            yield from _flatten(v, name + ".")
        else:
            yield name, v


def node_sections(doc: Any, name: str, namespace: str
                  ) -> Iterator[tuple[bool, str, dict[str, Any]]]:
    """(explicit, key, parameters) of the sections of ``doc`` that apply to a node.

    ``explicit``: the key names the node (no wildcard in its last component).
    """
    fqn = (namespace.rstrip("/") + "/" + name) if namespace not in ("", "/") else "/" + name
    for key, params in _sections(doc):
        if _pattern(key).match(fqn):
            yield "*" not in key.rsplit("/", 1)[-1], key, params


def override_problem(name: str, namespace: str, has_parameter: Callable[[str], bool],
                     argv: Sequence[str]) -> str | None:
    """One error line if a params file gives the node a value no parameter takes, else None.

    Two cases: a mapping where the node declares a plain parameter (``seed: {a: 1}``: the
    value would be dropped), in any section that applies to the node; and an unknown name
    in a section that names the node explicitly (a typo would be ignored).
    """
    for path in params_files(argv):
        doc, problem = load_params_file(path)
        if problem:
            return problem
        for explicit, key, params in node_sections(doc, name, namespace):
            for pname, value in _flatten(params):
                if pname.startswith(_BUILTIN_PREFIXES) or has_parameter(pname):
                    continue
                head = pname.split(".", 1)[0]
                if "." in pname and has_parameter(head):
                    return one_line(f"params file {path}: '{key}': parameter '{head}' takes a "
                                    f"single value, got a mapping ({pname}="
                                    f"{short_repr(value)})", 260)
                if explicit:
                    return one_line(f"params file {path}: '{key}': node '{name}' has no "
                                    f"parameter '{pname}'", 260)
    return None


NodeInfo = tuple[str, str, Callable[[str], bool]]
"""A node of the process: (name, namespace, has_parameter)."""


def _ros_region(argv: Sequence[str]) -> Iterator[tuple[int, str]]:
    """(index, argument) of the ROS arguments (after ``--ros-args``, up to ``--``)."""
    inside = False
    for i, a in enumerate(argv):
        if a == "--ros-args":
            inside = True
        elif a == "--":
            inside = False
        elif inside:
            yield i, a


def cli_params(argv: Sequence[str]) -> list[tuple[str | None, str, str]]:
    """The ``-p [node:]name:=value`` overrides of a ROS argument list.

    Returns (node name or None for every node, parameter name, the argument as given).
    """
    out: list[tuple[str | None, str, str]] = []
    args = list(_ros_region(argv))
    for n, (i, a) in enumerate(args):
        if a not in ("-p", "--param") or n + 1 >= len(args) or args[n + 1][0] != i + 1:
            continue
        arg = args[n + 1][1]
        left = arg.split(":=", 1)[0]
        node, _, name = left.rpartition(":")
        out.append((node or None, name, arg))
    return out


def _applies(node: str, name: str, namespace: str) -> bool:
    """Whether a ``-p node:...`` prefix names the node ``name`` in ``namespace``."""
    fqn = (namespace.rstrip("/") + "/" + name) if namespace not in ("", "/") else "/" + name
    return node in (name, fqn) or _pattern(node).match(fqn) is not None


def unknown_problem(nodes: Sequence[NodeInfo], argv: Sequence[str]) -> str | None:
    """One error line for an override rclpy would ignore, else None.

    A ``-p name:=value`` that no node of the process declares (or a ``-p node:name:=...``
    naming no node here, or a parameter that node does not declare), and a ``--params-file``
    none of whose sections applies to a node of the process.
    """
    names = ", ".join(sorted({n for n, _, _ in nodes})) or "none"
    for node, pname, arg in cli_params(argv):
        targets = [has for n, ns, has in nodes if node is None or _applies(node, n, ns)]
        if not targets:
            return one_line(f"-p {arg}: no node '{node}' in this process (nodes: {names})",
                            260)
        if pname.startswith(_BUILTIN_PREFIXES) or any(has(pname) for has in targets):
            continue
        who = f"node '{node}' has" if node else f"no node of this process ({names}) has"
        return one_line(f"-p {arg}: {who} a parameter '{pname}' (rclpy would ignore it)", 260)
    for path in params_files(argv):
        doc, problem = load_params_file(path)
        if problem:
            return problem
        keys = [key for key, _ in _sections(doc)]
        if keys and not any(any(True for _ in node_sections(doc, n, ns)) for n, ns, _ in nodes):
            return one_line(f"params file {path}: its sections ({', '.join(keys[:5])}) name no "
                            f"node of this process (nodes: {names}); nothing in it would be "
                            "used", 260)
    return None
