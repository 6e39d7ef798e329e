"""SUMO side by side: the graph-speed yardstick, reproducible on any machine (ROS-free).

``python -m metro_atc.bench.sumo [--json] [--scenario S] [--pairs N] [--duration S]
[--no-graph] [--out DIR]``

Writes a SUMO scenario from one of our scenarios (:func:`write_sumo_scenario`: the same
line, stations, timetable, train ids and rolling stock) and times, in ``--pairs``
alternating pairs (SUMO first in even pairs, ours first in odd ones):

(a) **SUMO standalone** (``sumo -c``, no GUI, step = our control period) to the end of the
    scenario or ``--duration`` simulated seconds;
(b) **SUMO + TraCI**: a Python controller over TraCI that every step reads every train's
    edge, position and speed (one ``get`` call each, as the issue's figure did;
    ``--traci-reads subscribe`` uses subscriptions instead) and commands each train
    (``traci.vehicle.setSpeed`` of a target speed: the current limit - 2 km/h, capped by a
    braking curve at the timetable's driving deceleration to the next stop point);
(c) **our core with sensors**: :func:`metro_atc.bench.perf.run_core` with the sensor samples
    consumed (``core_rtf_with_sensors``), same simulated duration;
(d) **our graph** (``python -m metro_atc run``, every node its own process, lockstep) for
    ``--graph-duration`` simulated seconds (default 1800 s, as ``bench perf``'s
    ``graph_rtf``), next to a SUMO + TraCI run over the same window; ``--no-graph`` skips.
    Ours is given twice: over the launcher's whole wall time (five processes started,
    DDS discovery, the end) and over its stepping loop alone (``loop_real_time_factor``),
    each beside SUMO + TraCI's like figure (its whole process; its loop).

It reports medians and ratios (ours / SUMO), the SUMO version, the machine load
(``os.getloadavg``) and checks that SUMO ran the trains (all arrived, every stop served in
order, the end-to-end run time of the middle train in SUMO and ours). Real-time factors are
simulated time / wall time of the simulation loop (SUMO: its own ``Duration`` statistics,
network loading excluded, as our plant's construction is excluded; the whole process'
wall time is reported too). Progress on stderr, one JSON object with ``--json``.

What SUMO models less (so we should be faster anyway): Krauss car-following with Euler
steps and constant acceleration/deceleration (no traction/resistance curves, no grades,
no curves, no jerk limit), no ATP braking curves or overspeed supervision, no passengers
(the timetable's dwells are fixed durations), no brake sensors, no turnback (a train
leaves the network at the end of the tail track), no departure disturbances, no TSRs.

SUMO is **not** a project dependency: install it apart, e.g.
``python3 -m venv /work/sumo_venv && /work/sumo_venv/bin/pip install eclipse-sumo traci``,
then ``export SUMO_HOME=$(/work/sumo_venv/bin/python -c 'import sumo; print(sumo.SUMO_HOME)')``
(or put its ``bin`` on ``PATH``). It is found via ``$SUMO_HOME``, ``sumo`` on ``PATH`` or
the ``sumo`` Python package; TraCI from ``$SUMO_HOME/tools`` (pure Python).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import math
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

from metro_atc.bench.progress import progress_enabled
from metro_atc.core.line.rolling_stock import KMH, train_params_for
from metro_atc.core.line.scenario import Scenario, load_scenario
from metro_atc.core.line.service import B_DRIVE_FRACTION, timetable_for

APPROACH_M = 100.0
"""Track before the first stop beyond one train length (the trains enter there) [m]."""
PLATFORM_EXTRA_M = 10.0
"""Platform (train stop) length beyond one train length [m]."""
COMMAND_MARGIN_MPS = 2.0 * KMH
"""The TraCI controller drives this far below the limit (as our reference driver) [m/s]."""
MIN_COMMAND_MPS = 1.0
"""Floor of the TraCI command near a stop (SUMO's own stop logic brakes to the point) [m/s]."""
AT_STOP_M = 1.0
"""A train within this distance of its next stop point has reached it (controller) [m]."""
NOT_FOUND = ("SUMO not found: set SUMO_HOME or put sumo on PATH (e.g. python3 -m venv "
             "/work/sumo_venv && /work/sumo_venv/bin/pip install eclipse-sumo traci; "
             "export SUMO_HOME=$(/work/sumo_venv/bin/python -c 'import sumo; "
             "print(sumo.SUMO_HOME)'))")
"""The one-line error when SUMO is missing."""


# --------------------------------------------------------------------------- scenario writer


@dataclass(frozen=True)
class SumoEdge:
    """One edge of the SUMO line: chainage [m] from ``start_m`` to ``end_m``, limit [m/s]."""

    id: str
    start_m: float
    end_m: float
    speed_mps: float

    @property
    def length_m(self) -> float:
        """Edge length [m]."""
        return self.end_m - self.start_m


@dataclass(frozen=True)
class SumoScenario:
    """A written SUMO scenario (:func:`write_sumo_scenario`); chainages as in our scenario.

    ``stops[j]`` = (train stop id, edge id, chainage of the stop point [m]);
    ``vehicles[i]`` = (train id, depart [s], [(stop id, dwell [s], until [s]), ...]).
    """

    name: str
    directory: Path
    files: dict[str, Path]
    edges: list[SumoEdge]
    stops: list[tuple[str, str, float]]
    vehicles: list[tuple[str, float, list[tuple[str, float, float]]]]
    step_length_s: float
    end_s: Optional[float]
    train_length_m: float
    decel_mps2: float
    line_length_m: float = field(default=0.0)


def _limit_at(scn: Scenario, x_m: float) -> float:
    """Permanent speed limit at chainage ``x_m`` [m/s] (step function of the scenario)."""
    lim = scn.line.line_speed_kmh
    for s in scn.line.speed_limits:
        if s.start_m <= x_m:
            lim = s.limit_kmh
    return lim * KMH


def _fmt(x: float) -> str:
    """A number for the XML files (millimetre / millisecond resolution)."""
    return f"{x:.3f}".rstrip("0").rstrip(".")


def _write_xml(root: ET.Element, path: Path) -> Path:
    """Write ``root`` as an indented XML file; returns ``path``."""
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="UTF-8", xml_declaration=True)
    return path


