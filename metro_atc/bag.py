"""rosbag2 directories with MCAP storage, written without rosbag2 (ROS-free).

A bag is a directory with one MCAP file (``<name>_0.mcap``, profile ``ros2``) and a
``metadata.yaml`` (rosbag2 metadata version 9, the Jazzy layout), so ``ros2 bag info/play``,
the ``rosbags`` reader and Foxglove open it:

* one MCAP schema per type, encoding ``ros2msg``: the type's ``.msg`` text followed by every
  nested type's, each preceded by 80 ``=`` and ``MSG: pkg/msg/Name`` (rosbag2's
  ``docs/message_definition_encoding.md``);
* one channel per topic, message encoding ``cdr``, with the publishers' QoS in the channel
  metadata ``offered_qos_profiles`` (YAML, as rosbag2 writes it) and the type hash;
* messages as the serialized CDR bytes received, log time = receive time [ns since epoch].

The writer is the ``mcap`` library (Foxglove); this module only lays the records out the way
rosbag2 does.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Callable, Sequence

import yaml

PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
                        "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"})
"""Built-in field types of the .msg format."""

DELIMITER = "=" * 80
"""Separator line between the definitions of a ros2msg schema."""

_INFINITE = {"sec": 2147483647, "nsec": 4294967295}
"""rmw's 'infinite' duration as rosbag2 writes it in QoS YAML."""


@dataclass(frozen=True)
class Qos:
    """The QoS fields rosbag2 stores per publisher (enum names lower case, as rmw prints)."""

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    liveliness: str = "automatic"


def qos_yaml(profiles: Sequence[Qos]) -> str:
    """``offered_qos_profiles`` as rosbag2 (metadata v9) writes it: a YAML list in a string."""
    items = [{"history": q.history, "depth": int(q.depth), "reliability": q.reliability,
              "durability": q.durability, "deadline": dict(_INFINITE),
              "lifespan": dict(_INFINITE), "liveliness": q.liveliness,
              "liveliness_lease_duration": dict(_INFINITE),
              "avoid_ros_namespace_conventions": False} for q in profiles]
    return yaml.safe_dump(items, default_flow_style=False, sort_keys=False) if items else ""


def _field_types(text: str, package: str) -> list[str]:
    """The non-primitive field types (``pkg/msg/Name``) of one .msg text."""
    out = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
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


def message_definition(type_name: str, find_msg: Callable[[str, str], str]) -> str:
    """The ``ros2msg`` schema text of ``pkg/msg/Name`` with all nested definitions.

    ``find_msg(package, name)`` returns the text of ``share/<package>/msg/<name>.msg``.
    """
    pkg, _, name = type_name.split("/")
    main = find_msg(pkg, name)
    parts = [main.rstrip("\n")]
    seen = {type_name}
    todo = _field_types(main, pkg)
    while todo:
        t = todo.pop(0)
        if t in seen:
            continue
        seen.add(t)
        p, _, n = t.split("/")
        text = find_msg(p, n)
        parts.append(f"{DELIMITER}\nMSG: {t}\n{text.rstrip(chr(10))}")
        todo.extend(_field_types(text, p))
    return "\n".join(parts) + "\n"


@dataclass
class _Topic:
    name: str
    type: str
    qos: list[Qos]
    type_hash: str
    channel_id: int
    count: int = 0


@dataclass
class BagWriter:
    """Write one rosbag2 directory (MCAP storage) message by message.

    ``open`` creates the directory (it must not exist), ``add_topic`` registers a channel,
    ``write`` appends serialized CDR bytes, ``close`` finishes the MCAP file (summary and
    indexes) and writes ``metadata.yaml``.
    """

    path: Path
    find_msg: Callable[[str, str], str]
    topics: dict[str, _Topic] = field(default_factory=dict)
    _schemas: dict[str, int] = field(default_factory=dict)
    _fh: BinaryIO | None = None
    _writer: Any = None
    _t0: int | None = None
    _t1: int = 0
    custom_data: dict[str, str] = field(default_factory=dict)
    """``custom_data`` of ``metadata.yaml`` (strings; rosbag2's field for a recorder's own
    notes)."""

    @property
    def mcap_path(self) -> Path:
        """The storage file inside the bag directory."""
        return self.path / f"{self.path.name}_0.mcap"

    def open(self) -> None:
        """Create the directory and start the MCAP file."""
        from mcap.writer import CompressionType, Writer

        self.path.mkdir(parents=True, exist_ok=False)
        self._fh = self.mcap_path.open("wb")
        self._writer = Writer(self._fh, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library="metro_atc bag_recorder (mcap)")

    def add_topic(self, name: str, type_name: str, qos: Sequence[Qos],
                  type_hash: str = "") -> None:
        """Register ``name`` (type ``pkg/msg/Name``) with its publishers' QoS."""
        if name in self.topics:
            return
        sid = self._schemas.get(type_name)
        if sid is None:
            text = message_definition(type_name, self.find_msg)
            sid = self._writer.register_schema(name=type_name, encoding="ros2msg",
                                               data=text.encode())
            self._schemas[type_name] = sid
        meta = {"offered_qos_profiles": qos_yaml(qos)}
        if type_hash:
            meta["topic_type_hash"] = type_hash
        cid = self._writer.register_channel(topic=name, message_encoding="cdr",
                                            schema_id=sid, metadata=meta)
        self.topics[name] = _Topic(name, type_name, list(qos), type_hash, cid)

    def write(self, topic: str, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Append one serialized message of a registered topic."""
        t = self.topics[topic]
        self._writer.add_message(channel_id=t.channel_id, log_time=int(log_time_ns),
                                 data=bytes(data),
                                 publish_time=int(publish_time_ns or log_time_ns),
                                 sequence=t.count)
        t.count += 1
        self._t0 = log_time_ns if self._t0 is None else min(self._t0, log_time_ns)
        self._t1 = max(self._t1, log_time_ns)

    def close(self) -> None:
        """Finish the MCAP file and write ``metadata.yaml``."""
        if self._writer is None:
            return
        self._writer.finish()
        assert self._fh is not None
        self._fh.close()
        self._writer = None
        n = sum(t.count for t in self.topics.values())
        start = int(self._t0 or 0)
        duration = int(self._t1 - start) if n else 0
        info = {
            "version": 9,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": n,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.type,
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": qos_yaml(t.qos),
                                    "type_description_hash": t.type_hash},
                 "message_count": t.count} for t in self.topics.values()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.mcap_path.name],
            "files": [{"path": self.mcap_path.name,
                       "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": n}],
            "custom_data": dict(self.custom_data) or None,
            "ros_distro": "jazzy",
        }
        (self.path / "metadata.yaml").write_text(
            yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False))
