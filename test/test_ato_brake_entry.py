"""the ATO enters a braking curve from coasting without a step to full brake.

A real ATO anticipates the brake build-up: entering the stopping curve straight from
coasting, the effort ramps (jerk limited) from 0 to the planned braking and that ramp loses
speed only half as fast as the curve on average, so the train falls behind the curve unless
the ramp starts half its duration early.  Behind the curve, the tracker and the stopping
guard catch up with a full service brake (``gen_0009_inc``: 1.5 s at full service from
37 km/h, a brake false alarm).  Closed loop of :class:`OnboardAto` (tracker + guards) on a
plant with the jerk-limited brake demand of :mod:`metro_atc.core.plant.physics` (RK4 of
Li n.d.): level and downhill/uphill platforms, runs planned to coast into the stop.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from metro_atc.core.ato.onboard import MODE_ACCELERATE, SPEED_MARGIN_MPS, OnboardAto
from metro_atc.core.bridge import ato_limits_for
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track, effort_force, rk4_step

P = TAIPEI_MRT_6CAR
DT = 0.25
LIMITS = dataclasses.replace(ato_limits_for(P), grade_aware_braking=True,
                             speed_margin_mps=SPEED_MARGIN_MPS)
"""The ATO's limits as :func:`metro_atc.core.ato.onboard.envelope_limits` sets them."""


def _track(grade: float) -> Track:
    return Track(np.array([-1e12, 600.0]), np.array([0.0, grade]),
                 np.array([-1e12]), np.array([80.0 / 3.6]))


def _run(track: Track, x1: float, target_s: float) -> tuple[list[float], list[float], float]:
    """Drive 0 -> x1: (commanded efforts, speeds [m/s], final front position [m])."""
    ato = OnboardAto(P, track, [0.0, x1], control_period_s=DT, limits=LIMITS)
    ato.plan(0, target_s, 0.0)
    x, v, t, u_pl = 0.0, 0.0, 0.0, 0.0
    us, vs = [], []
    j_u = P.max_jerk_mps3 * DT / max(P.a1_mps2, P.max_service_brake_mps2)
    while t < 3.0 * target_s:
        s = {"step": int(t / DT), "t_s": t, "x_m": x, "v_mps": v, "mode": MODE_ACCELERATE,
             "current_station": 0, "next_station": 1, "departure_time_s": 0.0,
             "target_running_time_s": target_s, "supervision_speed_mps": np.inf,
             "movement_authority_m": np.inf}
        u = ato.control(s)[0]
        us.append(u)
        vs.append(v)
        if ato.core.last_reason == "stopped at platform":
            break
        # the plant's demand follows the command at the jerk limit
        u_pl = min(max(u, u_pl - j_u), u_pl + j_u)
        s1, v1 = rk4_step(P, 0.0, v, float(effort_force(P, v, u_pl)),
                          float(track.grade_at(x)), DT)
        x, v, t = x + float(s1), float(v1), t + DT
    return us, vs, x


@pytest.mark.parametrize("grade,x1,slack_s", [
    (0.0, 1500.0, 12.0), (0.0, 900.0, 8.0), (-0.02, 1500.0, 12.0), (0.015, 1200.0, 10.0)])
def test_entry_from_coasting_ramps_and_berths(grade: float, x1: float, slack_s: float) -> None:
    """Brake demand within the jerk limit, never full service, stop within +-0.30 m."""
    track = _track(grade)
    fast = OnboardAto(P, track, [0.0, x1], control_period_s=DT, limits=LIMITS)
    t_min = fast.plan(0, 1.0, 0.0).profile.running_time_s
    us, vs, x = _run(track, x1, t_min + slack_s)
    du = np.abs(np.diff(np.asarray(us[:-1])))
    j_u = P.max_jerk_mps3 * DT / max(P.a1_mps2, P.max_service_brake_mps2)
    assert np.max(du) <= j_u + 1e-9
    u = np.asarray(us)
    coasted = np.flatnonzero((np.abs(u) < 0.05) & (np.asarray(vs) > 5.0))
    assert coasted.size, "the plan should coast into the stop"
    assert float(u.min()) > -0.95
    assert abs(x - x1) <= 0.30