def write_sumo_scenario(scn: Scenario, out_dir: Path | str,
                        duration_s: Optional[float] = None) -> SumoScenario:
    """Write the SUMO files of ``scn`` into ``out_dir``; returns what was written.

    Files: ``line.nod.xml`` / ``line.edg.xml`` (plain network: one straight single-track
    line from ``APPROACH_M`` + one train length before the first stop to the end of the
    tail track, split at every station and permanent speed-limit change, ``allow="rail"``;
    ``netconvert`` builds ``line.net.xml``), ``stops.add.xml`` (one ``trainStop`` per
    station, ending at its stop point), ``trains.rou.xml`` (one rail ``vType`` from our
    rolling stock; every timetable train as a vehicle entering at its scheduled platform
    entry with its front at the first stop point, with its stops: dwell = our scheduled
    dwell, ``until`` = our scheduled departure), ``line.sumocfg`` (step = our control
    period, ``end`` = ``duration_s`` if given). Speeds [m/s], lengths [m], times [s].
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    p = train_params_for(scn)
    tt = timetable_for(scn)
    ln = scn.line
    st_x = [float(x) for x in tt.station_positions_m]
    x_start = st_x[0] - float(p.length_m) - APPROACH_M
    x_end = st_x[-1] + float(ln.tail_track_m)
    cuts = set(st_x) | {s.start_m for s in ln.speed_limits if x_start < s.start_m < x_end}
    xs = sorted({x_start, x_end} | {float(c) for c in cuts})
    edges: list[SumoEdge] = []
    for k in range(len(xs) - 1):
        a, b = xs[k], xs[k + 1]
        v = min(_limit_at(scn, a), float(p.max_speed_mps))
        if a >= st_x[-1]:
            v = min(v, ln.tail_speed_kmh * KMH)
        edges.append(SumoEdge(f"e{k:03d}", a, b, v))
    nodes = ET.Element("nodes")
    for k, x in enumerate(xs):
        ET.SubElement(nodes, "node", id=f"n{k:03d}", x=_fmt(x - x_start), y="0",
                      type="priority")
    edg = ET.Element("edges")
    for k, e in enumerate(edges):
        ET.SubElement(edg, "edge", id=e.id, attrib={"from": f"n{k:03d}"}, to=f"n{k + 1:03d}",
                      numLanes="1", speed=_fmt(e.speed_mps), allow="rail",
                      length=_fmt(e.length_m))
    add = ET.Element("additional")
    plat = float(p.length_m) + PLATFORM_EXTRA_M
    stops: list[tuple[str, str, float]] = []
    for j, x in enumerate(st_x):
        e = next(e for e in edges if abs(e.end_m - x) < 1e-6)
        sid = f"st{j:02d}"
        st = ln.stations[j]
        ET.SubElement(add, "trainStop", id=sid, lane=f"{e.id}_0",
                      startPos=_fmt(max(0.0, e.length_m - plat)), endPos=_fmt(e.length_m),
                      name=f"{st.code} {st.name}".strip(), friendlyPos="true")
        stops.append((sid, e.id, x))
    b_drive = B_DRIVE_FRACTION * float(p.max_service_brake_mps2)
    rou = ET.Element("routes")
    ET.SubElement(rou, "vType", id="metro", vClass="rail", carFollowModel="Krauss",
                  length=_fmt(p.length_m), accel=_fmt(p.a1_mps2), decel=_fmt(b_drive),
                  emergencyDecel=_fmt(p.emergency_brake_mps2),
                  apparentDecel=_fmt(b_drive), maxSpeed=_fmt(p.max_speed_mps), sigma="0",
                  tau="1", minGap=_fmt(scn.signalling.safety_margin_m), speedFactor="1",
                  speedDev="0")
    ET.SubElement(rou, "route", id="line", edges=" ".join(e.id for e in edges))
    first_edge = edges[0]
    vehicles: list[tuple[str, float, list[tuple[str, float, float]]]] = []
    order = sorted(range(len(tt.train_ids)), key=lambda i: (float(tt.arrival_s[i, 0]), i))
    for i in order:
        depart = float(tt.arrival_s[i, 0])
        veh = ET.SubElement(rou, "vehicle", id=tt.train_ids[i], type="metro", route="line",
                            depart=_fmt(depart), departLane="0",
                            departPos=_fmt(first_edge.length_m), departSpeed="0",
                            arrivalPos="max")
        vstops = []
        for j, (sid, _, _) in enumerate(stops):
            dwell = float(tt.dwell_s[i, j])
            until = float(tt.departure_s[i, j])
            ET.SubElement(veh, "stop", trainStop=sid, duration=_fmt(dwell), until=_fmt(until))
            vstops.append((sid, dwell, until))
        vehicles.append((tt.train_ids[i], depart, vstops))
    cfg = ET.Element("configuration")
    inp = ET.SubElement(cfg, "input")
    ET.SubElement(inp, "net-file", value="line.net.xml")
    ET.SubElement(inp, "route-files", value="trains.rou.xml")
    ET.SubElement(inp, "additional-files", value="stops.add.xml")
    tim = ET.SubElement(cfg, "time")
    ET.SubElement(tim, "begin", value="0")
    ET.SubElement(tim, "step-length", value=_fmt(scn.sim.control_period_s))
    if duration_s is not None:
        ET.SubElement(tim, "end", value=_fmt(duration_s))
    proc = ET.SubElement(cfg, "processing")
    # no rail signals on the line: moving block (else a rail vehicle is only inserted when
    # the whole line ahead is free)
    ET.SubElement(proc, "railsignal-moving-block", value="true")
    rep = ET.SubElement(cfg, "report")
    ET.SubElement(rep, "no-step-log", value="true")
    ET.SubElement(rep, "duration-log.statistics", value="true")
    files = {"nodes": _write_xml(nodes, out / "line.nod.xml"),
             "edges": _write_xml(edg, out / "line.edg.xml"),
             "stops": _write_xml(add, out / "stops.add.xml"),
             "routes": _write_xml(rou, out / "trains.rou.xml"),
             "config": _write_xml(cfg, out / "line.sumocfg")}
    return SumoScenario(scn.name, out, files, edges, stops, vehicles,
                        float(scn.sim.control_period_s), duration_s, float(p.length_m),
                        b_drive, x_end - x_start)


# --------------------------------------------------------------------------- finding SUMO


@dataclass(frozen=True)
class SumoInstall:
    """Where SUMO is: binaries, ``tools`` (TraCI) and its version string."""

    sumo: str
    netconvert: str
    home: Optional[str]
    version: str


def _home_from_package() -> Optional[str]:
    """``SUMO_HOME`` of the ``sumo`` Python package (eclipse-sumo), if importable."""
    try:  # an optional tool found at run time, not a dependency (no package.xml key)
        sumo = importlib.import_module("sumo")
    except Exception:  # noqa: BLE001 - any import failure means "not there"
        return None
    return str(getattr(sumo, "SUMO_HOME", "")) or None


def find_sumo() -> Optional[SumoInstall]:
    """SUMO via ``$SUMO_HOME``, ``sumo`` on ``PATH`` or the ``sumo`` package; None if absent."""
    homes: list[str] = []
    if os.environ.get("SUMO_HOME"):
        homes.append(os.environ["SUMO_HOME"])
    on_path = shutil.which("sumo")
    if on_path:
        bindir = Path(on_path).resolve().parent
        homes.append(str(bindir.parent))
        # a venv's console script: the package lives in ../lib/python*/site-packages/sumo
        homes += [str(d) for d in sorted(bindir.parent.glob("lib/python*/site-packages/sumo"))]
    pkg = _home_from_package()
    if pkg:
        homes.append(pkg)
    for h in homes:
        exe, net = Path(h) / "bin" / "sumo", Path(h) / "bin" / "netconvert"
        if exe.is_file() and os.access(exe, os.X_OK) and net.is_file():
            return SumoInstall(str(exe), str(net), h, _version(str(exe), h))
    if on_path and shutil.which("netconvert"):
        return SumoInstall(on_path, str(shutil.which("netconvert")), None,
                           _version(on_path, None))
    return None


def _env(home: Optional[str]) -> dict[str, str]:
    """Environment of the SUMO processes (``SUMO_HOME`` set when known)."""
    env = dict(os.environ)
    if home:
        env["SUMO_HOME"] = home
    return env


def _version(exe: str, home: Optional[str]) -> str:
    """``Eclipse SUMO sumo 1.28.0`` (first line of ``sumo --version``)."""
    try:
        r = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60,
                           env=_env(home))
        return (r.stdout.strip().splitlines() or ["?"])[0]
    except (OSError, subprocess.SubprocessError) as exc:
        return f"? ({exc})"


def build_network(inst: SumoInstall, sc: SumoScenario) -> Path:
    """``netconvert`` the plain nodes/edges into ``line.net.xml`` (no turnarounds)."""
    net = sc.directory / "line.net.xml"
    cmd = [inst.netconvert, "--node-files", str(sc.files["nodes"]), "--edge-files",
           str(sc.files["edges"]), "--output-file", str(net), "--no-turnarounds", "true",
           "--no-internal-links", "true", "--offset.disable-normalization", "true",
           "--no-warnings", "true"]
    r = subprocess.run(cmd, capture_output=True, text=True, env=_env(inst.home), timeout=300)
    if r.returncode != 0 or not net.is_file():
        raise RuntimeError(f"netconvert failed ({r.returncode}): {r.stderr.strip()[-300:]}")
    return net


# --------------------------------------------------------------------------- SUMO runs


_DURATION_RE = re.compile(r"Performance:\s*\n\s*Duration:\s*([0-9.]+)\s*(ms|s)\b")


def run_standalone(inst: SumoInstall, sc: SumoScenario, outputs: bool = True
                   ) -> dict[str, Any]:
    """(a) ``sumo -c line.sumocfg``; loop and process wall times [s], RTFs, outputs.

    ``outputs``: tripinfo and stop outputs (for :func:`check_sumo_run`); they cost little.
    """
    cmd = [inst.sumo, "-c", str(sc.files["config"]), "--no-warnings", "true"]
    if outputs:
        cmd += ["--tripinfo-output", str(sc.directory / "tripinfo.xml"),
                "--stop-output", str(sc.directory / "stops.xml")]
    c0 = _children_cpu_s()
    w0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=_env(inst.home),
                       cwd=sc.directory, timeout=3600)
    wall = time.perf_counter() - w0
    cpu = _children_cpu_s() - c0
    if r.returncode != 0:
        raise RuntimeError(f"sumo failed ({r.returncode}): {r.stderr.strip()[-300:]}")
    m = _DURATION_RE.search(r.stdout)
    loop = (float(m.group(1)) / (1000.0 if m.group(2) == "ms" else 1.0)) if m else wall
    sim_end = _sim_end(sc)
    return {"sim_time_s": sim_end, "loop_wall_s": loop, "process_wall_s": wall,
            "cpu_s": cpu, "rtf": sim_end / max(loop, 1e-9),
            "rtf_process": sim_end / max(wall, 1e-9), "rtf_cpu": sim_end / max(cpu, 1e-9)}


def _children_cpu_s() -> float:
    """User + system CPU time of this process' waited-for children so far [s]."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return float(ru.ru_utime + ru.ru_stime)


