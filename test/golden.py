"""Golden traces of the line plant: record once from a reference plant, replay open loop.

A *case* is a scenario (possibly a variant built from a packaged one), a seed and a window.
:func:`record` runs the plant closed loop with a command policy (the reference driver, plus
scripted NaN commands, traction pulses that provoke ATP interventions and ATS departure
commands) and stores the command sequence itself together with the plant outputs.
:func:`replay` feeds the stored commands open loop into the plant under test and returns the
same outputs, so the comparison does not depend on the driver.

Stored per step: ATP intervention count, event tuples and a sum of every sensor channel;
every ``stride`` steps the full per-train state (positions, speeds, accelerations, modes,
stations, energy terms, ATP state: limit, authority, speed code, EB/SB, interventions,
violations, loads, targets); for the fault case the raw sensor samples of a window.

Re-record (only when the physics is meant to change, and say so in the commit):
``python test/golden.py [case ...]``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(__file__).resolve().parent / "data" / "golden"
sys.path.insert(0, str(ROOT))

from metro_atc.core.plant.driver import simple_driver  # noqa: E402
from metro_atc.core.plant.line import LineSim  # noqa: E402
from metro_atc.core.line.scenario import (Scenario, _package_dir,  # noqa: E402
                                          parse_scenario)

U_SCALE = 10000.0
"""Commands are stored as int16 ``round(u * U_SCALE)``; ``U_NAN`` encodes NaN."""
U_NAN = -32768


@dataclasses.dataclass(frozen=True)
class Case:
    """One golden case: scenario, seed, window [s], state stride [steps], policy knobs."""

    name: str
    scenario: str
    seed: int
    t_end_s: float
    stride: int
    overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    nan_prob: float = 0.0
    pulse_trains: tuple[int, ...] = ()
    pulse_s: tuple[float, float] = (150.0, 20.0)
    ats_every: int = 0
    sensor_window_s: tuple[float, float] | None = None


CASES = [
    Case("taipei_blue", "taipei_blue", 3, 1800.0, 20, ats_every=3),
    Case("thsr", "thsr", 5, 2400.0, 8, nan_prob=0.01),
    Case("mini_pad_fault", "mini_pad_fault", 1, 1200.0, 2, ats_every=2,
         sensor_window_s=(265.0, 340.0)),
    # fixed block, wet rail, TSR + hold + breakdown incidents, wheel and sensor faults,
    # ATP-provoking traction pulses and NaN commands
    Case("mini_incidents", "mini", 2, 1200.0, 2, nan_prob=0.02, pulse_trains=(0,),
         ats_every=1, sensor_window_s=(420.0, 470.0),
         overrides={
             "signalling": {"mode": "fixed_block", "safety_margin_m": 40},
             "line": {"adhesion": "wet", "block_length_m": 300,
                      "temporary_speed_limits": [
                          {"start_m": 1300, "end_m": 1700, "limit_kmh": 30,
                           "from_s": 300, "to_s": 700}]},
             "incidents": [
                 {"kind": "tsr", "at_s": 200, "duration_s": 400, "start_m": 2100,
                  "end_m": 2400, "limit_kmh": 40},
                 {"kind": "hold", "train": "train_02", "station": "MN02", "duration_s": 45},
                 {"kind": "breakdown", "train": "train_01", "at_s": 520, "duration_s": 30}],
             "faults": [
                 {"kind": "wheel", "train": "train_01", "axle": 2, "at_s": 100,
                  "adhesion_factor": 0.3, "radius_factor": 0.97},
                 {"kind": "pad_mu", "train": "train_02", "axle": 0, "at_s": 200,
                  "duration_s": 300, "mu_b": 0.2},
                 {"kind": "sensor_stuck", "train": "train_01", "axle": 1, "at_s": 430,
                  "duration_s": 20, "channel": "wheel_omega"},
                 {"kind": "sensor_dropout", "train": "train_02", "axle": 0, "at_s": 440,
                  "duration_s": 15, "channel": "all"}],
             "disturbances": {"running_time_noise": 0.05, "departure_delay_prob": 0.5},
         }),
    # full traction most of the time into TSRs on a wet rail: ATP service and emergency
    # brake interventions (EB latched to standstill), stuck clamp force, accel dropout
    Case("mini_atp_eb", "mini", 4, 1200.0, 2, pulse_trains=(0, 1), pulse_s=(100.0, 90.0),
         sensor_window_s=(600.0, 640.0),
         overrides={
             "line": {"adhesion": "wet", "temporary_speed_limits": [
                 {"start_m": 1250, "end_m": 1450, "limit_kmh": 25, "from_s": 0},
                 {"start_m": 2300, "end_m": 2500, "limit_kmh": 30, "from_s": 400,
                  "to_s": 900}]},
             "faults": [
                 {"kind": "sensor_stuck", "train": "train_02", "axle": 3, "at_s": 610,
                  "duration_s": 20, "channel": "clamp_force"},
                 {"kind": "sensor_dropout", "train": "train_01", "at_s": 615,
                  "duration_s": 10, "channel": "accel"}],
         }),
]


def scenario_of(case: Case) -> Scenario:
    """The case's scenario: the packaged YAML with ``overrides`` merged key by key."""
    path = _package_dir() / f"{case.scenario}.yaml"
    raw = yaml.safe_load(path.read_text())
    for key, val in case.overrides.items():
        if isinstance(val, dict):
            raw.setdefault(key, {}).update(val)
        else:
            raw[key] = val
    return parse_scenario(yaml.safe_dump(raw), src=f"golden:{case.name}")


