"""TractionCommand (an ATO's per-train ``/<train>/command`` echo): its encoder.

Layout: ``header``, ``train_id``, then the scalars of ``msg_defs/msg/TractionCommand.msg``
(``step``, ``effort``, ``mode``), read from the generated class (:data:`SCALARS`).  The ATO
publishes one per echoed train and step from the bytes built here (a rosidl message object
per echo cost ~40 us); the readers take message objects (``conv.traction_from_msg``).
"""

from __future__ import annotations

import struct

from metro_atc_msgs.msg import TractionCommand

from metro_atc.nodes.wire import cdr

HEAD = (("header", "header"), ("train_id", "string"))
"""The leading fields, written by hand."""
SCALARS = cdr.split_layout(TractionCommand, HEAD, "scalar")
"""The scalars after ``train_id``, in order, from the message class."""
cdr.require_names(TractionCommand, SCALARS, ("step", "effort", "mode"), ordered=True)
_ALIGN = struct.calcsize("<" + SCALARS[0].code)
"""Alignment of the first scalar [bytes]."""

_mids: dict[tuple[str, str], tuple[bytes, struct.Struct]] = {}


def encode(stamp: tuple[int, int], frame_id: str, train_id: str, step: int, effort: float,
           mode: int) -> bytes:
    """A TractionCommand's CDR bytes (what rclpy publishes for the same field values).

    ``stamp``: (sec, nanosec), e.g. :func:`cdr.stamp_parts`; ``effort`` [-1, 1]; ``mode``
    a TrainState.MODE_*.  Raises ValueError / struct.error on values the message cannot
    hold (the caller then publishes a message object, whose setters decide).  The bytes
    between the stamp and the scalars depend on the frame and the train id only (cached).
    """
    if type(effort) is not float or type(step) is not int or type(mode) is not int:
        raise ValueError("step, effort or mode of another type")
    key = (frame_id, train_id)
    got = _mids.get(key)
    if got is None:
        frame = cdr.cdr_string(frame_id)
        pos = 8 + len(frame)  # body offset after the stamp and the frame id
        tid = cdr.cdr_string(train_id)
        pad = -pos % 4
        pos += pad + len(tid)
        tail = -pos % _ALIGN
        got = (frame + b"\x00" * pad + tid + b"\x00" * tail,
               cdr.scalars_struct(SCALARS, pos + tail))
        if len(_mids) < 4096:
            _mids[key] = got
    mid, st = got
    return b"".join((cdr.ENCAPSULATION, cdr.STAMP.pack(*stamp), mid, st.pack(step, effort, mode)))
