"""Bounded YAML loading for every file a user hands us (scenarios, parameter files).

``yaml.safe_load`` is safe against code execution but not against resource exhaustion: an
alias bomb (billion laughs) makes any later ``repr`` of the document exponential, 50 000
nested brackets overflow the composer's recursion, a 300 000-element list or a 1 GB file is
read in full, and an integer of 400 digits overflows the first ``float()`` it meets.  This
module loads YAML with hard limits, checked while the document is composed (before any
Python object of the document exists):

- file size (bytes, checked with ``stat`` before reading),
- aliases (``*ref``) per document, and the size of the document with aliases expanded,
- nesting depth of collections,
- number of nodes (scalars + collections),
- digits of an integer scalar.

Every violation raises :class:`YamlLimitError` (a ``ValueError``) with one short line.
:func:`short_repr` gives a bounded ``repr`` for error messages about loaded values.
"""

from __future__ import annotations

import dataclasses
import os
import reprlib
from pathlib import Path
from typing import Any

import yaml

__all__ = ["YamlLimits", "YamlLimitError", "load_yaml_text", "load_yaml_file", "short_repr",
           "one_line"]


@dataclasses.dataclass(frozen=True)
class YamlLimits:
    """Resource limits of one YAML document."""

    max_bytes: int = 256_000
    """Largest file / text accepted [bytes] (the shipped scenarios are < 13 kB)."""
    max_aliases: int = 100
    """Largest number of alias nodes (``*name``) per document."""
    max_depth: int = 32
    """Deepest nesting of mappings/sequences (the scenario schema needs 4)."""
    max_nodes: int = 20_000
    """Largest number of nodes (scalars, sequences, mappings) per document."""
    max_expanded_nodes: int = 1_000_000
    """Largest number of nodes with every alias expanded (a bomb of few aliases)."""
    max_int_digits: int = 30
    """Longest integer scalar [digits] (int64 has 19)."""


DEFAULT_LIMITS = YamlLimits()


class YamlLimitError(ValueError):
    """The YAML text breaks a limit of :class:`YamlLimits` or is malformed (one line)."""


def _make_loader(limits: YamlLimits) -> type:
    """A SafeLoader subclass enforcing ``limits`` while composing."""

    class _Loader(yaml.SafeLoader):
        def __init__(self, stream: Any) -> None:
            super().__init__(stream)
            self._depth = 0
            self._aliases = 0
            self._nodes = 0
            self._weights: dict[int, int] = {}
            self._keep: list[Any] = []

        def compose_node(self, parent: Any, index: Any) -> Any:  # noqa: D102
            if self.check_event(yaml.AliasEvent):
                self._aliases += 1
                if self._aliases > limits.max_aliases:
                    raise YamlLimitError(f"more than {limits.max_aliases} YAML aliases "
                                         "(anchors/aliases are limited)")
            self._nodes += 1
            if self._nodes > limits.max_nodes:
                raise YamlLimitError(f"more than {limits.max_nodes} YAML nodes")
            self._depth += 1
            if self._depth > limits.max_depth:
                raise YamlLimitError(f"YAML nested deeper than {limits.max_depth} levels")
            try:
                node = super().compose_node(parent, index)
            finally:
                self._depth -= 1
            self._weigh(node)
            return node

        def _weigh(self, node: Any) -> int:
            """Size of ``node`` with every alias expanded (memoised per node)."""
            w = self._weights.get(id(node))
            if w is not None:
                return w
            if isinstance(node, yaml.SequenceNode):
                w = 1 + sum(self._weights.get(id(c), 1) for c in node.value)
            elif isinstance(node, yaml.MappingNode):
                w = 1 + sum(self._weights.get(id(k), 1) + self._weights.get(id(v), 1)
                            for k, v in node.value)
            else:
                w = 1
            if w > limits.max_expanded_nodes:
                raise YamlLimitError(f"YAML expands to more than {limits.max_expanded_nodes} "
                                     "nodes through aliases")
            self._weights[id(node)] = w
            self._keep.append(node)
            return w

        def construct_yaml_int(self, node: Any) -> Any:  # noqa: D102
            text = str(node.value)
            if len(text.replace("_", "").lstrip("+-")) > limits.max_int_digits:
                raise YamlLimitError(f"integer with more than {limits.max_int_digits} digits "
                                     f"(line {node.start_mark.line + 1})")
            return super().construct_yaml_int(node)

    _Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)
    return _Loader


def one_line(text: str, limit: int = 240) -> str:
    """``text`` on one line, at most ``limit`` characters (ellipsis when cut)."""
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[:limit - 3] + "..."


def load_yaml_text(text: str, limits: YamlLimits = DEFAULT_LIMITS) -> Any:
    """Parse one YAML document from ``text`` within ``limits``.

    Raises :class:`YamlLimitError` (one line) for a limit or malformed YAML.
    """
    if len(text) > limits.max_bytes:
        raise YamlLimitError(f"larger than {limits.max_bytes} bytes")
    loader = _make_loader(limits)(text)
    try:
        return loader.get_single_data()
    except YamlLimitError:
        raise
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        what = getattr(exc, "problem", None) or str(exc)
        raise YamlLimitError(one_line(f"malformed YAML (not valid YAML){where}: {what}",
                                      160)) from None
    except (RecursionError, MemoryError, OverflowError, ValueError) as exc:
        raise YamlLimitError(one_line(f"unreadable YAML: {type(exc).__name__}: {exc}",
                                      160)) from None
    finally:
        loader.dispose()


def load_yaml_file(path: str | os.PathLike[str], limits: YamlLimits = DEFAULT_LIMITS) -> Any:
    """Read and parse a YAML file within ``limits`` (size checked before reading).

    Raises :class:`YamlLimitError` (one line, without the path: callers name the file)
    for a missing file, a directory, an unreadable or non-UTF-8 file, or any YAML limit.
    """
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise YamlLimitError(f"cannot read: {exc.strerror or exc}") from None
    if p.is_dir():
        raise YamlLimitError("is a directory, expected a YAML file")
    if not p.is_file():
        raise YamlLimitError("is not a regular file")
    if st.st_size > limits.max_bytes:
        raise YamlLimitError(f"file of {st.st_size} bytes, larger than the limit of "
                             f"{limits.max_bytes} bytes")
    try:
        with open(p, "rb") as fh:
            data = fh.read(limits.max_bytes + 1)
    except OSError as exc:
        raise YamlLimitError(f"cannot read: {exc.strerror or exc}") from None
    if len(data) > limits.max_bytes:
        raise YamlLimitError(f"larger than {limits.max_bytes} bytes")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise YamlLimitError(f"not a UTF-8 text file (byte {exc.start})") from None
    if "\x00" in text:
        raise YamlLimitError("not a text file (contains NUL bytes)")
    return load_yaml_text(text, limits)


_REPR = reprlib.Repr()
_REPR.maxlevel = 3
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = 4
_REPR.maxstring = 40
_REPR.maxother = 40
_REPR.maxlong = 24


def short_repr(value: Any) -> str:
    """A bounded ``repr`` of a loaded value for error messages (< ~80 characters)."""
    return one_line(_REPR.repr(value), 80)
