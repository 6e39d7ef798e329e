"""Checkpoints of mutable object graphs: capture, restore, and a file format without pickle.

A generic walker (ROS-free) captures the *dynamic* state of an object graph -- numpy arrays
(a long list of same-shape arrays, e.g. a trace, as one stacked array), Python and numpy
scalars, lists/tuples/dicts of them, objects of this package (their
``__dict__``/slots, walked recursively) and numpy random generators (their
``bit_generator.state``) -- and restores it into a freshly built object of the same kind
(same scenario and seed).  Objects named as *static* (the line geometry, the rolling stock,
the scenario...) and everything reachable from them are not stored: the fresh object built
from the same scenario already holds them.  Aliasing inside the graph (two components that
share one array or one generator) is kept: a second reference is stored as a reference.

Because the walker looks at whatever attributes the components hold, a component that
gains, renames or re-shapes an array keeps being checkpointed without a change here; a
value it cannot store (a function, a file) raises :class:`CheckpointError` at capture time
rather than being silently lost.

File format (:func:`save` / :func:`load`): one ``.npz`` (``numpy.savez``, read back with
``allow_pickle=False``, so loading never runs code) holding the arrays ``a0``, ``a1``, ...
and ``header``: UTF-8 JSON bytes with ``format`` (:data:`FORMAT_VERSION`), the caller's
identity fields (e.g. scenario hash, seed, step) and ``tree``, the captured structure whose
leaves are JSON scalars (floats round-trip exactly through ``repr``; NaN/inf as JSON
``NaN``/``Infinity``) or references to the arrays.  Written atomically: a temporary file in
the same directory, flushed, then ``os.replace``.  Objects are rebuilt only for classes of
this package (``metro_atc.*``), without calling their ``__init__``.
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import importlib
import json
import os
import types
from collections import deque
from pathlib import Path
from typing import Any, Mapping

import numpy as np

FORMAT_VERSION = 1
"""Version of the checkpoint file layout (a file of another version is refused)."""

_PACKAGE = "metro_atc."
_SCALARS = (bool, int, float, str, type(None))


class CheckpointError(ValueError):
    """A state that cannot be captured, or a checkpoint that does not fit (one line)."""


def _qualname(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _resolve(name: str) -> type:
    """The class ``module:qualname`` of this package (nothing else is rebuilt)."""
    mod, _, qual = str(name).partition(":")
    if not (mod + ".").startswith(_PACKAGE) or not qual:
        raise CheckpointError(f"checkpoint names class {name!r} outside {_PACKAGE[:-1]}")
    obj: Any = importlib.import_module(mod)
    for part in qual.split("."):
        if part.startswith("<"):
            raise CheckpointError(f"checkpoint names a local class {name!r}")
        obj = getattr(obj, part)
    if not isinstance(obj, type):
        raise CheckpointError(f"checkpoint names {name!r}, which is not a class")
    return obj


def _function_name(v: Any) -> str | None:
    """``module:qualname`` of a module-level function of this package, else None.

    A compiled kernel's dispatcher is named by its Python function: code is stored by name,
    never as data.
    """
    fn = getattr(v, "py_func", v)
    mod, qual = getattr(fn, "__module__", None), getattr(fn, "__qualname__", None)
    if not (callable(v) and isinstance(mod, str) and isinstance(qual, str)) \
            or not (mod + ".").startswith(_PACKAGE) or "<" in qual:
        return None
    try:
        same = _lookup(mod, qual) is v
    except (ImportError, AttributeError):
        return None
    return f"{mod}:{qual}" if same else None


def _lookup(mod: str, qual: str) -> Any:
    obj: Any = importlib.import_module(mod)
    for part in qual.split("."):
        obj = getattr(obj, part)
    return obj


def _resolve_function(name: str) -> Any:
    """The module-level function ``module:qualname`` of this package.

    See :func:`_function_name`.
    """
    mod, _, qual = str(name).partition(":")
    if not (mod + ".").startswith(_PACKAGE) or not qual or "<" in qual:
        raise CheckpointError(f"checkpoint names function {name!r} outside {_PACKAGE[:-1]}")
    try:
        obj = _lookup(mod, qual)
    except (ImportError, AttributeError):
        raise CheckpointError(f"checkpoint names function {name!r}, not found") from None
    if isinstance(obj, type) or not callable(obj):
        raise CheckpointError(f"checkpoint names {name!r}, which is not a function")
    return obj


def _fields(obj: Any) -> dict[str, Any]:
    """The instance attributes of ``obj`` (``__dict__`` and slots).

    Less the names its class lists in ``checkpoint_transient`` (measurements of this
    process, e.g. a compile time).
    """
    out = dict(getattr(obj, "__dict__", {}))
    for cls in type(obj).__mro__:
        for s in getattr(cls, "__slots__", ()):
            if s not in ("__dict__", "__weakref__") and hasattr(obj, s):
                out[s] = getattr(obj, s)
    for name in getattr(type(obj), "checkpoint_transient", ()):
        out.pop(name, None)
    return out


def _static_paths(roots: Mapping[str, Any]) -> dict[int, list[Any]]:
    """Where each static object lies: id -> path from a named root (breadth first)."""
    paths: dict[int, list[Any]] = {}
    queue: deque[tuple[Any, list[Any]]] = deque((o, [name]) for name, o in roots.items())
    while queue:
        o, path = queue.popleft()
        if id(o) in paths or isinstance(o, _SCALARS) or isinstance(o, (np.generic, type)):
            continue
        paths[id(o)] = path
        if isinstance(o, np.ndarray):
            continue
        if isinstance(o, (list, tuple)):
            queue.extend((x, path + [i]) for i, x in enumerate(o))
        elif isinstance(o, dict):
            queue.extend((x, path + [[k]]) for k, x in o.items() if isinstance(k, (str, int)))
        elif type(o).__module__.startswith(_PACKAGE) or dataclasses.is_dataclass(o):
            queue.extend((x, path + [k]) for k, x in _fields(o).items())
    return paths


def _follow(roots: Mapping[str, Any], path: list[Any]) -> Any:
    """The static object at ``path`` (see :func:`_static_paths`) in ``roots``."""
    try:
        o = roots[path[0]]
        for step in path[1:]:
            if isinstance(step, list):
                o = o[step[0]]
            elif isinstance(step, int):
                o = o[step]
            else:
                o = getattr(o, str(step))
    except (KeyError, IndexError, AttributeError, TypeError):
        raise CheckpointError(f"static part {path!r} of the checkpoint not found in the "
                              "object restored into") from None
    return o


class _Capture:
    """One capture: the array list, the alias memo and the static ids."""

    def __init__(self, static: dict[int, list[Any]]) -> None:
        self.arrays: list[np.ndarray] = []
        self.memo: dict[int, int] = {}
        self.keep: list[Any] = []  # objects stay alive while the memo holds their id
        self.static = static

    def enc(self, v: Any, path: str) -> Any:
        if isinstance(v, enum.Enum):
            return {"enum": _qualname(type(v)), "v": v.value}
        if isinstance(v, np.generic):  # before the scalars: np.float64 is a float
            if v.dtype.hasobject:
                raise CheckpointError(f"{path}: object scalar")
            return {"np": v.dtype.str, "v": v.item()}
        if isinstance(v, _SCALARS):
            return v
        if id(v) in self.static:
            return {"static": self.static[id(v)]}
        if id(v) in self.memo:
            return {"ref": self.memo[id(v)]}
        ref = len(self.memo)
        self.memo[id(v)] = ref
        self.keep.append(v)
        if isinstance(v, np.ndarray):
            if v.dtype.hasobject:
                raise CheckpointError(f"{path}: object array")
            self.arrays.append(np.array(v, copy=True))
            return {"id": ref, "a": len(self.arrays) - 1}
        if isinstance(v, np.random.Generator):
            bg = v.bit_generator
            return {"id": ref, "rng": type(bg).__name__,
                    "s": self.enc(bg.state, path + ".state")}
        if type(v) is list and len(v) > 8 and _stackable(v):
            # a long list of same-shape arrays (a trace): one stacked array; an element
            # already seen elsewhere stays a reference
            refs = [[i, self.memo[id(x)]] for i, x in enumerate(v) if id(x) in self.memo]
            self.arrays.append(np.stack(v))
            return {"id": ref, "stack": len(self.arrays) - 1, "refs": refs}
        if type(v) in (list, tuple):
            return {"id": ref, "l" if type(v) is list else "t":
                    [self.enc(x, f"{path}[{i}]") for i, x in enumerate(v)]}
        if type(v) is dict:
            return {"id": ref, "d": [[self.enc(k, path + ".key"), self.enc(x, f"{path}[{k!r}]")]
                                     for k, x in v.items()]}
        if isinstance(v, types.ModuleType) and (v.__name__ + ".").startswith(_PACKAGE):
            return {"id": ref, "mod": v.__name__}
        fname = _function_name(v)
        if fname is not None:
            return {"id": ref, "fn": fname}
        cls = type(v)
        if not cls.__module__.startswith(_PACKAGE) or callable(v):
            raise CheckpointError(f"{path}: cannot checkpoint a {cls.__module__}."
                                  f"{cls.__qualname__}")
        if isinstance(v, tuple):  # a NamedTuple of this package
            return {"id": ref, "o": _qualname(cls),
                    "t": [self.enc(x, f"{path}[{i}]") for i, x in enumerate(v)]}
        return {"id": ref, "o": _qualname(cls),
                "f": {k: self.enc(x, f"{path}.{k}") for k, x in _fields(v).items()}}


class _Restore:
    """One restore: the arrays of the file and the objects rebuilt so far (by id)."""

    def __init__(self, arrays: Mapping[str, np.ndarray], static: Mapping[str, Any]) -> None:
        self.arrays = arrays
        self.static = static
        self.objs: dict[int, Any] = {}

    def dec(self, e: Any, into: Any = None) -> Any:
        """The value of ``e``; an object of the same class as ``into`` is restored in place."""
        if not isinstance(e, dict):
            return e
        if "enum" in e:
            return _resolve(e["enum"])(e["v"])
        if "np" in e:
            return np.dtype(e["np"]).type(e["v"])
        if "ref" in e:
            return self.objs[int(e["ref"])]
        if "static" in e:
            return _follow(self.static, list(e["static"]))
        ref = int(e["id"])
        if "a" in e:
            out: Any = np.array(self.arrays[f"a{int(e['a'])}"], copy=True)
        elif "rng" in e:
            bg_cls = getattr(np.random, str(e["rng"]), None)
            if not (isinstance(bg_cls, type) and issubclass(bg_cls, np.random.BitGenerator)):
                raise CheckpointError(f"unknown bit generator {e['rng']!r}")
            out = into if isinstance(into, np.random.Generator) \
                and type(into.bit_generator) is bg_cls else np.random.Generator(bg_cls())
            self.objs[ref] = out
            out.bit_generator.state = self.dec(e["s"])
            return out
        elif "o" in e:
            cls = _resolve(e["o"])
            if "t" in e:
                out = cls(*[self.dec(x) for x in e["t"]])
            else:
                out = into if type(into) is cls else object.__new__(cls)
                self.objs[ref] = out
                cur = _fields(out) if out is into else {}
                for k, x in e["f"].items():
                    object.__setattr__(out, k, self.dec(x, cur.get(k)))
                return out
        elif "fn" in e:
            out = _resolve_function(e["fn"])
        elif "mod" in e:
            if not (str(e["mod"]) + ".").startswith(_PACKAGE):
                raise CheckpointError(f"checkpoint names module {e['mod']!r} outside "
                                      f"{_PACKAGE[:-1]}")
            out = importlib.import_module(str(e["mod"]))
        elif "stack" in e:
            rows = self.arrays[f"a{int(e['stack'])}"]
            out = [np.array(r, copy=True) for r in rows]
            for i, r in e["refs"]:
                out[int(i)] = self.objs[int(r)]
        elif "l" in e or "t" in e:
            enc: list[Any] = list(e["l"] if "l" in e else e["t"])
            old = list(into) if isinstance(into, (list, tuple)) and len(into) == len(enc) \
                else [None] * len(enc)
            items = [self.dec(x, o) for x, o in zip(enc, old)]
            out = items if "l" in e else tuple(items)
        elif "d" in e:
            out = {_hashable(self.dec(k)): self.dec(x) for k, x in e["d"]}
        else:
            raise CheckpointError(f"malformed checkpoint entry with keys {sorted(e)[:5]}")
        self.objs[ref] = out
        return out


def _stackable(v: list[Any]) -> bool:
    """Every element an ndarray of one shape and plain dtype."""
    a0 = v[0]
    return isinstance(a0, np.ndarray) and not a0.dtype.hasobject and all(
        type(x) is np.ndarray and x.shape == a0.shape and x.dtype == a0.dtype for x in v)


def _hashable(k: Any) -> Any:
    return tuple(_hashable(x) for x in k) if isinstance(k, list) else k


def capture(obj: Any, static: Mapping[str, Any] | None = None
            ) -> tuple[dict[str, Any], list[np.ndarray]]:
    """The dynamic state of ``obj``: (JSON-able tree, arrays).

    ``static``: named objects (and all they reach) that are not stored: a reference to one
    is stored as its path and resolved in the ``static`` given to :func:`restore`.
    """
    c = _Capture(_static_paths(static or {}))
    fields = {k: c.enc(v, k) for k, v in _fields(obj).items()}
    return {"class": _qualname(type(obj)), "f": fields}, c.arrays


def restore(obj: Any, tree: Mapping[str, Any], arrays: Mapping[str, np.ndarray],
            static: Mapping[str, Any] | None = None) -> None:
    """Load a :func:`capture` of an object of the same class into ``obj`` (in place).

    ``static``: the same named static objects as at capture, as the fresh ``obj`` holds them.
    """
    if tree.get("class") != _qualname(type(obj)):
        raise CheckpointError(f"checkpoint of a {tree.get('class')}, not of a "
                              f"{_qualname(type(obj))}")
    r = _Restore(arrays, static or {})
    cur = _fields(obj)
    for k, e in tree["f"].items():
        object.__setattr__(obj, k, r.dec(e, cur.get(k)))


def content_hash(*parts: Any) -> str:
    """A short SHA-256 of the ``repr`` of ``parts`` (scenario, parameters) [hex, 16 chars]."""
    h = hashlib.sha256()
    for p in parts:
        h.update(repr(p).encode("utf-8", "replace"))
        h.update(b"\0")
    return h.hexdigest()[:16]


def save(path: Path, obj: Any, static: Mapping[str, Any] | None = None,
         **header: Any) -> Path:
    """Capture ``obj`` into ``path`` (``.npz``) atomically; ``header``: identity fields."""
    tree, arrays = capture(obj, static)
    return save_tree(path, tree, arrays, **header)


def save_tree(path: Path, tree: Mapping[str, Any], arrays: list[np.ndarray],
              **header: Any) -> Path:
    """Write a captured tree and its arrays into ``path`` atomically (tmp + rename)."""
    path = Path(path)
    head = dict(header, format=FORMAT_VERSION, tree=tree)
    blob = np.frombuffer(json.dumps(head, allow_nan=True).encode("utf-8"), dtype=np.uint8)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        named: dict[str, Any] = {f"a{i}": a for i, a in enumerate(arrays)}
        np.savez(fh, header=blob, **named)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path


def read(path: Path, **expect: Any) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read a checkpoint file: (header, arrays); each ``expect`` field must match the header.

    Raises :class:`CheckpointError` (one line) on a file that is not a checkpoint, of
    another format version, or made for another scenario/parameters.
    """
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as exc:
        raise CheckpointError(f"{path}: not a readable checkpoint ({exc})") from None
    try:
        head = json.loads(arrays.pop("header").tobytes().decode("utf-8"))
    except (KeyError, ValueError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{path}: no valid header ({exc})") from None
    if not isinstance(head, dict) or head.get("format") != FORMAT_VERSION:
        raise CheckpointError(f"{path}: checkpoint format {head.get('format')!r}, this "
                              f"version reads {FORMAT_VERSION}")
    for k, v in expect.items():
        if head.get(k) != v:
            raise CheckpointError(f"{path}: made for {k}={head.get(k)!r}, not {v!r}; "
                                  "refusing to resume from it")
    return head, arrays


def load(path: Path, obj: Any, static: Mapping[str, Any] | None = None,
         **expect: Any) -> dict[str, Any]:
    """Restore ``obj`` from the checkpoint at ``path`` (see :func:`read`); return the header."""
    head, arrays = read(path, **expect)
    restore(obj, head["tree"], arrays, static)
    return head
