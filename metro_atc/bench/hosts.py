"""Benchmark: the lockstep graph split over 1, 2 and 3 hosts (network namespaces).

``python -m metro_atc bench hosts [--scenario taipei_blue] [--duration 600] [--pairs 2]
[--hosts 1,2,3] [--json]``

Each configuration runs ``python -m metro_atc run --dds-hosts`` in the namespaces of a
private lab (:class:`metro_atc.netns.Lab`, bridge ``10.213.231.0/24``, DDS domain 231):

- 1 host: the whole graph in host 1 (its processes talk over shared memory);
- 2 hosts: ``simulator,ats,brake`` on host 1, ``ato`` on host 2;
- 3 hosts: ``simulator,ats`` on host 1, ``ato:1/2,brake`` on host 2, ``ato:2/2`` on host 3.

Per run: the simulator's stepping loop (``loop_wall_s``, the launcher's figure), the step
time = loop wall time / steps [ms], its real-time factor, and what crossed the bridge
(every host's ``eth0`` transmit counters: frames and bytes per step).  Runs go in
alternating order (1, 2, 3 hosts, then 3, 2, 1, ...), ``--pairs`` times each; medians.
All the "hosts" share this machine's cores: the figures show the cost of UDP through the
kernel between hosts against shared memory within one, not a gain in computing power.

Also the payload sizes of the lockstep messages from the wire codecs
(:mod:`metro_atc.nodes.wire`): per step the simulator sends each ATO host the whole fleet
state, each ATO process answers with its trains' commands, and the brake host gets the
sensor samples.  Needs root (network namespaces): otherwise one line and exit 2.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

DOMAIN = 231
"""DDS domain and lab subnet of the bench (tests take 30..229, ``bench perf`` 230)."""
CONFIGS = {1: ("",),
           2: ("simulator,ats,brake", "ato"),
           3: ("simulator,ats", "ato:1/2,brake", "ato:2/2")}
"""``--only`` per host of each configuration ('' : the whole graph)."""
RUN_TIMEOUT_S = 3600.0
"""Wall-clock limit of one run [s]."""


def wire_sizes(trains: int, samples: int = 1) -> dict[str, float]:
    """Payload bytes (CDR, without RTPS/UDP/IP headers) of the lockstep messages.

    ``fleet_state``: one FleetState of ``trains`` trains; ``fleet_command``: one
    FleetCommand of ``trains`` trains; ``sensors``: one FleetBrakeSensorData of
    ``samples`` samples (4 axles each); ``*_per_train`` / ``*_per_sample``: what a train
    (sample) adds, at scale [B].
    """
    import numpy as np

    from metro_atc.nodes.wire import cdr, fleet_command, fleet_sensors, fleet_state

    def ids(n: int) -> list[str]:
        return [f"train_{k:02d}" for k in range(1, n + 1)]

    def state(n: int) -> int:
        return len(fleet_state.encode(1.0, 1, cdr.string_seq(ids(n)),
                                      [np.zeros(n, f.dtype) for f in fleet_state.ARRAYS]))

    def command(n: int) -> int:
        return len(fleet_command.encode((1, 0), "line", 1, ids(n), [0.0] * n, [0] * n))

    def sensors(n: int) -> int:
        axles = {"wheel_angular_speed_radps", "clamp_force_n"}
        return len(fleet_sensors.encode(1.0, cdr.string_seq(ids(n)), [
            np.zeros(n * (4 if f.name in axles else 1), f.dtype)
            for f in fleet_sensors.ARRAYS]))

    def slope(size: Any) -> float:
        # per train at scale: the arrays' alignment padding (< 8 B each) left out
        return round((size(1000) - size(100)) / 900.0, 1)

    return {"fleet_state": state(trains), "fleet_state_per_train": slope(state),
            "fleet_command": command(trains), "fleet_command_per_train": slope(command),
            "sensors": sensors(samples), "sensors_per_sample": slope(sensors)}


def run_config(lab: Any, hosts: int, scenario: str, duration_s: float, tmp: Path,
               peers: Path) -> dict[str, Any]:
    """One run of a configuration; loop time, steps and bridge traffic."""
    before = [lab.counters(k) for k in range(1, hosts + 1)]
    procs = []
    for k, only in enumerate(CONFIGS[hosts], 1):
        out = tmp / f"h{hosts}_{k}_{time.monotonic_ns()}"
        out.mkdir()
        argv = [sys.executable, "-m", "metro_atc", "run", "--scenario", scenario, "--json",
                "--no-plots", "--progress", "never", "--out", str(out), "--dds-hosts",
                str(peers), "--duration", repr(duration_s), "--timeout", repr(RUN_TIMEOUT_S),
                *(["--only", only] if only else [])]
        procs.append(subprocess.Popen(lab.exec_argv(k, argv), cwd=out,
                                      env=dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN)),
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                      text=True, stdin=subprocess.DEVNULL))
    res = [p.communicate(timeout=RUN_TIMEOUT_S + 120) for p in procs]
    codes = [p.returncode for p in procs]
    # a cut run ends with 6 (CUT): the expected end of --duration
    if any(c not in (0, 6) for c in codes):
        raise RuntimeError(f"{hosts} hosts: exit codes {codes}: "
                           f"{' | '.join(e.strip().splitlines()[-1] for _, e in res if e)}")
    kpis = json.loads(res[0][0].strip().splitlines()[-1])
    after = [lab.counters(k) for k in range(1, hosts + 1)]
    steps = int(kpis["steps"])
    tx_b = sum(a["tx_bytes"] - b["tx_bytes"] for a, b in zip(after, before))
    tx_f = sum(a["tx_packets"] - b["tx_packets"] for a, b in zip(after, before))
    loop = float(kpis["loop_wall_s"])
    return {"hosts": hosts, "steps": steps, "trains": int(kpis["trains"]),
            "loop_wall_s": loop, "step_ms": 1000.0 * loop / max(steps, 1),
            "loop_real_time_factor": float(kpis["loop_real_time_factor"]),
            "lockstep_misses": int(kpis["lockstep_misses"]),
            "bridge_bytes_per_step": tx_b / max(steps, 1),
            "bridge_frames_per_step": tx_f / max(steps, 1)}


def main(argv: list[str] | None = None) -> int:
    """Run the configurations in alternating order; print medians (``--json``: one line)."""
    ap = argparse.ArgumentParser(prog="python -m metro_atc bench hosts", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="taipei_blue")
    ap.add_argument("--duration", type=float, default=600.0,
                    help="simulated seconds of each run (default 600)")
    ap.add_argument("--pairs", type=int, default=2, help="runs per configuration (medians)")
    ap.add_argument("--hosts", default="1,2,3", help="configurations (default 1,2,3)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    from metro_atc import netns
    try:
        configs = [int(x) for x in a.hosts.split(",")]
        if not configs or any(c not in CONFIGS for c in configs):
            raise ValueError
    except ValueError:
        print(f"bench hosts: --hosts {a.hosts!r}: a list of 1, 2, 3", file=sys.stderr)
        return 2
    if a.pairs < 1 or not a.duration > 0:
        print("bench hosts: --pairs >= 1 and --duration > 0", file=sys.stderr)
        return 2
    why = netns.unavailable()
    if why is not None:
        print(f"bench hosts: {why}", file=sys.stderr)
        return 2
    runs: dict[int, list[dict[str, Any]]] = {c: [] for c in configs}
    with tempfile.TemporaryDirectory(prefix="metro_atc_bench_hosts_") as tmp, \
            netns.Lab(max(configs), DOMAIN) as lab:
        peers: dict[int, Path] = {}
        for c in configs:
            peers[c] = Path(tmp) / f"peers{c}.txt"
            peers[c].write_text("".join(f"{lab.address(k)} host{k}\n"
                                        for k in range(1, c + 1)))
        for r in range(a.pairs):
            for c in (configs if r % 2 == 0 else configs[::-1]):
                got = run_config(lab, c, a.scenario, a.duration, Path(tmp), peers[c])
                runs[c].append(got)
                print(f"bench hosts: {c} host(s), run {r + 1}: step {got['step_ms']:.2f} ms, "
                      f"{got['loop_real_time_factor']:.1f}x real time, "
                      f"{got['bridge_bytes_per_step']:.0f} B / "
                      f"{got['bridge_frames_per_step']:.1f} frames per step on the bridge",
                      file=sys.stderr, flush=True)
    keys = ("step_ms", "loop_real_time_factor", "bridge_bytes_per_step",
            "bridge_frames_per_step")
    med = {c: {k: round(statistics.median(x[k] for x in runs[c]), 3) for k in keys}
           for c in configs}
    trains = next(iter(runs.values()))[0]["trains"]
    result = {"scenario": a.scenario, "duration_s": a.duration, "pairs": a.pairs,
              "trains": trains, "median": med, "runs": runs,
              "wire_bytes": wire_sizes(trains)}
    if a.json:
        print(json.dumps(result, sort_keys=True))
    else:
        print(f"{a.scenario}, {a.duration:g} s simulated, {trains} trains, {a.pairs} runs "
              "each in alternating order; medians:")
        print(f"{'hosts':>5}  {'step ms':>8}  {'RTF':>7}  {'bridge B/step':>13}  "
              f"{'frames/step':>11}")
        for c in configs:
            m = med[c]
            print(f"{c:>5}  {m['step_ms']:>8.2f}  {m['loop_real_time_factor']:>7.1f}  "
                  f"{m['bridge_bytes_per_step']:>13.0f}  {m['bridge_frames_per_step']:>11.1f}")
        w = result["wire_bytes"]
        print(f"payloads ({trains} trains): fleet state {w['fleet_state']} B "
              f"(+{w['fleet_state_per_train']} B a train), fleet command "
              f"{w['fleet_command']} B (+{w['fleet_command_per_train']} B a train), "
              f"sensor samples +{w['sensors_per_sample']} B a sample")
    return 0


if __name__ == "__main__":
    sys.exit(main())