STATE_KEYS = ("x_m", "v_mps", "a_mps2", "mode", "current_station", "next_station",
              "traction_energy_j", "regen_energy_j", "atp_limit_mps", "movement_authority_m",
              "speed_code_mps", "atp_interventions", "load_pax", "in_service",
              "target_running_time_s", "departure_time_s")
ENERGY_KEYS = ("traction_wheel", "brake_rail", "electric_brake", "friction_brake",
               "resistance", "curve", "grade", "aux", "regen_to_line", "stop_correction",
               "kinetic", "substation")
SENSOR_CH = ("omega", "clamp", "accel", "vref", "car_mass")


def _snapshot(sim: LineSim) -> dict[str, np.ndarray]:
    """Full per-train state through the public API."""
    st = sim.states()
    out = {f"s_{k}": np.asarray(st[k], dtype=float) for k in STATE_KEYS}
    e = sim.energy_breakdown()
    out.update({f"e_{k}": np.asarray(e[k], dtype=float) for k in ENERGY_KEYS})
    out["atp_eb"] = np.asarray(sim.atp.eb, dtype=float)
    out["atp_sb"] = np.asarray(sim.atp.sb, dtype=float)
    out["atp_violations"] = np.asarray(sim.atp.violations, dtype=float)
    return out


class _Log:
    """Accumulates the outputs of a run (identical code path for record and replay)."""

    def __init__(self, case: Case) -> None:
        self.case = case
        self.n_int: list[int] = []
        self.events: list[tuple[float, ...]] = []
        self.sensor_sum: list[list[float]] = []
        self.states: dict[str, list[np.ndarray]] = {}
        self.raw: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "trains") + SENSOR_CH}

    def after_step(self, sim: LineSim, k: int, res: Any) -> None:
        self.n_int.append(int(res.atp_interventions))
        for e in res.events:
            self.events.append((k, e.train_idx, e.station_idx, 0 if e.kind == "arrival" else 1,
                                e.t_s, e.boarded, e.alighted, e.dwell_s, e.delay_s,
                                e.scheduled_t_s))
        b = res.sensor_arrays
        row = [0.0] * (len(SENSOR_CH) + 1)
        if b is not None:
            row = [float(b.t.size)] + [float(np.nansum(getattr(b, c))) for c in SENSOR_CH]
            w = self.case.sensor_window_s
            if w is not None and w[0] <= sim.t <= w[1]:
                for s in range(b.t.size):
                    self.raw["t"].append(np.full(b.trains.size, b.t[s]))
                    self.raw["trains"].append(np.asarray(b.trains, dtype=float))
                    for c in SENSOR_CH:
                        a = getattr(b, c)
                        self.raw[c].append(a if c == "car_mass" else a[s])
        self.sensor_sum.append(row)
        if (k + 1) % self.case.stride == 0:
            for key, val in _snapshot(sim).items():
                self.states.setdefault(key, []).append(val)

    def arrays(self, sim: LineSim) -> dict[str, np.ndarray]:
        out = {"n_int": np.asarray(self.n_int, dtype=np.int64),
               "events": np.asarray(self.events, dtype=float).reshape(-1, 10),
               "sensor_sum": np.asarray(self.sensor_sum, dtype=float)}
        for key, val in self.states.items():
            out["state_" + key] = np.asarray(val)
        if self.raw["t"]:
            for key, val in self.raw.items():
                out["raw_" + key] = np.concatenate(val)
        for key, val in _snapshot(sim).items():
            out["final_" + key] = val
        for key in ("x", "v", "atp"):
            out["trace_" + key] = np.asarray(sim.trace[key], dtype=float)
        out["kpis"] = np.frombuffer(json.dumps(sim.kpis(), sort_keys=True).encode(),
                                    dtype=np.uint8)
        return out


