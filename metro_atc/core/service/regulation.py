"""Regulation across the turnback: Lin 2010a, Experiment 2 followed through the terminus.

The question: after an initial delay (180 s) at the first station in the morning peak, what
is the delay at the terminus, is it absorbed by the turnback buffer (Lin 2010a,
Experiment 2: 210 s at the 105 s headway), and what does the train's next trip, in the
other direction, inherit?

Leg 1: the closed loop of a regulator on the truth traffic model
(:func:`metro_atc.core.atr.evaluation.simulate_linked`, the same incident and seeded exponential
departure delays as the regulation bench, :func:`metro_atc.core.atr.evaluation.
incident_scenario`); the delayed train is the one at the first station in the initial state
(train -1 of the staggered state); its arrival deviation at the terminus is read from the
simulation's arrivals.  The turnback: :func:`metro_atc.core.service.turnback.link` with the
buffer, the delay it inherits = max(0, terminal delay - buffer).

Leg 2: the next trip in the other direction on the down line's traffic model
(:func:`direction_line`: the line as seen running down, with the down direction's flow
factor of the period, :func:`peak_lines`), the delayed train dispatched at
stage 0 with the inherited delay as its turnback link (``ready_dev_s``): whatever the
regulator commands, it does not leave the first platform before it can have turned back.
Trained regulators (AOC, DHP) have weights per direction: weights trained on the up
direction's traffic model are refused on the down line (traffic-model hash); a regulator
without weights for the down line is reported as not assessed on leg 2.
"""

from __future__ import annotations

from typing import Any, Dict, Optional, Sequence

import dataclasses

import numpy as np

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.evaluation import incident_scenario, simulate_linked
from metro_atc.core.atr.regulators import Regulator
from metro_atc.core.service.day import LIN2010A_TURNBACK_BUFFER_S, DayPlan
from metro_atc.core.service.planned import directed_line
from metro_atc.core.service.turnback import link

INITIAL_DELAY_S = 180.0
"""Initial delay at the first station [s] (Lin 2010a, Experiment 2)."""
DIRECTIONS = ("up", "down")
"""Running directions of a day (up: from the day's first terminus)."""


def direction_line(line: LineData, direction: str, flow_factor: float) -> LineData:
    """The traffic model of ``line`` run in ``direction`` at a period's ``flow_factor`` [-].

    :func:`metro_atc.core.service.planned.directed_line` (down: every array reversed) with
    the boarding rates p_j scaled by the flow factor, so that c_j = t_b p_j (Lin 2010a,
    eq. 4-5) is the direction's in that period; factor 1.0 leaves the line as it is (the up
    line at the morning peak keeps its traffic-model hash).  ValueError for a factor that
    is not finite and >= 0.
    """
    f = float(flow_factor)
    if not (np.isfinite(f) and f >= 0.0):
        raise ValueError(f"flow_factor must be finite and >= 0, got {flow_factor!r}")
    ln = directed_line(line, direction)
    if f == 1.0:
        return ln
    return dataclasses.replace(ln, boarding_pax_h=ln.boarding_pax_h * f)


def peak_period(plan: DayPlan) -> int:
    """Index of the day's peak period: the first with the shortest headway."""
    h = min(p.headway_s for p in plan.periods)
    return next(n for n, p in enumerate(plan.periods) if p.headway_s == h)


def peak_lines(plan: DayPlan, line: LineData) -> Dict[str, LineData]:
    """Both directions' traffic models of ``line`` at the day's peak (:func:`direction_line`).

    ``line`` is the ATR line of the day's line (e.g. the ``taipei_blue`` scenario's); the
    flow factors are the peak period's ``flow_up`` / ``flow_down``.  ValueError if the
    line's stations are not the day's.
    """
    if tuple(line.station_codes) != tuple(plan.line.station_codes):
        raise ValueError(f"line {line.name!r} does not have the stations of day {plan.name!r}")
    p = plan.periods[peak_period(plan)]
    return {"up": direction_line(line, "up", p.flow_up),
            "down": direction_line(line, "down", p.flow_down)}


