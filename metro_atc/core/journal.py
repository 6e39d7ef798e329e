"""An append-only JSON-lines journal that survives a SIGKILL of its writer (ROS-free).

Each :meth:`Journal.append` writes one line and flushes it to the OS (a killed process
loses nothing written; a machine crash is not covered: no fsync per line).  Reading stops
at the first line that is not a JSON object (a line torn by a kill); :meth:`Journal.reset`
rewrites the journal atomically (tmp + rename) with the entries kept.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Callable, Optional, TextIO


class Journal:
    """One JSON-lines file (see module docstring)."""

    def __init__(self, path: Path) -> None:
        """Open (create) ``path``; :attr:`entries` holds what was there, torn tail dropped."""
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.entries: list[dict[str, Any]] = read_entries(self.path)
        self._fh: TextIO | None = None
        self.reset(self.entries)

    def append(self, entry: dict[str, Any]) -> None:
        """Write one entry (flushed to the OS before returning)."""
        assert self._fh is not None
        self._fh.write(json.dumps(entry) + "\n")
        self._fh.flush()

    def append_all(self, entries: list[dict[str, Any]],
                   encode: Callable[[dict[str, Any]], str] = json.dumps) -> None:
        """Write several entries in one write (flushed to the OS before returning).

        ``encode``: an entry's JSON text (what ``json.dumps`` gives; a writer of one kind of
        entry may pass a faster encoder of that kind).
        """
        assert self._fh is not None
        if entries:
            self._fh.write("".join(encode(e) + "\n" for e in entries))
            self._fh.flush()

    def reset(self, entries: list[dict[str, Any]]) -> None:
        """Replace the journal's content by ``entries`` (atomically) and go on appending."""
        if self._fh is not None:
            self._fh.close()
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        tmp.write_text("".join(json.dumps(e) + "\n" for e in entries), encoding="utf-8")
        os.replace(tmp, self.path)
        self._fh = open(self.path, "a", encoding="utf-8")


Accept = Callable[[dict[str, Any], list[dict[str, Any]]], bool]
"""A further check of a journal entry, given the entries read before it."""


def read_entries(path: Path, accept: Optional[Accept] = None) -> list[dict[str, Any]]:
    """The JSON objects of a journal file, up to the first bad line ([] if none).

    ``accept(entry, entries_so_far)``: a further check of each entry; the first entry it
    refuses (False, or a KeyError / TypeError / ValueError) ends the reading like a torn line.
    """
    out: list[dict[str, Any]] = []
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return out
    for line in text.splitlines():
        try:
            e = json.loads(line)
            ok = isinstance(e, dict) and (accept is None or bool(accept(e, out)))
        except (ValueError, KeyError, TypeError):
            ok = False
        if not ok:
            break
        out.append(e)
    return out