def _sim_end(sc: SumoScenario) -> float:
    """Simulated end [s]: ``end_s``, else the last arrival of the tripinfo output."""
    if sc.end_s is not None:
        return float(sc.end_s)
    trips = ET.parse(sc.directory / "tripinfo.xml").getroot()
    return max(float(t.get("arrival", "0")) for t in trips.iter("tripinfo"))


def _import_traci(inst: SumoInstall) -> Any:
    """The ``traci`` module (installed, else ``$SUMO_HOME/tools``)."""
    if inst.home and str(Path(inst.home) / "tools") not in sys.path:
        sys.path.append(str(Path(inst.home) / "tools"))
    return importlib.import_module("traci")  # optional, found at run time (not a dependency)


@contextlib.contextmanager
def _traci_errors(traci: Any) -> Iterator[None]:
    """TraCI's own exceptions as a one-line :class:`RuntimeError`."""
    try:
        yield
    except (traci.exceptions.FatalTraCIError, traci.exceptions.TraCIException) as exc:
        raise RuntimeError(f"TraCI: {type(exc).__name__}: {exc}") from None


def run_traci(inst: SumoInstall, sc: SumoScenario, end_s: float, reads: str = "get"
              ) -> dict[str, Any]:
    """(b) SUMO driven step by step by a Python controller over TraCI (module docstring).

    Every step: read every train's edge, lane position and speed (``reads="get"``: three
    calls per train; ``"subscribe"``: one subscription each), command
    ``setSpeed(min(limit - 2 km/h, max(sqrt(2 b d), 1 m/s)))`` with d the distance to the
    next stop point [m] and b the timetable's driving deceleration. ``end_s``: simulated
    seconds to run (``math.inf``: until no train is left; a run also ends then).
    """
    traci = _import_traci(inst)
    tc = traci.constants
    start = {e.id: e.start_m for e in sc.edges}
    limit = {e.id: e.speed_mps for e in sc.edges}
    stop_x = [x for _, _, x in sc.stops]
    nxt: dict[str, int] = {}
    label = f"metro_atc_bench_{os.getpid()}_{time.monotonic_ns()}"
    c0, p0 = _children_cpu_s(), time.process_time()
    w0 = time.perf_counter()
    end_arg = [] if math.isinf(end_s) else ["--end", _fmt(end_s)]
    with contextlib.redirect_stdout(sys.stderr), _traci_errors(traci):
        # (traci prints its connection retries on stdout)
        traci.start([inst.sumo, "-c", str(sc.files["config"]), "--no-warnings", "true",
                     *end_arg, "--tripinfo-output",
                     str(sc.directory / "tripinfo_traci.xml")], label=label,
                    stdout=subprocess.DEVNULL)
    conn = traci.getConnection(label)
    veh = conn.vehicle
    steps = commands = 0
    l0 = time.perf_counter()
    t = 0.0
    sub = (tc.VAR_ROAD_ID, tc.VAR_LANEPOSITION, tc.VAR_SPEED)
    with _traci_errors(traci):
        try:
            while t < end_s - 1e-9 and conn.simulation.getMinExpectedNumber() > 0:
                conn.simulationStep()
                steps += 1
                t = conn.simulation.getTime()
                if reads == "subscribe":
                    for vid in conn.simulation.getDepartedIDList():
                        veh.subscribe(vid, sub)
                    states = [(vid, r[tc.VAR_ROAD_ID], r[tc.VAR_LANEPOSITION], r[tc.VAR_SPEED])
                              for vid, r in veh.getAllSubscriptionResults().items()]
                else:
                    states = [(vid, veh.getRoadID(vid), veh.getLanePosition(vid),
                               veh.getSpeed(vid)) for vid in veh.getIDList()]
                for vid, road, pos, _speed in states:
                    if road not in start:
                        continue  # between edges (no internal links: not expected)
                    x = start[road] + pos
                    j = nxt.get(vid, 0)
                    while j < len(stop_x) and x >= stop_x[j] - AT_STOP_M:
                        j += 1
                    nxt[vid] = j
                    target = limit[road] - COMMAND_MARGIN_MPS
                    if j < len(stop_x):
                        target = min(target, max(math.sqrt(2.0 * sc.decel_mps2 * (stop_x[j] - x)),
                                                 MIN_COMMAND_MPS))
                    veh.setSpeed(vid, max(target, MIN_COMMAND_MPS))
                    commands += 1
            loop = time.perf_counter() - l0
        finally:
            conn.close()  # waits for SUMO to exit: its CPU time is then counted
    wall = time.perf_counter() - w0
    cpu_sumo, cpu_ctl = _children_cpu_s() - c0, time.process_time() - p0
    return {"sim_time_s": t, "loop_wall_s": loop, "process_wall_s": wall, "steps": steps,
            "commands": commands, "reads": reads, "rtf": t / max(loop, 1e-9),
            "rtf_process": t / max(wall, 1e-9), "cpu_s_sumo": cpu_sumo,
            "cpu_s_controller": cpu_ctl, "rtf_cpu": t / max(cpu_sumo + cpu_ctl, 1e-9),
            "arrived": _count_trips(sc.directory / "tripinfo_traci.xml")}


