"""The ATO journal's written-out state line is ``json.dumps`` of the state.

A restarted ATO replays its journal and a resumed simulator is compared with it field for
field: the line must stay exactly what ``json.dumps`` wrote, for every value a validated
state can hold (NaN, infinities, signed zeros, subnormals, huge steps) and any other dict.
"""

from __future__ import annotations

import json
import math
import random
import struct

from metro_atc.nodes.ato_controller import _STATE_KEYS, state_json

SPECIAL = (0.0, -0.0, math.inf, -math.inf, math.nan, 5e-324, 1e16, 1e-7, 123456789.0,
           1.7976931348623157e308, 0.1, 1 / 3)


def _state(rng: random.Random) -> dict[str, object]:
    def f() -> float:
        if rng.random() < 0.3:
            return rng.choice(SPECIAL)
        return struct.unpack("<d", struct.pack("<Q", rng.getrandbits(64)))[0] \
            if rng.random() < 0.2 else rng.uniform(-1e5, 1e5)

    return {"step": rng.choice((0, 7, rng.getrandbits(64))), "t_s": f(), "x_m": f(),
            "v_mps": f(), "a_mps2": f(), "current_station": rng.randint(-1, 40),
            "next_station": rng.randint(-1, 40), "mode": rng.randint(0, 7),
            "departure_time_s": f(), "target_running_time_s": f(),
            "supervision_speed_mps": f(), "movement_authority_m": f(), "mass_kg": f(),
            "again": rng.random() < 0.5}


def test_state_line_equals_json_dumps() -> None:
    """20 000 random states (random bit patterns too): the same text as json.dumps."""
    rng = random.Random(2)
    for _ in range(20000):
        s = _state(rng)
        assert tuple(s) == _STATE_KEYS
        assert state_json(s) == json.dumps(s)


def test_other_dicts_fall_back_to_json_dumps() -> None:
    """Other keys, order or value types: still json.dumps's text."""
    rng = random.Random(4)
    s = _state(rng)
    cases = [{}, {"step": 1}, dict(reversed(list(s.items()))), {**s, "extra": 1},
             {**s, "mode": True}, {**s, "step": 1.0}, {**s, "t_s": 3}, {**s, "again": 1},
             {**s, "x_m": None}]
    for c in cases:
        assert state_json(c) == json.dumps(c)