def leg(line: LineData, reg: Regulator, x0_s: np.ndarray, w_dep: np.ndarray, horizon: int,
        ready_dev_s: Optional[np.ndarray] = None) -> Dict[str, Any]:
    """One trip leg of the closed loop; the tracked train and its deviations [s].

    Train -1 of the staggered state is tracked when ``ready_dev_s`` is None (the delayed
    train of the incident: stage k holds it at station k), train 0 otherwise (dispatched at
    stage 0 with its turnback link: stage k+1 holds it at station k).
    """
    tr = simulate_linked(line, reg, x0_s, w_dep, horizon, ready_dev_s)
    n = line.n_stations
    off = 0 if ready_dev_s is None else 1
    k = np.arange(n) + off
    dep = tr["x"][k, np.arange(n)]
    arr = tr["arr"][k, np.arange(n)]
    return {"first_departure_dev_s": float(dep[0]),
            "terminal_arrival_dev_s": float(arr[-1]),
            "terminal_departure_dev_s": float(dep[-1]),
            "worst_terminal_arrival_dev_s": float(np.nanmax(tr["arr"][:, -1])),
            "trajectory": tr}


def turnback_experiment(regs: Dict[str, Regulator], line: LineData,
                        down_regs: Dict[str, Optional[Regulator]], down_line: LineData,
                        min_turnback_s: float, buffers_s: Sequence[float] = (),
                        delay_s: float = INITIAL_DELAY_S, seed: int = 0,
                        weights: Optional[CostWeights] = None,
                        disturbances: bool = True) -> Dict[str, Any]:
    """Leg 1, the turnback and leg 2 for every regulator (module docstring); JSON-able.

    ``buffers_s``: further turnback buffers [s] to assess (e.g. the planned day's), besides
    Lin 2010a's 210 s; ``down_regs[name]`` None: leg 2 not assessed for that regulator.
    """
    w = weights if weights is not None else CostWeights()
    steps = w.horizon + line.n_stations
    out: Dict[str, Any] = {"initial_delay_s": delay_s, "seed": seed, "line": line.name,
                           "min_turnback_s": min_turnback_s, "methods": {}}
    for name, reg in regs.items():
        sc = incident_scenario(line, delay_s, seed, steps, disturbances=disturbances)
        one = leg(line, reg, sc["x0"], sc["w"], w.horizon)
        d = one["terminal_arrival_dev_s"]
        links = {}
        for b in (LIN2010A_TURNBACK_BUFFER_S, *buffers_s):
            lk = link(line.station_codes[-1], "next", 0.0, min_turnback_s + b,
                      min_turnback_s, d)
            links[f"{b:.0f}"] = {"buffer_s": lk.buffer_s,
                                 "inherited_delay_s": lk.inherited_delay_s,
                                 "absorbed": lk.inherited_delay_s == 0.0}
        row: Dict[str, Any] = {
            "terminal_arrival_delay_s": d,
            "terminal_departure_delay_s": one["terminal_departure_dev_s"],
            "worst_terminal_arrival_delay_s": one["worst_terminal_arrival_dev_s"],
            "turnback": links,
        }
        inherited = links[f"{LIN2010A_TURNBACK_BUFFER_S:.0f}"]["inherited_delay_s"]
        dreg = down_regs.get(name)
        if dreg is None:
            row["next_trip"] = None
        else:
            sc2 = incident_scenario(down_line, 0.0, seed + 1, steps, disturbances=disturbances)
            ready = np.zeros(steps)
            ready[0] = inherited
            two = leg(down_line, dreg, sc2["x0"], sc2["w"], w.horizon, ready_dev_s=ready)
            row["next_trip"] = {
                "inherited_delay_s": inherited,
                "first_departure_delay_s": two["first_departure_dev_s"],
                "terminal_arrival_delay_s": two["terminal_arrival_dev_s"],
            }
        out["methods"][name] = row
    return out


def experiment_text(res: Dict[str, Any]) -> str:
    """Plain-text report of :func:`turnback_experiment`."""
    lines = [f"Lin 2010a Exp. 2 through the turnback: {res['initial_delay_s']:.0f} s initial "
             f"delay at {res['line']} first station, seed {res['seed']}, minimum turnback "
             f"{res['min_turnback_s']:.0f} s"]
    for name, r in res["methods"].items():
        tb = ", ".join(f"buffer {v['buffer_s']:.0f} s -> inherits {v['inherited_delay_s']:.1f} s"
                       for v in r["turnback"].values())
        nxt = r["next_trip"]
        nx = ("next trip: not assessed (regulator not available on the down line)"
              if nxt is None else
              f"next trip departs {nxt['first_departure_delay_s']:.1f} s late, arrives "
              f"{nxt['terminal_arrival_delay_s']:.1f} s late")
        lines.append(f"  {name:5s} terminal arrival delay {r['terminal_arrival_delay_s']:6.1f} s "
                     f"(worst train {r['worst_terminal_arrival_delay_s']:6.1f} s); {tb}; {nx}")
    return "\n".join(lines)
