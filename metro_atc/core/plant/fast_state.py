"""Persistent row blocks of component arrays for the compiled step (:mod:`.fast`).

The compiled kernel's call cost grows with its number of array arguments (numba unboxes each
one).  :class:`Blocks` holds per-train arrays of the components as the rows of a few 2-D
arrays passed as single arguments, packed once and reused:

* *owned* rows (state the kernel updates in place: ATP flags, counters, energy meter,
  stop points, ...) -- the component's attribute is rebound to the row view, so the
  component and the kernel share the memory and nothing is copied per step;
* *copied* rows (arrays the components rebind at discrete events and never edit in place
  except together with a rebinding of another array of the same component: fleet masks,
  mass constants, brake ratios, supervision grids) -- all the copied rows of a component
  are copied again when any of its arrays is rebound (those of the other components are
  not: the supervision grids are ~30 000 cells each, and the fleet's masks change at every
  station event).

Each :meth:`Blocks.sync` compares the components' current arrays with those of the last
sync by identity (one generated expression of ``is`` tests); an owned array
that a component rebound (the numpy supervision, a checkpoint restore) is copied into its
row and the attribute rebound to the row again.  A copy or pickle of a :class:`Blocks` syncs
in full on its next use (its row views no longer look at its blocks).
"""

from __future__ import annotations

import operator
from typing import Any

import numpy as np
from numpy.typing import NDArray


class Blocks:
    """Arrays ``part.attr`` of the components as rows of a few blocks (see module doc)."""

    def __init__(self, layout: tuple[tuple[tuple[int, ...], Any, int,
                                           tuple[tuple[int, str, bool | None], ...]], ...],
                 n_parts: int) -> None:
        """``layout``: per block (row shape, dtype, scratch rows, rows).

        Each row is (component index, attribute, owned); ``owned`` None: a copied row
        that is not checked (it is only ever rebound together with a checked copied row of
        the same component: e.g. ``davis_b`` with ``meff``).  Scratch rows (kernel work
        space, never synced) follow them.  :meth:`sync` gets ``n_parts`` components, each
        with at least two checked rows.
        """
        self.blocks = tuple(np.zeros((len(rows) + scratch,) + shape, dtype=dtype)
                            for shape, dtype, scratch, rows in layout)
        where: list[list[tuple[int, int, str, bool | None]]] = [[] for _ in range(n_parts)]
        for b, (_, _, _, rows) in enumerate(layout):
            for r, (part, attr, owned) in enumerate(rows):
                where[part].append((b, r, attr, owned))
        self.where = tuple(tuple(w) for w in where)
        self.getters = tuple(_getter(w) for w in self.where)
        self.check = _checker(self.where)
        self.views: tuple[tuple[Any, ...], ...] = ()
        self.ident: tuple[tuple[Any, ...], ...] = ((),) * n_parts
        self.flat: tuple[Any, ...] = ()
        """The arrays of the last sync, components one after the other."""

    def __getstate__(self) -> dict[str, Any]:
        """Pickle / deep copy without the row views and identities (full sync next)."""
        state = dict(self.__dict__)
        state["views"], state["ident"], state["flat"] = (), ((),) * len(self.where), ()
        state["getters"], state["check"] = (), None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Rebuild the attribute getters (see :meth:`__getstate__`)."""
        self.__dict__.update(state)
        self.getters = tuple(_getter(w) for w in self.where)
        self.check = _checker(self.where)

    def sync(self, parts: tuple[Any, ...]) -> tuple[NDArray[Any], ...]:
        """The blocks, up to date with the components ``parts`` (see module doc)."""
        if self.flat and self.check(parts, self.flat):
            return self.blocks
        return self._resync(parts)

    def reset(self) -> None:
        """Forget the components (the next :meth:`sync` is a full one)."""
        self.views, self.ident, self.flat = (), ((),) * len(self.where), ()

    def _resync(self, parts: tuple[Any, ...]) -> tuple[NDArray[Any], ...]:
        """Copy what changed into the blocks and rebind the owned attributes to rows."""
        if not self.views:
            self.views = tuple(tuple(blk) for blk in self.blocks)
        views = self.views
        ident = []
        for part, where, getter, old in zip(parts, self.where, self.getters, self.ident):
            if old and same(getter(part), old):  # this component rebound nothing
                ident.append(old)
                continue
            new = []
            for b, r, attr, owned in where:
                arr = getattr(part, attr)
                view = views[b][r]
                if owned:
                    if arr is not view:
                        self.blocks[b][r] = arr
                        setattr(part, attr, view)
                    arr = view
                else:  # copied rows: all again (an edit in place comes with a rebinding)
                    self.blocks[b][r] = arr
                if owned is not None:
                    new.append(arr)
            ident.append(tuple(new))
        self.ident = tuple(ident)
        self.flat = sum(self.ident, ())
        return self.blocks


def same(a: tuple[Any, ...], b: tuple[Any, ...]) -> bool:
    """True when both non-empty tuples hold the same objects, element by element."""
    return len(a) == len(b) and len(a) > 0 and all(map(operator.is_, a, b))


def _checker(where: tuple[tuple[tuple[int, int, str, bool | None], ...], ...]) -> Any:
    """``check(parts, flat)``: every checked ``parts[i].attr is flat[k]`` (generated code).

    One expression of plain attribute loads and ``is`` tests: about three times cheaper per
    step than :func:`operator.attrgetter` calls and a ``map`` over the results.
    """
    terms, k = [], 0
    for i, w in enumerate(where):
        for _, _, attr, owned in w:
            if owned is None:
                continue
            if not attr.isidentifier():
                raise ValueError(f"not an attribute name: {attr!r}")
            terms.append(f"parts[{i}].{attr} is flat[{k}]")
            k += 1
    src = "def check(parts, flat):\n    return (" + "\n            and ".join(terms) + ")\n"
    ns: dict[str, Any] = {}
    exec(compile(src, "<fast_state.check>", "exec"), ns)  # noqa: S102 (own names only)
    return ns["check"]


def _getter(where: tuple[tuple[int, int, str, bool | None], ...]) -> Any:
    """One call returning the checked arrays of a component (``owned`` not None)."""
    return operator.attrgetter(*(a for _, _, a, owned in where if owned is not None))


__all__ = ["Blocks"]
