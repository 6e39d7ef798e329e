"""ROS-free replay of recorded ATO inputs through :class:`OnboardAto`.

The ATO's commands are a deterministic function of the states it acted on (the node's
journal, ``OUT/checkpoints/ato_<train>.jsonl``, holds exactly those).  This module replays
journals, or states recorded from the ROS-free closed loop, through fresh on-board ATOs the
way the node builds them, and writes one line per train-step: train, step, effort (exact,
``float.hex``), mode, the run planned at that state (if any) and the journal line the node
writes for it.  Two versions of the code compare by their outputs, byte for byte.

Command line (run it once per code version, ``PYTHONPATH`` choosing the version)::

    python test/ato_replay.py OUT/checkpoints replay.txt [--repeat 3]

prints the CPU time of the ``OnboardAto.control`` calls (median of ``--repeat`` replays).

The small version kept as a test (``test/test_ato_replay.py``): the ROS-free closed loop
(:func:`metro_atc.core.closed_loop.run_closed_loop`) on :data:`GOLDEN_CASES`, every ATO
command (effort bits, mode, plan) compared with the commands recorded from the code before
the issue-13 tracking fast paths (``test/data/ato_commands_golden.json.gz``; identical
commands mean identical plant states, hence identical ATO inputs all along).  Re-record
only when the commands are meant to change, and say so in the commit:
``PYTHONPATH=. python test/ato_replay.py --record-golden``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Iterable, Sequence


def load_journals(ck_dir: Path) -> dict[str, list[dict[str, Any]]]:
    """Every ``ato_<train>.jsonl`` of a checkpoint directory: train id -> its states."""
    out: dict[str, list[dict[str, Any]]] = {}
    for p in sorted(ck_dir.glob("ato_*.jsonl")):
        tid = p.name[len("ato_"):-len(".jsonl")]
        out[tid] = [json.loads(line) for line in p.read_text().splitlines() if line.strip()]
    return out


def interleave(states: dict[str, list[dict[str, Any]]]) -> list[tuple[str, dict[str, Any]]]:
    """The states of all trains in lockstep order: by step, then by train id."""
    rows = [(int(s["step"]), tid, i) for tid, lst in states.items() for i, s in enumerate(lst)]
    rows.sort()
    return [(tid, states[tid][i]) for _, tid, i in rows]


def make_atos(scenario: str, train_ids: Iterable[str],
              shared: dict[str, Any] | None = None) -> dict[str, Any]:
    """One on-board ATO per train, built as ``ato_controller`` builds it (ectp, fuzzy)."""
    from metro_atc.core.ato.onboard import OnboardAto, atp_model_for, envelope_limits, \
        tsr_zones
    from metro_atc.core.bridge import timetable_for, track_for, train_for
    from metro_atc.core.line.scenario import load_scenario

    scn = load_scenario(scenario)
    tt = timetable_for(scn)
    train, track = train_for(scn), track_for(scn)
    limits = envelope_limits(scn, train)
    atp = atp_model_for(scn, train)
    shared = {} if shared is None else shared
    period = float(scn.sim.control_period_s)
    return {tid: OnboardAto(train, track, tt.station_positions_m, planner="ectp",
                            tracker="fuzzy", control_period_s=period, limits=limits,
                            shared=shared, tsrs=tsr_zones(scn), atp=atp)
            for tid in train_ids}


def replay(atos: dict[str, Any], rows: Sequence[tuple[str, dict[str, Any]]]
           ) -> tuple[list[str], float]:
    """Feed ``rows`` through ``atos``; (one output line per row, CPU [s] of the controls)."""
    out: list[str] = []
    cpu = 0.0
    clock = time.process_time
    for tid, s in rows:
        ato = atos[tid]
        t0 = clock()
        u, mode, planned = ato.control(s)
        cpu += clock() - t0
        plan = "-" if planned is None else (
            f"{planned.station}:{float(planned.target_s).hex()}:"
            f"{float(planned.profile.running_time_s).hex()}:{bool(planned.late)}")
        out.append(f"{tid} {s['step']} {float(u).hex()} {int(mode)} {plan} {json.dumps(s)}")
    return out, cpu


GOLDEN = Path(__file__).parent / "data" / "ato_commands_golden.json.gz"
GOLDEN_CASES: tuple[tuple[str, float], ...] = (("taipei_blue", 300.0), ("gen:0:inc", 500.0))
"""(scenario, simulated seconds): the Blue line's first trains, and a generated line with a
TSR (known from 115 s at 6.5 km: the TSR caps and the hold rule act)."""


def golden_scenario(name: str) -> Any:
    """``taipei_blue`` or ``gen:<seed>[:inc]`` (a generated line, with incidents)."""
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.linegen import load_generated

    if name.startswith("gen:"):
        parts = name.split(":")
        return load_generated(int(parts[1]), incidents=parts[-1] == "inc")
    return load_scenario(name)


def closed_loop_commands(name: str, duration_s: float) -> list[str]:
    """Every ATO command of the ROS-free closed loop, in call order, as exact text.

    One line per call: the ATO's index (by first call), the state's step, the effort's
    bits, the mode and the plan made at that state (run, target and running-time bits).
    """
    from metro_atc.core.ato.onboard import OnboardAto
    from metro_atc.core.closed_loop import run_closed_loop

    out: list[str] = []
    index: dict[int, int] = {}
    orig = OnboardAto.control

    def control(self: Any, s: dict[str, Any]) -> Any:
        res = orig(self, s)
        u, mode, planned = res
        k = index.setdefault(id(self), len(index))
        plan = "-" if planned is None else (
            f"{planned.station}:{float(planned.target_s).hex()}:"
            f"{float(planned.profile.running_time_s).hex()}")
        out.append(f"{k} {s['step']} {float(u).hex()} {int(mode)} {plan}")
        return res

    OnboardAto.control = control  # type: ignore[method-assign]
    try:
        run_closed_loop(golden_scenario(name), duration_s=duration_s)
    finally:
        OnboardAto.control = orig  # type: ignore[method-assign]
    return out


def record_golden() -> None:
    """Write :data:`GOLDEN` from the code on ``PYTHONPATH`` (see the module docstring)."""
    import gzip

    data = {f"{n}@{d:g}": closed_loop_commands(n, d) for n, d in GOLDEN_CASES}
    GOLDEN.write_bytes(gzip.compress(json.dumps(data, indent=0).encode(), mtime=0))
    print({k: len(v) for k, v in data.items()})


def main(argv: Sequence[str] | None = None) -> int:
    """Replay a checkpoint directory's journals; write the outputs; print the CPU."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("checkpoints", type=Path, nargs="?")
    p.add_argument("output", type=Path, nargs="?")
    p.add_argument("--record-golden", action="store_true",
                   help="write test/data/ato_commands_golden.json.gz (see the docstring)")
    p.add_argument("--scenario", default="taipei_blue")
    p.add_argument("--repeat", type=int, default=1)
    a = p.parse_args(argv)
    if a.record_golden:
        record_golden()
        return 0
    if a.checkpoints is None or a.output is None:
        p.error("checkpoints and output are required (or --record-golden)")
    states = load_journals(a.checkpoints)
    rows = interleave(states)
    cpus = []
    lines: list[str] = []
    shared: dict[str, Any] = {}
    for _ in range(max(1, a.repeat)):
        # fresh ATOs per repeat, one shared cache (from the second repeat on the plans are
        # warm: the CPU is the tracking's)
        atos = make_atos(a.scenario, states, shared)
        lines, cpu = replay(atos, rows)
        cpus.append(cpu)
    a.output.write_text("\n".join(lines) + "\n")
    import metro_atc
    code = str(Path(metro_atc.__file__).parent)
    print(json.dumps({"code": code, "train_steps": len(rows), "trains": len(states),
                      "control_cpu_s": [round(c, 3) for c in cpus],
                      "median_cpu_s": round(statistics.median(cpus), 3),
                      "us_per_train_step": round(1e6 * statistics.median(cpus)
                                                 / max(len(rows), 1), 2)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