Policy = Callable[[LineSim, int], np.ndarray]


def _policy(case: Case) -> Policy:
    """Reference driver + scripted NaN commands and traction pulses (deterministic)."""
    rng = np.random.default_rng(1000 + case.seed)

    def pol(sim: LineSim, k: int) -> np.ndarray:
        u = np.asarray(simple_driver(sim), dtype=float).copy()
        period, length = case.pulse_s
        for i in case.pulse_trains:  # full traction for `length` of every `period` s
            if (k * sim.control_period_s) % period < length and sim.active_mask()[i]:
                u[i] = 1.0
        if case.nan_prob > 0.0:
            u = np.where(rng.random(u.size) < case.nan_prob, math.nan, u)
        return u
    return pol


def _quantise(u: np.ndarray) -> np.ndarray:
    return np.where(np.isnan(u), U_NAN, np.round(np.clip(u, -1.0, 1.0) * U_SCALE)
                    ).astype(np.int16)


def _decode(q: np.ndarray) -> np.ndarray:
    return np.where(q == U_NAN, math.nan, q.astype(float) / U_SCALE)


def _ats(sim: LineSim, case: Case, res: Any) -> list[tuple[float, ...]]:
    """ATS commands issued on arrivals: hold/advance, target running time, dwell cut."""
    cmds: list[tuple[float, ...]] = []
    if not case.ats_every:
        return cmds
    for e in res.events:
        if e.kind != "arrival" or (e.train_idx + e.station_idx) % case.ats_every:
            continue
        i, j = e.train_idx, e.station_idx
        dep = e.t_s + 25.0 + 7.0 * ((i + j) % 3)
        rt = math.nan if j % 2 else 80.0 + 5.0 * i
        lim = 30.0 if (i + j) % 4 == 0 else math.nan
        cmds.append((i, j, dep, rt, lim))
    return cmds


def record(case: Case) -> dict[str, np.ndarray]:
    """Run the reference plant closed loop and return commands + outputs."""
    sim = LineSim(scenario_of(case), seed=case.seed)
    pol = _policy(case)
    log = _Log(case)
    us: list[np.ndarray] = []
    ats: list[tuple[float, ...]] = []
    n_steps = int(round(case.t_end_s / sim.control_period_s))
    for k in range(n_steps):
        if sim.done:
            break
        q = _quantise(pol(sim, k))
        us.append(q)
        res = sim.step(_decode(q))
        log.after_step(sim, k, res)
        for c in _ats(sim, case, res):
            ats.append((k,) + c)
            sim.set_departure(int(c[0]), int(c[1]), c[2], c[3], c[4])
    out = log.arrays(sim)
    out["u"] = np.asarray(us, dtype=np.int16)
    out["ats"] = np.asarray(ats, dtype=float).reshape(-1, 6)
    return out


def replay(case: Case, u: np.ndarray, ats: np.ndarray) -> dict[str, np.ndarray]:
    """Feed the stored commands open loop into the plant under test."""
    sim = LineSim(scenario_of(case), seed=case.seed)
    log = _Log(case)
    by_step: dict[int, list[np.ndarray]] = {}
    for row in ats:
        by_step.setdefault(int(row[0]), []).append(row)
    for k in range(u.shape[0]):
        res = sim.step(_decode(u[k]))
        log.after_step(sim, k, res)
        for row in by_step.get(k, []):
            sim.set_departure(int(row[1]), int(row[2]), row[3], row[4], row[5])
    return log.arrays(sim)


def path_of(case: Case) -> Path:
    """Where a case's golden data lives."""
    return DATA / f"{case.name}.npz"


def main(names: list[str]) -> None:
    """Record the named cases, or every case (overwrites the golden data)."""
    DATA.mkdir(parents=True, exist_ok=True)
    for case in CASES:
        if names and case.name not in names:
            continue
        data = record(case)
        np.savez_compressed(path_of(case), **data)
        print(f"{case.name}: {data['u'].shape[0]} steps, {data['events'].shape[0]} events, "
              f"{int(data['n_int'].sum())} ATP interventions, "
              f"{path_of(case).stat().st_size / 1e3:.0f} kB")


if __name__ == "__main__":
    main(sys.argv[1:])
