"""The simulator's kept brake sensor samples: how far back it keeps them.

A whole ``taipei_blue`` run once hit ``sensor_keep_max`` (200 000 kept samples, warnings
from t = 4 300 s on) with the brake diagnosis alive: the first train out of service kept its
last acknowledgement for ever, and the keep floor was the minimum over every train heard.
"""

from __future__ import annotations

import numpy as np

from metro_atc.nodes.sim_sensors import sensor_keep_floor

INF = np.inf


def test_an_acknowledged_train_holds_nothing_back() -> None:
    """Out of service (last sample acknowledged long ago): only the re-send window counts."""
    ack = np.array([4195.0, 6000.0, 5999.5])
    last = np.array([4195.0, 6000.0, 6000.0])
    assert sensor_keep_floor(6000.0, 120.0, ack, last) == 5880.0  # was 4195
    assert sensor_keep_floor(6000.0, 120.0, ack[:2], last[:2]) == 5880.0


def test_an_unacknowledged_train_is_kept_back_to_its_acknowledgement() -> None:
    """A reader that was down catches up on all it missed: kept back to its last ack."""
    ack = np.array([1000.0, 5990.0])
    last = np.array([5999.0, 6000.0])
    assert sensor_keep_floor(6000.0, 120.0, ack, last) == 1000.0


def test_never_acknowledged_trains_keep_the_window_only() -> None:
    """No acknowledgement yet (-inf): the ``resend_s`` window (a new reader's re-send)."""
    ack = np.array([-INF, -INF])
    last = np.array([50.0, 60.0])
    assert sensor_keep_floor(600.0, 120.0, ack, last) == 480.0
    assert sensor_keep_floor(600.0, 0.0, ack, last) == 600.0


def test_the_floor_never_passes_an_unacknowledged_sample() -> None:
    """Property on random fleets: every train's samples after its ack stay kept."""
    rng = np.random.default_rng(7)
    for _ in range(500):
        n = int(rng.integers(1, 31))
        now = float(rng.uniform(0.0, 7200.0))
        last = now - rng.uniform(0.0, 600.0, n)
        ack = np.where(rng.random(n) < 0.2, -INF, last - rng.exponential(50.0, n)
                       * (rng.random(n) < 0.5))
        floor = sensor_keep_floor(now, 120.0, ack, last)
        assert floor <= now - 120.0
        pending = np.isfinite(ack) & (last > ack + 1e-6)
        assert np.all(floor <= ack[pending])
        if not pending.any():
            assert floor == now - 120.0
