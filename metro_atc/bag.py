"""rosbag2 directories with MCAP storage, written by the ``rosbags`` library (ROS-free).

A bag is what :class:`rosbags.rosbag2.Writer` writes (rosbag2 metadata version 9, the Jazzy
layout, MCAP storage with zstd-compressed chunks): a directory with one MCAP file (profile
``ros2``) and a ``metadata.yaml``, which ``ros2 bag info/play``, the ``rosbags`` reader and
Foxglove open:

* one MCAP schema per type, encoding ``ros2msg``, and its RIHS01 type hash, both generated
  by a ``rosbags`` typestore: the ROS 2 Jazzy types it ships, and the project's own
  (``metro_atc_msgs``, ``msg_defs/msg``) registered from their ``.msg`` text
  (``find_msg``), nested types first;
* one channel per topic, message encoding ``cdr``, with the publishers' QoS
  (``offered_qos_profiles``, :func:`qos_profile`);
* messages as the serialized CDR bytes received, log time = receive time [ns since epoch];
* the recorder's own notes in ``custom_data`` (strings).

This module only keeps the per-topic counts and registers the types; ``docs/bag.md`` says
what the library covers.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
                        "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"})
"""Built-in field types of the .msg format."""

_INFINITE = QosTime(sec=2147483647, nsec=4294967295)
"""rmw's 'infinite' duration as rosbag2 writes it in QoS YAML."""


def qos_profile(history: str = "keep_last", depth: int = 10, reliability: str = "reliable",
                durability: str = "volatile", liveliness: str = "automatic") -> Qos:
    """A publisher's QoS as the bag stores it (enum names as rmw prints them, any case)."""
    return Qos(history=QosHistory[history.upper()], depth=int(depth),
               reliability=QosReliability[reliability.upper()],
               durability=QosDurability[durability.upper()], deadline=_INFINITE,
               lifespan=_INFINITE, liveliness=QosLiveliness[liveliness.upper()],
               liveliness_lease_duration=_INFINITE, avoid_ros_namespace_conventions=False)


def _field_types(text: str, package: str) -> list[str]:
    """The non-primitive field types (``pkg/msg/Name``) of one .msg text."""
    out = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue  # (a constant's type is a primitive)
        typ = line.split()[0]
        typ = re.sub(r"\[.*\]$", "", typ)          # arrays: T[], T[3], T[<=3]
        typ = re.sub(r"<=\d+$", "", typ)           # bounded strings
        if typ in PRIMITIVES:
            continue
        if "/" in typ:
            pkg, name = typ.split("/")[0], typ.split("/")[-1]
        else:
            pkg, name = package, typ
        out.append(f"{pkg}/msg/{name}")
    return out


class TypeDefs:
    """Message definitions as a bag and a viewer take them: a ``rosbags`` Jazzy typestore.

    The ROS 2 Jazzy types it ships, and the others (the project's own, ``msg_defs/msg``)
    registered from their ``.msg`` text (``find_msg(package, name)``), nested types first.
    :meth:`msgdef` is a type's schema text in the ``ros2msg`` encoding (the type's .msg,
    then each nested type's after a ``MSG: pkg/msg/Name`` separator), the text rosbag2
    writes into an MCAP schema and the Foxglove WebSocket protocol advertises.
    """

    def __init__(self, find_msg: Callable[[str, str], str]) -> None:
        """A Jazzy typestore; ``find_msg`` gives the .msg text of a type it lacks."""
        self.find_msg = find_msg
        self.store: Any = get_typestore(Stores.ROS2_JAZZY)

    def register(self, type_name: str) -> None:
        """Make ``pkg/msg/Name`` known to the typestore (from its .msg text, nested first)."""
        if type_name in self.store.types:
            return
        pkg, _, name = type_name.split("/")
        text = self.find_msg(pkg, name)
        for nested in _field_types(text, pkg):
            self.register(nested)
        self.store.register(get_types_from_msg(text, type_name))

    def msgdef(self, type_name: str) -> str:
        """The ``ros2msg`` schema text of ``pkg/msg/Name`` (registered first if need be)."""
        self.register(type_name)
        return str(self.store.generate_msgdef(type_name, ros_version=2)[0])


@dataclass
class _Topic:
    name: str
    type: str
    connection: Any
    count: int = 0


@dataclass
class BagWriter:
    """Write one rosbag2 directory (MCAP storage) message by message.

    ``open`` creates the directory (it must not exist), ``add_topic`` registers a channel,
    ``write`` appends serialized CDR bytes, ``close`` finishes the MCAP file (summary and
    indexes) and writes ``metadata.yaml`` (with :attr:`custom_data`).
    """

    path: Path
    find_msg: Callable[[str, str], str]
    topics: dict[str, _Topic] = field(default_factory=dict)
    custom_data: dict[str, str] = field(default_factory=dict)
    """``custom_data`` of ``metadata.yaml`` (strings; rosbag2's field for a recorder's own
    notes)."""
    _writer: Any = None
    _store: Any = None

    def open(self) -> None:
        """Create the directory and start the MCAP file."""
        self._store = TypeDefs(self.find_msg)
        w = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        w.open()
        self._writer = w

    def add_topic(self, name: str, type_name: str, offered: Sequence[Qos],
                  type_hash: str = "") -> None:
        """Register ``name`` (type ``pkg/msg/Name``) with its publishers' QoS.

        ``type_hash``: the publishers' RIHS01 hash when known (else the typestore's).
        """
        if name in self.topics:
            return
        self._store.register(type_name)
        msgdef = rihs = None
        if type_hash:
            msgdef, rihs = self._store.msgdef(type_name), type_hash
        con = self._writer.add_connection(name, type_name, typestore=self._store.store,
                                          msgdef=msgdef, rihs01=rihs,
                                          offered_qos_profiles=list(offered))
        self.topics[name] = _Topic(name, type_name, con)

    def write(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Append one serialized message of a registered topic."""
        t = self.topics[topic]
        self._writer.write(t.connection, int(log_time_ns), data)
        t.count += 1

    def close(self) -> None:
        """Finish the MCAP file and write ``metadata.yaml``."""
        if self._writer is None:
            return
        for k, v in self.custom_data.items():
            self._writer.set_custom_data(k, str(v))
        self._writer.close()
        self._writer = None
