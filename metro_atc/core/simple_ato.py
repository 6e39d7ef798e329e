"""Baseline ATO: flat-out profile with a braking-curve stop, tracked by a P controller.

This is the smallest real ATO behaviour: accelerate at full traction up to the
supervised limit minus a margin, cruise, and brake along ``v = sqrt(2 b (x_stop - x))`` to the
platform stop point. Units SI. The seed planners (MMAS, coasting control, fuzzy tracking)
live in :mod:`metro_atc.core.ato`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class FlatOutTracker:
    """Per-train flat-out speed tracker.

    Attributes are SI: ``brake_mps2`` planned service deceleration for the stop [m/s^2],
    ``service_brake_mps2`` the deceleration of a full service brake command [m/s^2],
    ``margin_mps`` below the supervised speed [m/s], ``gain`` effort per m/s of speed error
    [1/(m/s)], ``creep_mps`` final approach speed [m/s], ``stop_window_m`` distance at which
    the holding brake is applied [m], ``authority_margin_m`` distance kept to the end of the
    movement authority [m].
    """

    brake_mps2: float = 0.7
    service_brake_mps2: float = 1.0
    margin_mps: float = 1.5
    gain: float = 0.8
    creep_mps: float = 0.4
    stop_window_m: float = 0.3
    authority_margin_m: float = 10.0

    def target_speed(self, x_m: float, x_stop_m: float, limit_mps: float) -> float:
        """Reference speed [m/s] at x: min(limit - margin, stopping curve to x_stop)."""
        d = x_stop_m - x_m
        if d <= self.stop_window_m:
            return 0.0
        v_stop = math.sqrt(2.0 * self.brake_mps2 * d)
        return max(min(limit_mps - self.margin_mps, max(v_stop, self.creep_mps)), 0.0)

    def command(self, x_m: float, v_mps: float, x_stop_m: float, limit_mps: float,
                authority_m: float = math.inf) -> float:
        """Normalised effort in [-1, 1] (+ traction, - service brake).

        ``x_stop_m`` is the platform stop point, ``authority_m`` the end of the ATP movement
        authority [m]: the train aims to stop ``authority_margin_m`` short of it.
        Non-finite inputs give a full service brake (safe fallback).
        """
        if math.isfinite(authority_m):
            x_stop_m = min(x_stop_m, authority_m - self.authority_margin_m)
        if not all(math.isfinite(z) for z in (x_m, v_mps, x_stop_m, limit_mps)):
            return -1.0
        r = self.target_speed(x_m, x_stop_m, limit_mps)
        d = x_stop_m - x_m
        if r == 0.0:
            return -1.0 if v_mps > 0.0 or d <= self.stop_window_m else 0.0
        a_req = v_mps * v_mps / (2.0 * max(d - 0.5 * self.stop_window_m, 0.05))
        if a_req >= 0.9 * self.brake_mps2 and v_mps > self.creep_mps:
            # stopping: feed-forward the deceleration that ends exactly at the stop point
            u = -a_req / self.service_brake_mps2 - self.gain * max(v_mps - r, 0.0)
            return max(-1.0, min(0.0, u))
        u = self.gain * (r - v_mps)
        if r - v_mps > 0.5:
            u = 1.0
        return max(-1.0, min(1.0, u))
