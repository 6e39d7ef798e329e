"""Named choices with one source each: name -> factory + one-line description (ROS-free).

A :class:`Registry` is the single list of the names of one kind of choice (the ATS
regulators, :mod:`metro_atc.core.atr.registry`; the ATO planners and trackers,
:mod:`metro_atc.core.ato.registry`).  Everything that needs the names takes them from it:
the launcher's argparse ``choices``, the nodes' parameter descriptors and validation, the
message conversions and the test against the ``.msg`` constants.  Adding a choice is one
:class:`Entry` plus the code it names.

An entry names its factory as ``"module:attribute"`` and imports it only when it is
called (:meth:`Entry.load`): the launcher reads the names without importing torch, scipy
or numba (``test/test_startup_imports.py``).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Mapping, Sequence


@dataclass(frozen=True)
class Entry:
    """One choice: its name, a one-line description and its factory (``module:attr``).

    ``flags``: properties the callers ask by name (e.g. a regulator that needs a weights
    file); an absent flag is False.
    """

    name: str
    description: str
    factory: str
    flags: frozenset[str] = field(default_factory=frozenset)

    def __post_init__(self) -> None:
        """Refuse a malformed entry (lowercase name, ``module:attr`` factory)."""
        if not self.name or self.name != self.name.lower() or not self.name.isidentifier():
            raise ValueError(f"registry name {self.name!r} is not a lowercase identifier")
        mod, sep, attr = self.factory.partition(":")
        if not (mod and sep and attr):
            raise ValueError(f"factory {self.factory!r} of {self.name!r} is not 'module:attr'")
        if "\n" in self.description or not self.description:
            raise ValueError(f"description of {self.name!r} must be one non-empty line")

    def load(self) -> Callable[..., Any]:
        """Import and return the factory (ImportError/AttributeError if it moved)."""
        mod, _, attr = self.factory.partition(":")
        obj: Any = importlib.import_module(mod)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj  # type: ignore[no-any-return]

    def has(self, flag: str) -> bool:
        """True when the entry carries ``flag``."""
        return flag in self.flags


class Registry(Mapping[str, Entry]):
    """The ordered entries of one kind of choice (``kind``: e.g. ``"regulator"``)."""

    def __init__(self, kind: str, entries: Sequence[Entry]) -> None:
        """Keep the entries in order; ValueError on a duplicate name."""
        self.kind = kind
        self._entries: dict[str, Entry] = {}
        for e in entries:
            if e.name in self._entries:
                raise ValueError(f"{kind} {e.name!r} registered twice")
            self._entries[e.name] = e

    def __getitem__(self, name: str) -> Entry:
        """The entry of ``name`` (KeyError when unknown, as a mapping)."""
        return self._entries[name]

    def __contains__(self, name: object) -> bool:
        """True when ``name`` is registered."""
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        """Names in registration order."""
        return iter(self._entries)

    def __len__(self) -> int:
        """Number of entries."""
        return len(self._entries)

    @property
    def names(self) -> tuple[str, ...]:
        """All names, in registration order (argparse ``choices``, parameter choices)."""
        return tuple(self._entries)

    def with_flag(self, flag: str) -> tuple[str, ...]:
        """Names of the entries that carry ``flag``, in order."""
        return tuple(n for n, e in self._entries.items() if e.has(flag))

    def entry(self, name: Any) -> Entry:
        """The entry of ``name``; ValueError (one line, naming the choices) when unknown."""
        if not isinstance(name, str) or name not in self._entries:
            raise ValueError(f"unknown {self.kind} {name!r}; choose one of "
                             f"{', '.join(self._entries)}")
        return self._entries[name]

    def check(self, name: Any) -> str:
        """``name`` if it is registered, else the ValueError of :meth:`entry`."""
        return self.entry(name).name

    def help(self) -> str:
        """One line: every name with its description (parameter and ``--help`` texts)."""
        return "; ".join(f"{n}: {e.description}" for n, e in self._entries.items())
