"""``python -m metro_atc run``: bring the graph up, run a scenario, tear down, report KPIs.

Like ``ros2 launch`` (which is not available on PyPI-only installs) but tested here: the node
executables installed at ``install/metro_atc/lib/metro_atc/`` are started as separate OS
processes, per-train ATO nodes composed several to a process (``--ato-per-process``).
``line_simulator`` drives the lockstep and exits when the scenario ends, after writing
``kpis.json`` (and events CSV and plots) into the output directory; the launcher then stops
every other process (SIGINT, then SIGKILL after a grace period; also on Ctrl-C/SIGTERM, so no
orphans remain) and prints the KPIs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

from metro_atc.dds import config_dir, dds_defaults

NODE_EXECUTABLES = ("line_simulator", "ats_regulator", "ato_controller", "brake_diagnostic")
REGULATORS = ("none", "lqr", "dhp", "aoc", "elqr")


def executable(name: str) -> list[str]:
    """Command prefix for a node executable: the installed one (where ``ros2 run`` looks)."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_prefix
        try:
            exe = Path(get_package_prefix("metro_atc")) / "lib" / "metro_atc" / name
            if exe.is_file() and os.access(exe, os.X_OK):
                return [str(exe)]
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    return [sys.executable, "-m", f"metro_atc.nodes.{name}"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m metro_atc run", description=__doc__)
    p.add_argument("--scenario", default="taipei_blue",
                   help="embedded scenario name or path to a scenario YAML (default taipei_blue)")
    p.add_argument("--regulator", choices=REGULATORS, default="none")
    p.add_argument("--out", default=None, help="output directory (KPIs, events CSV, PNGs)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--single-process", action="store_true",
                   help="run all nodes in this process on one SingleThreadedExecutor")
    p.add_argument("--ato-per-process", type=int, default=8,
                   help="ATO nodes composed per OS process (default 8)")
    p.add_argument("--free-run", action="store_true",
                   help="free-running at --rtf instead of the deterministic lockstep")
    p.add_argument("--rtf", type=float, default=10.0,
                   help="real-time factor in free-run mode (default 10)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=0.0,
                   help="stop after this much simulated time [s] (0: scenario end)")
    p.add_argument("--timeout", type=float, default=3600.0,
                   help="wall-clock limit for the whole run [s]")
    p.add_argument("--plots", action=argparse.BooleanOptionalAction, default=True,
                   help="write PNG plots into --out (default on)")
    p.add_argument("--log-dir", default=None, help="node logs (default OUT/logs)")
    return p


def common_params(a: argparse.Namespace, out_dir: Path) -> dict[str, Any]:
    """Parameters every node of the run gets."""
    return {"use_sim_time": True, "scenario": a.scenario}


def _ros_args(params: dict[str, Any], params_file: Path | None) -> list[str]:
    args = ["--ros-args"]
    if params_file is not None and params_file.is_file():
        args += ["--params-file", str(params_file)]
    for k, v in params.items():
        args += ["-p", f"{k}:={ros_param_value(v)}"]
    return args


def ros_param_value(v: Any) -> str:
    """A ``-p name:=value`` value that rcl's YAML parser reads back as exactly ``v``.

    A string that YAML would read as something else (a path containing ``": "``, ``#``,
    ``[`` or ``,``, or a word like ``true``) is JSON-quoted (a JSON string is a YAML
    double-quoted scalar); plain names and paths stay as they are.
    """
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(ros_param_value(x) for x in v) + "]"
    if isinstance(v, str):
        import yaml
        plain = re.fullmatch(r"[A-Za-z0-9_./~+-]+", v) is not None
        try:
            plain = plain and yaml.safe_load(v) == v
        except yaml.YAMLError:
            plain = False
        return v if plain else json.dumps(v)
    return str(v)


def check_out_dir(out_dir: Path) -> str | None:
    """Create ``out_dir`` and check a file can be written in it; return an error line or None.

    Called before any node starts (an unwritable directory would otherwise lose the KPIs
    at the end of the run).
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out_dir, prefix=".write_check_"):
            pass
    except OSError as exc:
        return f"output directory {out_dir}: not writable ({exc.strerror or exc})"
    return None


def build_commands(a: argparse.Namespace, train_ids: Sequence[str],
                   out_dir: Path) -> list[tuple[str, list[str]]]:
    """The process list of a run: (label, argv)."""
    cfg = config_dir()
    base = common_params(a, out_dir)
    sim_params = dict(base, seed=a.seed, lockstep=not a.free_run, real_time_factor=a.rtf,
                      out_dir=str(out_dir), plots=a.plots, exit_on_finish=True,
                      max_sim_time_s=float(a.duration))
    procs = [("line_simulator", executable("line_simulator")
              + _ros_args(sim_params, cfg / "line_simulator.yaml")),
             ("ats_regulator", executable("ats_regulator")
              + _ros_args(dict(base, regulator=a.regulator), cfg / "ats_regulator.yaml")),
             ("brake_diagnostic", executable("brake_diagnostic")
              + _ros_args(base, cfg / "brake_diagnostic.yaml"))]
    n = max(1, int(a.ato_per_process))
    for g in range(0, len(train_ids), n):
        group = list(train_ids[g:g + n])
        procs.append((f"ato_{group[0]}", executable("ato_controller")
                      + _ros_args(dict(base, train_ids=group), cfg / "ato_controller.yaml")))
    return procs


def _stop(procs: list[tuple[str, subprocess.Popen[bytes]]], grace_s: float = 5.0) -> None:
    for _, p in procs:
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + grace_s
    for _, p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait()


def main(argv: Sequence[str] | None = None) -> int:
    """Run one scenario through the graph; print KPIs (``--json``: one JSON object)."""
    a = _parser().parse_args(argv)
    dds_defaults()
    from metro_atc.core.line.scenario import ScenarioError, load_scenario
    try:
        scn = load_scenario(a.scenario)
        train_ids = list(scenario_train_ids(scn))
    except (ScenarioError, ValueError) as exc:
        print(f"metro_atc run: error: {exc}", file=sys.stderr)
        return 2
    out_dir = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="metro_atc_run_"))
    problem = check_out_dir(out_dir)
    if problem:
        print(f"metro_atc run: error: {problem}", file=sys.stderr)
        return 2
    t0 = time.monotonic()
    if a.single_process:
        from metro_atc.nodes.graph import run_single_process
        code = run_single_process(a, train_ids, out_dir)
    else:
        code = _run_processes(a, train_ids, out_dir)
    wall = time.monotonic() - t0
    kpi_file = out_dir / "kpis.json"
    if not kpi_file.is_file():
        print(f"metro_atc run: error: the simulator wrote no KPIs (exit {code}); "
              f"see the logs in {out_dir / 'logs'}", file=sys.stderr)
        return code or 1
    kpis = json.loads(kpi_file.read_text())
    kpis["wall_time_s"] = round(wall, 3)
    sim_t = float(kpis.get("sim_time_s", 0.0))
    kpis["real_time_factor"] = round(sim_t / wall, 2) if wall > 0 else math.nan
    kpis["regulator"] = a.regulator
    kpis["mode"] = "single_process" if a.single_process else "multi_process"
    kpis["out_dir"] = str(out_dir)
    kpi_file.write_text(json.dumps(kpis, indent=2, sort_keys=True))
    if a.json:
        print(json.dumps(kpis, sort_keys=True))
    else:
        _print_table(kpis)
    return code


def scenario_train_ids(scn: Any) -> list[str]:
    """Train ids of a loaded scenario (``train_01`` ...)."""
    return list(scn.train_ids)


def _run_processes(a: argparse.Namespace, train_ids: Sequence[str], out_dir: Path) -> int:
    log_dir = Path(a.log_dir) if a.log_dir else out_dir / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    procs: list[tuple[str, subprocess.Popen[bytes]]] = []
    interrupted = False

    def on_term(*_: Any) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    env = dict(os.environ, RCUTILS_LOGGING_BUFFERED_STREAM="0", PYTHONUNBUFFERED="1")
    try:
        for label, cmd in build_commands(a, train_ids, out_dir):
            log = open(log_dir / f"{label}.log", "wb")
            procs.append((label, subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                                  start_new_session=True, env=env)))
        sim = procs[0][1]
        deadline = time.monotonic() + a.timeout
        reported: set[str] = set()
        while sim.poll() is None:
            if time.monotonic() > deadline:
                print("metro_atc run: error: wall-clock timeout", file=sys.stderr)
                break
            for label, p in procs[1:]:
                if p.poll() not in (None, 0) and label not in reported:
                    reported.add(label)
                    print(f"metro_atc run: warning: {label} exited with {p.returncode} "
                          f"(log: {log_dir / (label + '.log')})", file=sys.stderr)
            time.sleep(0.1)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        _stop(procs)
        signal.signal(signal.SIGTERM, old)
    if interrupted:
        return 130
    rc = procs[0][1].returncode if procs else 1
    return 0 if rc == 0 else rc


def _print_table(k: dict[str, Any]) -> None:
    keys = ("trains", "completed_trains", "atp_violations", "atp_interventions",
            "min_separation_m", "energy_kwh", "max_delay_s", "recovery_time_s",
            "late_departures", "passengers_left_behind", "sim_time_s", "wall_time_s",
            "real_time_factor", "lockstep_misses", "regulator", "out_dir")
    width = max(len(x) for x in keys)
    for key in keys:
        if key in k:
            print(f"{key:<{width}}  {k[key]}")