def _count_trips(path: Path) -> int:
    """Vehicles in a tripinfo output (arrived trains)."""
    return sum(1 for _ in ET.parse(path).getroot().iter("tripinfo"))


def check_sumo_run(sc: SumoScenario) -> dict[str, Any]:
    """Did SUMO run the trains? Arrivals, stops served in order, middle train's run time.

    Reads the standalone run's ``tripinfo.xml`` and ``stops.xml``; ``run_time_s`` of the
    middle train = arrival at the last stop - departure from the first [s].
    """
    trips = ET.parse(sc.directory / "tripinfo.xml").getroot()
    arrived = {t.get("id") for t in trips.iter("tripinfo")}
    served: dict[str, list[tuple[str, float, float]]] = {}
    for s in ET.parse(sc.directory / "stops.xml").getroot().iter("stopinfo"):
        sid = s.get("trainStop") or s.get("busStop") or ""
        served.setdefault(str(s.get("id")), []).append(
            (sid, float(s.get("started", "nan")), float(s.get("ended", "nan"))))
    want = [sid for sid, _, _ in sc.stops]
    in_order = sum(1 for vid, *_ in sc.vehicles if [x[0] for x in served.get(vid, [])] == want)
    mid = sc.vehicles[len(sc.vehicles) // 2][0]
    ms = served.get(mid, [])
    run_time = ms[-1][1] - ms[0][2] if len(ms) == len(want) and len(ms) > 1 else None
    return {"trains": len(sc.vehicles), "arrived": len(arrived & {v[0] for v in sc.vehicles}),
            "trains_all_stops_in_order": in_order,
            "stops_served": sum(len(v) for v in served.values()),
            "stops_expected": len(sc.vehicles) * len(want), "middle_train": mid,
            "middle_train_run_time_s": run_time}


# --------------------------------------------------------------------------- the comparison


def _load(scenario: str, work: Path) -> tuple[Scenario, str]:
    """Our scenario and the name/path ``run_core``/the graph take (``gen:N`` = linegen N)."""
    if scenario.startswith("gen:"):
        from metro_atc.core.linegen import generate_line, scenario_yaml
        path = work / f"gen_{int(scenario[4:]):04d}.yaml"
        path.write_text(scenario_yaml(generate_line(int(scenario[4:]))))
        scenario = str(path)
    return load_scenario(scenario), scenario


def _core(scenario: str, seed: int, duration_s: Optional[float], train_id: str
          ) -> dict[str, Any]:
    """(c) our core with sensors (``bench perf``'s run); RTFs and ``train_id``'s run time.

    Run time = arrival at the last stop - departure from the first [s] (None if not run).
    """
    from metro_atc.bench.perf import run_core
    r = run_core(scenario, seed, duration_s, sensors=True)
    log = r["sim"].run_log()
    i = list(log.train_ids).index(train_id)
    rt = float(log.act_arr[i, -1] - log.act_dep[i, 0])
    return {"sim_time_s": float(r["sim_time_s"]), "wall_s": float(r["wall_s"]),
            "rtf": float(r["rtf"]), "rtf_cpu": float(r["rtf_cpu"]),
            "completed_trains": int(r["kpis"]["completed_trains"]),
            "middle_train_run_time_s": rt if math.isfinite(rt) else None}


def _graph(scenario: str, seed: int, duration_s: float, domain_id: int) -> dict[str, Any]:
    """(d) our graph (``python -m metro_atc run``); RTF or the reason it did not run."""
    from metro_atc.bench.closed_loop import run_graph
    k = run_graph(scenario, "none", seed, duration_s, domain_id=domain_id,
                  progress=progress_enabled())
    if k is None:
        return {"rtf": None, "rtf_cpu": None, "rtf_loop": None}
    cpu = sum(float(v) for v in (k.get("node_cpu_s") or {}).values())
    sim = float(k.get("sim_time_s") or 0.0)
    # rtf: the launcher's whole wall time (start-up and end included); rtf_loop: the
    # stepping loop alone (``loop_real_time_factor``), as SUMO + TraCI's rtf is its loop's
    return {"rtf": k.get("real_time_factor"), "wall_s": k.get("wall_time_s"),
            "rtf_loop": k.get("loop_real_time_factor"), "loop_wall_s": k.get("loop_wall_s"),
            "sim_time_s": sim, "node_cpu_s": cpu, "rtf_cpu": sim / cpu if cpu > 0 else None}


def _median(xs: list[Any]) -> Optional[float]:
    """Median of the non-None values (None if none)."""
    v = [float(x) for x in xs if x is not None]
    return statistics.median(v) if v else None


def _ratio(a: Optional[float], b: Optional[float]) -> Optional[float]:
    """a / b rounded, None when either is missing."""
    return round(a / b, 3) if a is not None and b else None


def compare(scenario: str, pairs: int, duration_s: Optional[float], graph_duration_s: float,
            graph: bool, reads: str, seed: int, domain_id: int, work: Path,
            say: Callable[[str], None]) -> dict[str, Any]:
    """Write, build and run everything ``pairs`` times alternately; medians and ratios."""
    inst = find_sumo()
    if inst is None:
        raise RuntimeError(NOT_FOUND)
    scn, scn_arg = _load(scenario, work)
    sc = write_sumo_scenario(scn, work / "sumo", duration_s)
    build_network(inst, sc)
    say(f"bench sumo: {inst.version}; scenario {scn.name} written to {sc.directory}")
    check: dict[str, Any] = {}
    rows: list[dict[str, Any]] = []
    mid = sc.vehicles[len(sc.vehicles) // 2][0]  # the train whose run times are compared
    for k in range(pairs):
        row: dict[str, Any] = {"order": "sumo_first" if k % 2 == 0 else "ours_first"}

        def sumo_side() -> None:
            row["sumo"] = run_standalone(inst, sc)
            say(f"bench sumo: pair {k + 1}/{pairs}: SUMO standalone "
                f"{row['sumo']['rtf']:.0f}x ({row['sumo']['sim_time_s']:.0f} s simulated)")
            row["traci"] = run_traci(inst, sc, math.inf if duration_s is None else duration_s,
                                     reads)
            say(f"bench sumo: pair {k + 1}/{pairs}: SUMO + TraCI {row['traci']['rtf']:.1f}x")
            if graph:
                row["traci_graph_window"] = run_traci(inst, sc, graph_duration_s, reads)
                say(f"bench sumo: pair {k + 1}/{pairs}: SUMO + TraCI ({graph_duration_s:.0f}"
                    f" s) {row['traci_graph_window']['rtf']:.1f}x")

        def ours_side() -> None:
            row["core"] = _core(scn_arg, seed, duration_s, mid)
            say(f"bench sumo: pair {k + 1}/{pairs}: our core with sensors "
                f"{row['core']['rtf']:.0f}x ({row['core']['sim_time_s']:.0f} s simulated)")
            if graph:
                row["graph"] = _graph(scn_arg, seed, graph_duration_s, domain_id)
                g = row["graph"]["rtf"]
                say(f"bench sumo: pair {k + 1}/{pairs}: our graph "
                    f"{'failed' if g is None else f'{g:.1f}x'}")

        for side in ((sumo_side, ours_side) if k % 2 == 0 else (ours_side, sumo_side)):
            side()
        row["load_1min"] = round(os.getloadavg()[0], 2)
        if not check:
            check = check_sumo_run(sc)
        rows.append(row)

    def med(key: str, sub: str = "rtf") -> Optional[float]:
        return _median([r[key][sub] for r in rows if key in r])

    ratios = {
        "core_vs_sumo": _median([_ratio(r["core"]["rtf"], r["sumo"]["rtf"]) for r in rows]),
        "core_vs_traci": _median([_ratio(r["core"]["rtf"], r["traci"]["rtf"]) for r in rows]),
        "graph_vs_traci": _median([_ratio(r["graph"]["rtf"], r["traci_graph_window"]["rtf"])
                                   for r in rows if "graph" in r]) if graph else None,
        "graph_vs_traci_process": _median([
            _ratio(r["graph"]["rtf"], r["traci_graph_window"]["rtf_process"])
            for r in rows if "graph" in r]) if graph else None,
        "graph_loop_vs_traci": _median([
            _ratio(r["graph"].get("rtf_loop"), r["traci_graph_window"]["rtf"])
            for r in rows if "graph" in r]) if graph else None,
        "core_vs_sumo_cpu": _median([_ratio(r["core"]["rtf_cpu"], r["sumo"]["rtf_cpu"])
                                     for r in rows]),
        "graph_vs_traci_cpu": _median([_ratio(r["graph"]["rtf_cpu"],
                                              r["traci_graph_window"]["rtf_cpu"])
                                       for r in rows if "graph" in r]) if graph else None,
    }
    core0 = rows[0]["core"]
    return {
        "scenario": scn.name, "sumo_version": inst.version, "pairs": pairs,
        "sim_time_s": {"sumo": rows[0]["sumo"]["sim_time_s"], "core": core0["sim_time_s"],
                       "graph": graph_duration_s if graph else None},
        "step_length_s": sc.step_length_s, "trains": len(sc.vehicles),
        "traci_reads": reads,
        "median_rtf": {"sumo_standalone": med("sumo"), "sumo_standalone_process":
                       med("sumo", "rtf_process"), "sumo_traci": med("traci"),
                       "sumo_traci_graph_window": med("traci_graph_window") if graph else None,
                       "sumo_traci_graph_window_process":
                       med("traci_graph_window", "rtf_process") if graph else None,
                       "core_with_sensors": med("core"),
                       "graph": med("graph") if graph else None,
                       "graph_loop": med("graph", "rtf_loop") if graph else None},
        "median_rtf_cpu": {"sumo_standalone": med("sumo", "rtf_cpu"),
                           "sumo_traci": med("traci", "rtf_cpu"),
                           "sumo_traci_graph_window": med("traci_graph_window", "rtf_cpu")
                           if graph else None,
                           "core_with_sensors": med("core", "rtf_cpu"),
                           "graph": med("graph", "rtf_cpu") if graph else None},
        "ratios_ours_over_sumo": ratios,
        "check": {**check, "traci_arrived": rows[0]["traci"]["arrived"],
                  "core_completed_trains": core0["completed_trains"],
                  "core_middle_train_run_time_s": core0["middle_train_run_time_s"]},
        "load_1min": [r["load_1min"] for r in rows], "cpus": os.cpu_count(),
        "runs": rows,
    }


def main(argv: Optional[list[str]] = None) -> int:
    """Command-line entry point (module docstring); 2 when SUMO is missing."""
    ap = argparse.ArgumentParser(prog="metro_atc.bench.sumo",
                                 description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    ap.add_argument("--scenario", default="taipei_blue",
                    help="scenario name or YAML path, or gen:N (generated line, seed N)")
    ap.add_argument("--pairs", type=int, default=3, help="alternating pairs (medians)")
    ap.add_argument("--duration", type=float, default=None,
                    help="simulated seconds (default: the scenario's end)")
    ap.add_argument("--graph-duration", type=float, default=1800.0,
                    help="simulated seconds of the graph run and its TraCI twin")
    ap.add_argument("--no-graph", action="store_true", help="skip our ROS graph")
    ap.add_argument("--traci-reads", choices=("get", "subscribe"), default="get",
                    help="controller reads: one get call per value, or subscriptions")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--domain-id", type=int, default=80, help="ROS_DOMAIN_ID of the graph")
    ap.add_argument("--out", type=Path, default=None, help="keep the SUMO files here")
    a = ap.parse_args(argv)
    if a.pairs < 1 or (a.duration is not None and not 0 < a.duration <= 200_000) \
            or not 0 < a.graph_duration <= 200_000 or not 0 <= a.domain_id <= 232:
        ap.error("pairs >= 1, durations in (0, 200000] s, domain id in [0, 232]")
    if find_sumo() is None:
        print(f"bench sumo: {NOT_FOUND}", file=sys.stderr)
        return 2

    def say(msg: str) -> None:
        if progress_enabled():
            print(msg, file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory(prefix="metro_atc_sumo_") as tmp:
        work = a.out if a.out is not None else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        try:
            res = compare(a.scenario, a.pairs, a.duration, a.graph_duration, not a.no_graph,
                          a.traci_reads, a.seed, a.domain_id, work, say)
        except (RuntimeError, OSError, subprocess.SubprocessError, ValueError) as exc:
            print(f"bench sumo: {exc}", file=sys.stderr)
            return 1
    if a.json:
        print(json.dumps(res))
        return 0
    m, r, c = res["median_rtf"], res["ratios_ours_over_sumo"], res["check"]
    mc = res["median_rtf_cpu"]

    def f(x: Optional[float], d: int = 0) -> str:
        return "-" if x is None else f"{x:.{d}f}"

    print(f"SUMO side by side -- {res['scenario']}, {res['sumo_version']}, {res['trains']} "
          f"trains, step {res['step_length_s']} s, {res['pairs']} alternating pairs, "
          f"load {res['load_1min']} on {res['cpus']} CPUs")
    print("  real-time factors, medians (wall clock; per CPU second in brackets)")
    print(f"  SUMO standalone        {f(m['sumo_standalone'])}x ({f(mc['sumo_standalone'])}x;"
          f" whole process {f(m['sumo_standalone_process'])}x)")
    print(f"  SUMO + TraCI ({res['traci_reads']})    {f(m['sumo_traci'], 1)}x "
          f"({f(mc['sumo_traci'], 1)}x)")
    print(f"  our core with sensors  {f(m['core_with_sensors'])}x "
          f"({f(mc['core_with_sensors'])}x) = {f(r['core_vs_sumo'], 2)} x SUMO standalone "
          f"({f(r['core_vs_sumo_cpu'], 2)} x)")
    if res["sim_time_s"]["graph"] is None:
        print("  our graph              skipped (--no-graph)")
    else:
        print(f"  our graph ({f(res['sim_time_s']['graph'])} s)     {f(m['graph'], 1)}x "
              f"({f(mc['graph'], 1)}x) = {f(r['graph_vs_traci'], 2)} x SUMO + TraCI over the "
              f"same window ({f(m['sumo_traci_graph_window'], 1)}x; "
              f"{f(r['graph_vs_traci_process'], 2)} x its whole process)")
        print(f"  our graph's loop       {f(m['graph_loop'], 1)}x = "
              f"{f(r['graph_loop_vs_traci'], 2)} x SUMO + TraCI's loop (both without "
              f"start-up and end)")
    print(f"  SUMO ran: {c['arrived']}/{c['trains']} arrived, {c['stops_served']}/"
          f"{c['stops_expected']} stops; {c['middle_train']} end to end "
          f"{f(c['middle_train_run_time_s'])} s in SUMO, "
          f"{f(c['core_middle_train_run_time_s'])} s in ours")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
