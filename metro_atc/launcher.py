"""``python -m metro_atc run``: bring the graph up, run a scenario, tear down, report KPIs.

Like ``ros2 launch`` (which is not available on PyPI-only installs) but tested here: the node
executables installed at ``install/metro_atc/lib/metro_atc/`` are started as separate OS
processes, per-train ATO nodes composed several to a process (``--ato-per-process``).
``line_simulator`` drives the lockstep and exits when the scenario ends, after writing
``kpis.json`` (and events CSV and plots) into the output directory; the launcher then stops
every other process (SIGTERM, then SIGKILL after a grace period; also on Ctrl-C/SIGTERM, so
no orphans remain) and prints the KPIs. SIGTERM, not SIGINT: a node still importing its
modules then ends silently (SIGINT would raise KeyboardInterrupt with a traceback), one that
runs ends its loop and closes cleanly.

Respawn and resume: a process that dies (any exit but the simulator's normal end) is started
again with the same command line, at most ``--respawn-limit`` times per process, one line on
stderr each time; the simulator resumes from its last checkpoint (``--checkpoint-period``
simulated seconds apart, in ``OUT/checkpoints``) and the ATOs from their state journals, so
the run ends with the events and KPIs of an uninterrupted one.  The current process ids
are in ``LOG_DIR/pids.json``.  ``--resume`` continues a run whose launcher itself was
stopped (the checkpoints in ``--out`` are kept; otherwise a run starts by removing them).

No silent degradation: exit 0 only when the whole service ran (every train completed its
trips) and the outputs were written; every other end has its own exit code
(:class:`metro_atc.exit_codes.Exit`) and one line on stderr: input refused before the graph
started (2), a process failed beyond its respawn limit (3, naming it and its reason),
outputs not written (4), trains that did not complete (5), a run cut by ``--duration`` (6),
a graph whose ATOs never answered (7), the wall-clock ``--timeout`` (124).
``--record DIR`` adds the ``bag_recorder`` node (a rosbag2 MCAP directory of every topic)
and the simulator waits for it before step 0.  ``--foxglove [PORT]`` adds the
``foxglove_bridge`` node (the topics over the Foxglove WebSocket protocol, bound to
127.0.0.1 unless ``--foxglove-host`` says otherwise); the lockstep does not wait for it.

The process list comes from :func:`graph_processes` (ROS-free), which the launch file
``launch/metro_line.launch.py`` uses as well.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence, Union

import numpy as np

from metro_atc import deploy
from metro_atc.core.atr.registry import REGULATORS
from metro_atc.dds import clean_killed_shm, config_dir, dds_defaults
from metro_atc.exit_codes import NO_RESPAWN, NORMAL_END, Exit, outcome
from metro_atc.nodes.sim_outputs import regulator_label
from metro_atc.process_watch import PARENT_PID_ENV
from metro_atc.zygote import Client as Zygote
from metro_atc.zygote import Forked

Proc = Union["subprocess.Popen[bytes]", Forked]
"""A node process: exec'd (``Popen``) or forked by the zygote (:class:`Forked`)."""
ZYGOTE_ENV = "METRO_ATC_ZYGOTE"
"""Environment variable: ``0`` makes ``run`` exec every node process (no fork server)."""

NODE_EXECUTABLES = ("line_simulator", "ats_regulator", "ato_controller", "brake_diagnostic",
                    "bag_recorder", "foxglove_bridge")
RECORDER_NODE = "bag_recorder"
"""Node name of the recorder (the simulator waits for it before step 0)."""
BRIDGE_NODE = "foxglove_bridge"
"""Node name of the live view's WebSocket bridge (``--foxglove``)."""
POLL_S = 0.05
"""Wall period at which ``run`` looks at its processes [s] (the simulator's end is seen at
most this late; a look costs one ``waitpid`` per process)."""


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
    p.add_argument("--regulator", choices=REGULATORS.names, default="none",
                   help=REGULATORS.help())
    p.add_argument("--out", default=None, help="output directory (KPIs, events CSV, PNGs)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--single-process", action="store_true",
                   help="run all nodes in this process on one SingleThreadedExecutor")
    p.add_argument("--ato-per-process", type=int, default=30,
                   help="ATO nodes composed per OS process (default 30: one process for the "
                        "Blue line's 30 trains; on 2 cores one process answered the lockstep "
                        "9-19 %% faster than two)")
    p.add_argument("--free-run", action="store_true",
                   help="free-running at --rtf instead of the deterministic lockstep")
    p.add_argument("--rtf", type=float, default=10.0,
                   help="real-time factor in free-run mode (default 10)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=0.0,
                   help="stop after this much simulated time [s] (0: scenario end); a run "
                        "this cuts before every train completed exits 6 (kpis.json: "
                        "finished false, cut_at_s)")
    p.add_argument("--timeout", type=float, default=3600.0,
                   help="wall-clock limit for the whole run [s]")
    p.add_argument("--plots", action=argparse.BooleanOptionalAction, default=True,
                   help="write PNG plots into --out (default on)")
    p.add_argument("--log-dir", default=None, help="node logs (default OUT/logs)")
    p.add_argument("--record", nargs="?", const="", default=None, metavar="BAG_DIR",
                   help="record every topic to a rosbag2 MCAP directory (default OUT/bag); "
                        "the lockstep waits for the recorder before step 0")
    p.add_argument("--foxglove", nargs="?", type=int, const=8765, default=None,
                   metavar="PORT",
                   help="serve the topics to Foxglove / Lichtblick over WebSocket on PORT "
                        "(default 8765), on 127.0.0.1 only (see --foxglove-host); "
                        "/line/trains at a viewer's rate, not every step (docs/live_view.md)")
    p.add_argument("--foxglove-host", default="127.0.0.1", metavar="HOST",
                   help="address the --foxglove server binds (default 127.0.0.1; another "
                        "address exposes the live view to that network)")
    p.add_argument("--progress", choices=("auto", "always", "never"), default="auto",
                   help="progress lines on stderr while the graph runs (auto: when stderr is "
                        "a terminal)")
    p.add_argument("--train-regulator", choices=("auto", "never"), default="auto",
                   help="aoc/dhp: when no shipped or cached weights were trained on the "
                        "scenario's line (traffic-model hash), train them before the graph "
                        "starts (auto; progress on stderr, cached) or refuse (never)")
    p.add_argument("--accept-worse-regulator", action="store_true",
                   help="aoc/dhp: use weights whose own validation cost is above the "
                        "timetable's (refused by default, with the figures)")
    p.add_argument("--weights", default="", metavar="FILE",
                   help="aoc/dhp weights file (refused before any node starts if it was "
                        "trained on another line)")
    p.add_argument("--respawn-limit", type=int, default=3, metavar="N",
                   help="restart a node process that dies, at most N times each (default 3; "
                        "0: a dead node ends the run)")
    p.add_argument("--checkpoint-period", type=float, default=60.0, metavar="S",
                   help="simulated seconds between the simulator's resume checkpoints "
                        "(default 60; 0: none, a restarted simulator starts again at t=0)")
    p.add_argument("--step-timeout", type=float, default=0.0, metavar="S",
                   help="lockstep: wall time the simulator waits for a step's commands "
                        "before applying the last ones [s] (0: the node's default, 10 s); "
                        "a respawned node must be back within it")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its checkpoints (default: remove them)")
    p.add_argument("--replay-commands", default="", metavar="BAG",
                   help="apply the dispatcher commands a recorded run's bag holds at the steps "
                        "they were applied at (same scenario, seed and options: the same "
                        "events.csv); live /line/dispatch requests are refused")
    p.add_argument("--wait-for-subscribers", default="", metavar="NODE[,NODE]",
                   help="node names that must subscribe to the simulator's topics before "
                        "step 0 (e.g. an outside recorder)")
    deploy.add_options(p)
    return p


@dataclass
class ProcessSpec:
    """One OS process of the graph: executable, parameter file and parameters (ROS-free)."""

    label: str
    executable: str
    params_file: str | None
    params: dict[str, Any] = field(default_factory=dict)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The parsed ``run`` options (as :func:`main` reads them)."""
    return _parser().parse_args(argv)


def graph_processes(scenario: str, train_ids: Sequence[str], regulator: str = "none",
                    seed: int = 0, lockstep: bool = True, rtf: float = 10.0,
                    duration_s: float = 0.0, out_dir: str = "", plots: bool = True,
                    ato_per_process: int = 30, record_dir: str | None = None,
                    wait_for: Sequence[str] = (), cfg: Path | None = None,
                    weights_file: str = "", checkpoint_dir: str = "",
                    checkpoint_period_s: float = 60.0,
                    step_timeout_s: float = 0.0,
                    plan_store_dir: str = "", finished_file: str = "",
                    foxglove: tuple[str, int] | None = None,
                    replay_commands: str = "", day: bool = False) -> list[ProcessSpec]:
    """The processes of a run, as ``run`` starts them and the launch file declares them.

    ``weights_file``: the aoc/dhp weights the ATS loads ('' : it looks them up itself).
    ``checkpoint_dir`` ('' : none): where the simulator checkpoints every
    ``checkpoint_period_s`` simulated seconds and the ATOs keep their state journals.
    ``plan_store_dir``: a directory the ATO processes share their finished plans in
    (:mod:`metro_atc.core.ato.plan_store`; '' : none). ``finished_file``: the file the
    simulator creates when its run is over ('' : none; ``run`` then stops the other nodes
    while the simulator writes its outputs; the launch file stops them at its exit).
    ``foxglove`` (host, port): the live view's bridge (None: none).
    ``replay_commands``: a recorded run's bag whose dispatcher commands the simulator
    applies at their steps ('' : none; live dispatcher requests are served).
    ``day``: ``scenario`` is a service day: no ATS process (the simulator's day plant
    decides the departures; :mod:`metro_atc.nodes.sim_day`) and no checkpoints.
    """
    if day:
        checkpoint_dir = ""
    cfg = cfg or config_dir()
    base: dict[str, Any] = {"use_sim_time": True, "scenario": scenario}
    waits = list(wait_for) + ([RECORDER_NODE] if record_dir is not None else [])
    sim = dict(base, seed=int(seed), lockstep=bool(lockstep), real_time_factor=float(rtf),
               out_dir=str(out_dir), plots=bool(plots), exit_on_finish=True,
               max_sim_time_s=float(duration_s))
    if day:
        sim["day_regulator"] = str(regulator)
    if waits:
        sim["wait_for_subscribers"] = waits
    if finished_file:
        sim["finished_file"] = str(finished_file)
    if replay_commands:
        sim["replay_commands"] = str(replay_commands)
    resume: dict[str, Any] = {"checkpoint_dir": str(checkpoint_dir)} if checkpoint_dir else {}
    if checkpoint_dir:
        sim.update(resume, checkpoint_period_s=float(checkpoint_period_s))
    if step_timeout_s > 0:
        sim["step_timeout_s"] = float(step_timeout_s)
    if record_dir is not None:
        sim["train_state_period_s"] = 0.0  # a recording has every train's state every step
    procs = [ProcessSpec("line_simulator", "line_simulator", str(cfg / "line_simulator.yaml"),
                         sim)]
    if not day:
        procs.append(ProcessSpec("ats_regulator", "ats_regulator",
                                 str(cfg / "ats_regulator.yaml"),
                                 dict(base, regulator=regulator,
                                      **({"weights_file": weights_file} if weights_file
                                         else {}))))
    # the brake diagnosis takes its time from the sample stamps: no /clock reader (one
    # delivery per step less for the simulator, none to take here)
    procs.append(ProcessSpec("brake_diagnostic", "brake_diagnostic",
                             str(cfg / "brake_diagnostic.yaml"),
                             dict(base, use_sim_time=False, **resume)))
    for group in ato_groups(train_ids, ato_per_process):
        # the ATOs take their time from the lockstep states, not from /clock: without
        # use_sim_time their 2 x 15 nodes add no /clock readers (each reader costs the
        # simulator a delivery per step)
        ato = dict(base, use_sim_time=False, train_ids=group)
        if plan_store_dir:
            ato["plan_store_dir"] = str(plan_store_dir)
        procs.append(ProcessSpec(f"ato_{group[0]}", "ato_controller",
                                 str(cfg / "ato_controller.yaml"), dict(ato, **resume)))
    if record_dir is not None:
        procs.append(ProcessSpec("bag_recorder", "bag_recorder", None,
                                 dict(base, output=str(record_dir))))
    if foxglove is not None:
        procs.append(ProcessSpec(BRIDGE_NODE, BRIDGE_NODE, None,
                                 dict(base, use_sim_time=False, host=str(foxglove[0]),
                                      port=int(foxglove[1]))))
    return procs


def ato_groups(train_ids: Sequence[str], per_process: int) -> list[list[str]]:
    """The trains of each ATO process: at most ``per_process`` each, dealt round-robin.

    ``ceil(n / per_process)`` processes; process k hosts trains k, k + P, k + 2P, ... of
    the timetable (P processes).  The trains of a line enter service in timetable order, so
    contiguous groups would load the first process alone for the first part of a run (on the
    lockstep's critical path) while the last idles; dealt round-robin, every process hosts
    early and late trains.  A process is labelled by its first train (``ato_<train>``).
    """
    ids = list(train_ids)
    n = max(1, int(per_process))
    procs = max(1, -(-len(ids) // n)) if ids else 0
    return [ids[k::procs] for k in range(procs)]


def record_dir(a: argparse.Namespace, out_dir: Path) -> str | None:
    """The bag directory of ``--record`` (None: not recording)."""
    if a.record is None:
        return None
    return str(Path(a.record) if a.record else out_dir / "bag")


def processes_for(a: argparse.Namespace, train_ids: Sequence[str],
                  out_dir: Path, plan_store_dir: str = "",
                  finished_file: str = "") -> list[ProcessSpec]:
    """:func:`graph_processes` for the parsed ``run`` options."""
    return graph_processes(
        a.scenario, train_ids, regulator=a.regulator, seed=a.seed, lockstep=not a.free_run,
        rtf=a.rtf, duration_s=a.duration, out_dir=str(out_dir), plots=a.plots,
        ato_per_process=a.ato_per_process, record_dir=record_dir(a, out_dir),
        wait_for=[x for x in a.wait_for_subscribers.split(",") if x],
        weights_file=getattr(a, "weights_file", ""),
        checkpoint_dir=str(checkpoint_dir(out_dir)), checkpoint_period_s=a.checkpoint_period,
        step_timeout_s=a.step_timeout, plan_store_dir=plan_store_dir,
        finished_file=finished_file,
        foxglove=None if a.foxglove is None else (a.foxglove_host, a.foxglove),
        replay_commands=a.replay_commands, day=getattr(a, "day", None) is not None)


def replay_problem(bag: str) -> str | None:
    """Why ``--replay-commands BAG`` cannot run (one line), or None."""
    from metro_atc.nodes.dispatch_msgs import APPLIED_TOPIC, recorded_commands
    try:
        got = recorded_commands(bag)
    except ValueError as exc:
        return f"--replay-commands {exc}"
    except ImportError as exc:
        return f"--replay-commands needs the built interfaces (make setup): {exc}"
    print(f"metro_atc run: replaying {len(got)} dispatcher commands of {bag} "
          f"({APPLIED_TOPIC})", file=sys.stderr, flush=True)
    return None


def checkpoint_dir(out_dir: Path) -> Path:
    """Where a run's checkpoints and journals live: ``OUT/checkpoints``."""
    return out_dir / "checkpoints"


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


def build_commands(a: argparse.Namespace, train_ids: Sequence[str],
                   out_dir: Path, plan_store_dir: str = "",
                   finished_file: str = "") -> list[tuple[str, list[str]]]:
    """The process list of a run: (label, argv); this host's share of it (``--only``).

    A host without the simulator runs :data:`deploy.WATCH_LABEL` first, in its place.
    """
    specs = deploy.share(a, processes_for(a, train_ids, out_dir, plan_store_dir,
                                          finished_file), train_ids, ato_groups)
    watch = deploy.watch_command(a)
    return ([(deploy.WATCH_LABEL, watch)] if watch else []) + \
        [(p.label, executable(p.executable)
          + _ros_args(p.params, Path(p.params_file) if p.params_file else None))
         for p in specs]


def node_env() -> dict[str, str]:
    """The environment of the node processes (and of the zygote that forks them)."""
    # PARENT_PID_ENV: the nodes stop themselves if this launcher dies (even by SIGKILL)
    return dict(os.environ, RCUTILS_LOGGING_BUFFERED_STREAM="0", PYTHONUNBUFFERED="1",
                **{PARENT_PID_ENV: str(os.getpid())})


def forkable(argv: Sequence[str]) -> bool:
    """True if ``argv`` runs an installed node executable (the zygote can fork it)."""
    if not argv:
        return False
    name = os.path.basename(argv[0])
    return name in NODE_EXECUTABLES and executable(name) == [argv[0]]


def start_zygote(executables: Sequence[str]) -> Zygote | None:
    """Start the fork server preloading ``executables`` (None when ``METRO_ATC_ZYGOTE=0``)."""
    if os.environ.get(ZYGOTE_ENV, "1") == "0":
        return None
    return Zygote(list(executables), node_env())


def _signal_all(procs: Sequence[tuple[str, Proc]]) -> None:
    """Send SIGTERM to the process group of every process still running."""
    for _, p in procs:
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass


def _stop(procs: list[tuple[str, Proc]], grace_s: float = 15.0) -> None:
    _signal_all(procs)
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


def check_listen(host: str, port: int) -> str | None:
    """Check that a server can listen on ``host``:``port`` now; one error line or None.

    Called before any node starts: the live view's bridge would otherwise fail once the
    graph runs (port 0: any free port, always possible).
    """
    import socket
    if not 0 <= port <= 65535:
        return f"--foxglove {port}: not a TCP port (0..65535)"
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        with socket.socket(infos[0][0], socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(infos[0][4])
    except OSError as exc:
        return f"--foxglove {port} on {host}: cannot listen there: " \
            f"{getattr(exc, 'strerror', None) or exc}"
    return None


def check_out_dir(path: Path) -> str | None:
    """Create ``path`` if needed and check it is a writable directory; one error line or None.

    Called before any node starts (an unwritable directory would otherwise lose the KPIs
    at the end of the run).
    """
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f"--out {path}: cannot create it: {exc.strerror}"
    if not path.is_dir():
        return f"--out {path}: not a directory"
    try:
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write_test_"):
            pass
    except OSError as exc:
        return f"--out {path}: not writable: {exc.strerror}"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Run one scenario through the graph; print KPIs (``--json``: one JSON object)."""
    a = parse_args(argv)
    problem, profile = deploy.configure(a)  # --dds-hosts: before the DDS defaults
    if problem:
        print(f"metro_atc run: error: {problem}", file=sys.stderr)
        return Exit.REFUSED
    dds_defaults()
    zygote = None
    if not a.single_process:
        # the fork server preloads while this process loads the scenario and checks options
        names = [x for x in NODE_EXECUTABLES if (x != RECORDER_NODE or a.record is not None)
                 and (x != BRIDGE_NODE or a.foxglove is not None)]
        if all(forkable(executable(x)) for x in names):
            zygote = start_zygote(names)
    try:
        return _main(a, zygote)
    finally:
        if zygote is not None:
            zygote.close()
        if profile is not None:
            profile.unlink(missing_ok=True)


def _main(a: argparse.Namespace, zygote: Zygote | None) -> int:
    from metro_atc.core.line.scenario import ScenarioError
    from metro_atc.core.service.dayrun import day_table, load_day_run, load_run_scenario
    try:
        day = load_day_run(a.scenario) if day_table(a.scenario) is not None else None
        scn = load_run_scenario(a.scenario)
        train_ids = list(scenario_train_ids(scn))
    except (ScenarioError, ValueError) as exc:
        print(f"metro_atc run: error: {exc}", file=sys.stderr)
        return Exit.REFUSED
    a.day = day
    out_dir = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="metro_atc_run_"))
    problem = check_out_dir(out_dir)
    if problem is None and a.log_dir:
        problem = check_out_dir(Path(a.log_dir))
    if problem is None and a.record is not None:
        bag = Path(record_dir(a, out_dir) or "")
        if bag.exists():
            problem = f"--record {bag}: already exists (rosbag2 does not overwrite a bag)"
        else:
            problem = check_out_dir(bag.parent)
    if problem is None:
        problem = deploy.check(a, train_ids)
    if problem is None and a.single_process and (a.record is not None
                                                 or a.wait_for_subscribers
                                                 or a.replay_commands):
        problem = "--record, --wait-for-subscribers and --replay-commands need the " \
            "multi-process graph"
    if problem is None and a.foxglove is not None:
        problem = check_listen(a.foxglove_host, a.foxglove) if not a.single_process else \
            "--foxglove needs the multi-process graph"
    if problem is None and day is not None:
        problem = day_problem(a)
    if problem is None and a.replay_commands:
        problem = replay_problem(a.replay_commands)
    if problem is None and (a.respawn_limit < 0 or not a.checkpoint_period >= 0
                            or not 0 <= a.step_timeout <= 600):
        problem = "--respawn-limit, --checkpoint-period and --step-timeout (<= 600) must " \
            "be >= 0"
    t_train = time.monotonic()
    if problem is None:
        problem = prepare_regulator(a, scn) if day is None else day_regulator_problem(a, day)
    training_s = time.monotonic() - t_train if getattr(a, "weights_source", "") == "trained" \
        else 0.0
    # last: a refused run leaves no checkpoints folder behind
    if problem is None and not a.single_process and day is None:
        problem = prepare_checkpoints(checkpoint_dir(out_dir), a.resume)
    if problem:
        print(f"metro_atc run: error: {problem}", file=sys.stderr)
        return Exit.REFUSED
    from metro_atc.show import stock_line
    print(f"metro_atc run: {stock_line(scn)}", file=sys.stderr, flush=True)
    if day is not None:
        from metro_atc.core.service.dayrun import describe
        from metro_atc.nodes.sim_day import NOT_IN_GRAPH
        print(f"metro_atc run: {describe(day)}; {len(train_ids)} trains; not through the "
              f"graph: {'; '.join(NOT_IN_GRAPH)}", file=sys.stderr, flush=True)
    if a.foxglove is not None:
        from metro_atc.nodes.wire.line_view import live_view_line
        print(f"metro_atc run: {live_view_line(a.foxglove_host, a.foxglove)}",
              file=sys.stderr, flush=True)
    t0 = time.monotonic()
    memory: dict[str, float | None] = {}
    cpu: dict[str, float | None] = {}
    timing: dict[str, float] = {}
    if a.single_process:
        from metro_atc.nodes.graph import run_single_process
        code = run_single_process(a, train_ids, out_dir)
        memory["graph"] = own_peak_rss_mb()
        cpu["graph"] = round(time.process_time(), 2)
    else:
        show = a.progress == "always" or (a.progress == "auto" and sys.stderr.isatty())
        horizon_s = None if not show else progress_horizon_s(scn, a.duration) \
            if day is None else day_horizon_s(day, a.duration)
        code = _run_processes(a, train_ids, out_dir, horizon_s, memory, cpu, zygote, timing)
    # the regulator's training (if any) is part of the run's wall time
    wall = time.monotonic() - t0 + training_s
    kpi_file = out_dir / "kpis.json"
    if not a.single_process and deploy.watch_command(a) is not None:
        return deploy.share_end(a, code, Path(a.log_dir) if a.log_dir else out_dir / "logs")
    if code != 0:
        return code
    try:
        kpis = json.loads(kpi_file.read_text())
        if not isinstance(kpis, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as exc:
        print(f"metro_atc run: error: OUTPUTS_NOT_WRITTEN (exit {int(Exit.OUTPUTS_NOT_WRITTEN)}"
              f"): no readable {kpi_file} ({getattr(exc, 'strerror', None) or exc}); see the "
              f"logs in {out_dir / 'logs'}", file=sys.stderr)
        return Exit.OUTPUTS_NOT_WRITTEN
    # the printed report adds the launcher's view; kpis.json stays as the simulator wrote it
    kpis["wall_time_s"] = round(wall, 3)
    kpis["regulator_training_s"] = round(training_s, 3)
    # simulated time run (a service day starts at its first pull-out, not at 0)
    sim_t = float(kpis.get("sim_time_s", 0.0)) - float(kpis.get("sim_start_s", 0.0))
    kpis["real_time_factor"] = round(sim_t / wall, 2) if wall > 0 else math.nan
    if timing:
        # the stepping loop alone (start-up and end left out), as a co-simulation times its
        # own loop (bench sumo)
        kpis["loop_wall_s"] = round(timing["loop_wall_s"], 3)
        kpis["loop_real_time_factor"] = round(timing["loop_sim_s"] / timing["loop_wall_s"], 2)
    kpis.setdefault("regulator", regulator_label(kpis.get("regulators_seen") or {}))
    kpis.setdefault("planner", ",".join(kpis.get("planners_seen") or []) or "none")
    if a.weights_file:
        kpis["weights"] = a.weights_file
    kpis["mode"] = "single_process" if a.single_process else "multi_process"
    kpis["out_dir"] = str(out_dir)
    kpis["node_peak_rss_mb"] = memory
    kpis["node_cpu_s"] = cpu
    if a.record is not None:
        kpis["bag"] = record_dir(a, out_dir)
    if a.json:
        print(json.dumps(kpis, sort_keys=True))
    else:
        _print_table(kpis)
    end, why = outcome(kpis)
    if end != Exit.OK:
        print(f"metro_atc run: {end.name} (exit {int(end)}): {why}", file=sys.stderr)
    return int(end)


def prepare_regulator(a: argparse.Namespace, scn: Any) -> str | None:
    """Resolve the aoc/dhp weights before any node starts; one error line or None.

    Sets ``a.weights_file`` to weights trained on the scenario's line (same traffic-model
    hash, :mod:`metro_atc.core.atr.weights_store`): ``--weights`` if given and valid, else
    the shipped or cached ones, else (``--train-regulator auto``) weights trained now into
    the cache with progress on stderr; ``a.weights_source`` says which (``given``,
    ``shipped``, ``cached``, ``trained``; '' without weights).  One line on stderr names
    the file used.  Weights whose own validation cost is above the timetable's
    (:func:`~metro_atc.core.atr.weights_store.validation_problem`) are refused with the
    figures unless ``--accept-worse-regulator`` (then, and for the shipped weights, the
    figures are printed as a warning).  The regulator is built once here as the ATS
    builds it, so a regulator that cannot start stops the run before the graph exists.
    """
    a.weights_file = ""
    a.weights_source = ""
    entry = REGULATORS.get(a.regulator)
    if entry is None or not entry.has("prebuilt"):
        return None
    from metro_atc.core.atr.lines import atr_line_for
    from metro_atc.core.atr.regulators import make_regulator
    from metro_atc.core.atr.weights_store import resolve_weights, validation_problem

    def say(m: str) -> None:
        print(f"metro_atc run: {m}", file=sys.stderr, flush=True)

    try:
        line = atr_line_for(scn)
        if entry.has("trained"):
            if a.weights:
                path, source = Path(a.weights).resolve(), "given"
            else:
                got = resolve_weights(a.regulator, line, a.train_regulator == "auto",
                                      progress=say)
                path, source = got.path, got.source
            a.weights_source = source
            make_regulator(a.regulator, line, None, path)
            say(f"{a.regulator} weights: {path} ({source})")
            worse = validation_problem(path)
            if worse is not None:
                if source != "shipped" and not getattr(a, "accept_worse_regulator", False):
                    return f"regulator '{a.regulator}': {worse}; refused (use " \
                        "--accept-worse-regulator to run it all the same)"
                say(f"warning: regulator '{a.regulator}': {worse}")
            a.weights_file = str(path)
        else:
            make_regulator(a.regulator, line)
    except (ValueError, FileNotFoundError, OSError) as exc:
        return f"regulator '{a.regulator}': {exc}"
    return None


def prepare_checkpoints(folder: Path, resume: bool) -> str | None:
    """Empty the checkpoint directory (a new run) or keep it (``--resume``); error or None."""
    import shutil
    try:
        if folder.exists() and not resume:
            shutil.rmtree(folder)
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f"checkpoints {folder}: {exc.strerror}"
    return None


def progress_horizon_s(scn: Any, duration_s: float) -> float:
    """Simulated time the progress ETA counts to [s].

    The run stops at ``duration_s`` (> 0) or the scenario's ``sim.duration_s``, or earlier
    when every train is out of service. The estimate of that end is a pure function of the
    scenario: the last scheduled arrival, its dwell, the run into the tail track (a
    triangular profile at the driving deceleration) and the turnback time; the earlier of the
    two counts.
    """
    limit = float(duration_s) if duration_s > 0 else float(scn.sim.duration_s)
    from metro_atc.core.line.service import describe
    d = describe(scn)
    sv = d.service
    arr = np.asarray(sv.sched_arr, dtype=float)[:, -1]
    if not np.isfinite(arr).any():
        return limit
    i = int(np.nanargmax(arr))
    tail_m = max(float(d.geometry.x_tail_stop - d.geometry.station_positions_m[-1]), 0.0)
    tail_s = 2.0 * math.sqrt(tail_m / max(float(sv.b_drive), 1e-3))
    dwell = float(np.nanmax(np.asarray(sv.sched_dwell, dtype=float)[..., -1], initial=0.0))
    end = float(arr[i]) + dwell + tail_s + float(scn.line.turnback_s)
    return min(limit, end)


def day_horizon_s(day: Any, duration_s: float) -> float:
    """Simulated time the progress ETA of a service day counts to [s]: its last arrival."""
    from metro_atc.core.service.dayrun import last_arrival_s
    end = last_arrival_s(day)
    return min(float(duration_s), end) if duration_s > 0 else end


def day_problem(a: argparse.Namespace) -> str | None:
    """Why a service day cannot run with these options (one line), or None.

    The day's departures are decided by the simulator's day plant (its ATS with the
    ``--regulator``), it takes no dispatcher commands and is not checkpointed.
    """
    if a.single_process:
        return "--single-process: a service day runs in the multi-process graph"
    if a.resume or a.replay_commands:
        return "--resume and --replay-commands: a service day is not checkpointed"
    if getattr(a, "weights", None):
        return ("--weights: a service day's aoc / dhp use the shipped weights of each "
                "direction")
    return None


def day_regulator_problem(a: argparse.Namespace, day: Any) -> str | None:
    """Why the day's ATS cannot regulate with ``--regulator`` (one line), or None.

    The day plant's ATS is built once here as the simulator builds it (aoc / dhp: the
    shipped weights of each direction), so a regulator that cannot start stops the run
    before the graph exists.
    """
    a.weights_file = ""
    a.weights_source = ""
    if a.regulator == "none":
        return None
    from metro_atc.core.service.dayrun import day_plant
    try:
        day_plant(day, regulator=a.regulator)
    except ValueError as exc:
        return f"--regulator {a.regulator}: {exc}"
    return None


def scenario_train_ids(scn: Any) -> list[str]:
    """Train ids of a loaded scenario (``train_01`` ...)."""
    return list(scn.train_ids)


def _last_error_line(log: Path) -> str:
    """The reason a node gave: its last ``error:`` line (or last line) in its log."""
    try:
        lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines()
                 if ln.strip()]
    except OSError:
        return "no log"
    for ln in reversed(lines):
        if "error" in ln.lower():
            return ln[:300]
    return lines[-1][:300] if lines else "no output"


PROGRESS_RE = re.compile(r"t=([0-9.]+) s: ([0-9]+) trains in service, ([0-9]+) lockstep "
                         r"misses, ([0-9.]+)x real time")
"""The simulator's progress log line (``line_simulator`` parameter ``progress_period_s``)."""
MILESTONE_RE = re.compile(r"(graph ready after [0-9.]+ s|scenario finished at t=[0-9.]+ s "
                          r"after [0-9]+ steps, [0-9.]+ s wall)")
"""The simulator's start (every node connected) and end log lines, echoed as they come: a
run shows a line within seconds of its start and one before its outputs are written."""


class ProgressTail:
    """Echo the simulator's progress lines from its log file, with horizon and ETA.

    Also its "graph ready" and "scenario finished" lines (:data:`MILESTONE_RE`).

    ETA = simulated seconds left / the real-time factor of the line [s of wall time].
    """

    def __init__(self, log: Path, horizon_s: float, stream: Any = None) -> None:
        """Follow ``log`` (it may not exist yet); ``horizon_s`` simulated end [s]."""
        self.log, self.horizon_s = log, float(horizon_s)
        self.stream = sys.stderr if stream is None else stream
        self.offset = 0
        self.partial = ""

    def poll(self) -> int:
        """Print the progress lines written since the last call; return how many."""
        try:
            with self.log.open("rb") as fh:
                fh.seek(self.offset)
                chunk = fh.read()
        except OSError:
            return 0
        self.offset += len(chunk)
        lines = (self.partial + chunk.decode("utf-8", errors="replace")).split("\n")
        self.partial = lines.pop()
        n = 0
        for ln in lines:
            m = PROGRESS_RE.search(ln)
            if m is None:
                done = MILESTONE_RE.search(ln)
                if done is not None:
                    then = "stepping" if done[1].startswith("graph") else \
                        "writing the outputs"
                    print(f"metro_atc run: {done[1]}; {then}", file=self.stream, flush=True)
                    n += 1
                continue
            t, trains, misses, rtf = float(m[1]), int(m[2]), int(m[3]), float(m[4])
            left = max(self.horizon_s - t, 0.0) / rtf if rtf > 0 else math.inf
            eta = f"{left // 60:.0f} min {left % 60:02.0f} s" if math.isfinite(left) else "?"
            if t > self.horizon_s:  # running late: the last trains are still arriving
                eta = "last trains arriving"
            end = max(self.horizon_s, t)
            print(f"metro_atc run: t = {t:.0f} / {end:.0f} s simulated, {trains} "
                  f"trains in service, {misses} lockstep misses, {rtf:.1f}x real time, "
                  f"ETA {eta}", file=self.stream, flush=True)
            n += 1
        return n


def peak_rss_mb(pid: int) -> float | None:
    """Peak resident memory of a live process so far (``VmHWM``) [MiB]; None if unknown."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii", errors="replace") as fh:
            for ln in fh:
                if ln.startswith("VmHWM:"):
                    return round(int(ln.split()[1]) / 1024.0, 1)
    except (OSError, ValueError, IndexError):
        pass
    return None


def cpu_seconds(pid: int) -> float | None:
    """CPU time (user + system) a live process has used so far [s]; None if unknown."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        return round((int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK"), 2)
    except (OSError, ValueError, IndexError):
        return None


def own_peak_rss_mb() -> float | None:
    """Peak resident memory of this process [MiB] (``ru_maxrss``, KiB on Linux)."""
    try:
        import resource
        return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
    except (ImportError, OSError):
        return None


def _run_processes(a: argparse.Namespace, train_ids: Sequence[str], out_dir: Path,
                   progress_horizon_s: float | None = None,
                   memory: dict[str, float | None] | None = None,
                   cpu: dict[str, float | None] | None = None,
                   zygote: Zygote | None = None,
                   timing: dict[str, float] | None = None) -> int:
    """Start the graph's processes, watch them, stop them; return an exit code.

    ``memory`` / ``cpu`` (filled if given): each process's peak resident memory [MiB] and
    CPU time [s], sampled once per second while it runs (the last sample before it exits).
    The installed node executables are forked by ``zygote`` (started here if None and
    :data:`ZYGOTE_ENV` is not ``0``; closed here), anything else (or everything, if the
    zygote cannot serve) is exec'd; a forked node's CPU time does not include its imports,
    which the zygote did once: its own CPU time and memory are reported as ``zygote``.
    ``timing`` (filled if given): the simulator's stepping loop, :func:`read_finished`.
    """
    log_dir = Path(a.log_dir) if a.log_dir else out_dir / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    procs: list[tuple[str, Proc]] = []
    code = 0
    tail = None if progress_horizon_s is None else \
        ProgressTail(log_dir / "line_simulator.log", progress_horizon_s)

    def on_term(*_: Any) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    env = node_env()
    # the ATO processes plan each run and target once between them (deleted at the end)
    plans = tempfile.mkdtemp(prefix="metro_atc_plans_")
    # the simulator creates it when its run is over: the other nodes are stopped then,
    # while it writes its outputs (their shutdown no longer follows its own)
    finished = Path(plans) / "line_simulator.finished"
    commands = dict(build_commands(a, train_ids, out_dir, plans, str(finished)))
    respawns = {label: 0 for label in commands}
    killed = False  # a process died by SIGKILL (its DDS shared memory stays behind)
    forks = {label for label, argv in commands.items() if forkable(argv)}
    if zygote is None and forks:
        zygote = start_zygote(sorted({os.path.basename(commands[x][0]) for x in forks}))

    def start(label: str, mode: str = "wb") -> Proc:
        if zygote is not None and label in forks:
            forked = zygote.spawn(commands[label], str(log_dir / f"{label}.log"), mode)
            if forked is not None:
                return forked
        with open(log_dir / f"{label}.log", mode) as log:
            return subprocess.Popen(commands[label], stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True, env=env)

    try:
        for label in commands:
            procs.append((label, start(label)))
        write_pids(log_dir, procs)
        if tail is not None:
            print(f"metro_atc run: {len(procs)} processes started (logs: {log_dir})",
                  file=sys.stderr, flush=True)
        deadline = time.monotonic() + a.timeout
        next_poll = 0.0
        stopping = False  # the simulator finished: the others were sent SIGTERM
        while code == 0:
            sim = procs[0][1]
            if not stopping and finished.exists():
                stopping = True
                if timing is not None:
                    timing.update(read_finished(finished))
                early = [(label, p) for label, p in procs[1:] if label != RECORDER_NODE]
                _signal_all(early)  # the recorder stops after the simulator, as before
            # any exit is a failure but the simulator's normal end (and, once it finished,
            # the others' ends: judged by their exit codes after the loop)
            ended = [(n, label, p.poll()) for n, (label, p) in enumerate(procs)
                     if n == 0 or not stopping]
            failed = [(n, label, rc) for n, label, rc in ended
                      if rc is not None and (n > 0 or rc not in NORMAL_END)]
            if failed:
                n, label, rc = failed[0]
                why = f"killed by {signal.Signals(-rc).name}" if rc < 0 and \
                    -rc in signal.valid_signals() else _last_error_line(log_dir / f"{label}.log")
                killed = killed or rc == -signal.SIGKILL
                if respawns[label] < a.respawn_limit and rc not in NO_RESPAWN and \
                        label != deploy.WATCH_LABEL:
                    respawns[label] += 1
                    print(f"metro_atc run: {label} exited with {rc} ({why}); restarting it "
                          f"({respawns[label]} of {a.respawn_limit})", file=sys.stderr,
                          flush=True)
                    procs[n] = (label, start(label, "ab"))
                    write_pids(log_dir, procs)
                    continue
                limit = " (not restarted: a restart cannot mend it)" if rc in NO_RESPAWN \
                    or label == deploy.WATCH_LABEL else " (respawn limit reached)" \
                    if a.respawn_limit else ""
                print(f"metro_atc run: error: {label} exited with {rc}{limit}: {why} "
                      f"(log: {log_dir / (label + '.log')})", file=sys.stderr)
                # the simulator's own verdicts stand (outputs not written, no ATO answered)
                code = rc if n == 0 and rc in (Exit.OUTPUTS_NOT_WRITTEN,
                                               Exit.GRAPH_NOT_READY) else Exit.NODE_FAILED
            elif sim.poll() in NORMAL_END:
                if tail is not None:
                    tail.poll()  # the lines since the last poll (a short run: all of them)
                break
            elif time.monotonic() > deadline:
                print(f"metro_atc run: error: wall-clock timeout after {a.timeout:g} s "
                      f"(logs: {log_dir})", file=sys.stderr)
                code = Exit.TIMEOUT
            else:
                if time.monotonic() >= next_poll:
                    if tail is not None:
                        tail.poll()
                    if memory is not None:
                        for label, p in procs:
                            rss = peak_rss_mb(p.pid)
                            if rss is not None:
                                memory[label] = rss
                            if cpu is not None:
                                c = cpu_seconds(p.pid)
                                if c is not None:
                                    cpu[label] = c
                    next_poll = time.monotonic() + 1.0
                time.sleep(POLL_S)
    except KeyboardInterrupt:
        code = Exit.INTERRUPTED
    finally:
        if zygote is not None:
            if zygote.info and zygote.proc is not None:
                if memory is not None:
                    memory["zygote"] = peak_rss_mb(zygote.proc.pid)
                if cpu is not None:
                    cpu["zygote"] = cpu_seconds(zygote.proc.pid)
            zygote.release()  # no respawn from here on: it ends while the nodes stop
        _stop(procs)
        signal.signal(signal.SIGTERM, old)
        shutil.rmtree(plans, ignore_errors=True)
        if zygote is not None:
            zygote.close()
        if killed or any(p.returncode == -signal.SIGKILL for _, p in procs):
            cleaned = clean_killed_shm()
            if cleaned:
                print(f"metro_atc run: removed {cleaned} Fast DDS shared-memory segments of "
                      "killed processes (fastdds shm clean)", file=sys.stderr)
    if code == 0:
        # the rest of the graph was stopped by SIGTERM: a node that then fails (or a recorder
        # that could not close its bag) still fails the run
        bad = [(label, p.returncode) for label, p in procs[1:]
               if p.returncode not in (0, -signal.SIGTERM, -signal.SIGKILL)]
        if bad:
            label, end_rc = bad[0]
            print(f"metro_atc run: error: {label} exited with {end_rc} at shutdown: "
                  f"{_last_error_line(log_dir / f'{label}.log')}", file=sys.stderr)
            code = Exit.OUTPUTS_NOT_WRITTEN if end_rc == Exit.OUTPUTS_NOT_WRITTEN \
                else Exit.NODE_FAILED
    return code


def read_finished(path: Path) -> dict[str, float]:
    """The simulator's ``finished_file``: its loop's ``loop_wall_s`` and ``loop_sim_s`` [s].

    Empty when the file is not the simulator's JSON (then no loop figures are reported).
    """
    try:
        d = json.loads(path.read_text())
        wall, sim_s = float(d["loop_wall_s"]), float(d["loop_sim_s"])
    except (OSError, ValueError, TypeError, KeyError):
        return {}
    if not (math.isfinite(wall) and wall > 0.0 and math.isfinite(sim_s) and sim_s >= 0.0):
        return {}
    return {"loop_wall_s": wall, "loop_sim_s": sim_s}


def write_pids(log_dir: Path, procs: Sequence[tuple[str, Proc]]) -> None:
    """``LOG_DIR/pids.json``: label -> process id of the running graph (atomically)."""
    tmp = log_dir / ".pids.json.tmp"
    tmp.write_text(json.dumps({label: p.pid for label, p in procs}, indent=1))
    os.replace(tmp, log_dir / "pids.json")


DAY_HIDDEN = ("trains", "completed_trains", "max_delay_s", "recovery_time_s",
              "late_departures", "incomplete_trains", "regulator")
"""One-way figures the printed table of a service day leaves out (kpis.json has them)."""
DAY_SHOWN = ("trips_planned", "trips_run", "fleet", "trains_in_depot", "route_conflicts",
             "missed_stops", "separation_violations", "stop_error_max_m",
             "stops_outside_0p30_m", "terminal_delay_max_s", "depot_moves")
"""The service day's figures in the printed table (``day`` in kpis.json)."""


def _print_table(k: dict[str, Any]) -> None:
    keys: tuple[str, ...] = (
        "trains", "completed_trains", "atp_violations", "atp_interventions",
        "min_separation_m", "energy_kwh", "max_delay_s", "recovery_time_s",
        "late_departures", "passengers_left_behind", "sim_time_s", "wall_time_s",
        "real_time_factor", "loop_wall_s", "loop_real_time_factor", "lockstep_misses",
        "regulator", "planner", "weights", "regulator_training_s", "finished",
        "cut_at_s", "incomplete_trains", "out_dir", "bag")
    day = k.get("day")
    if isinstance(day, dict):  # a service day: its trips, not the one-way trains' figures
        keys = tuple(x for x in keys if x not in DAY_HIDDEN) + tuple(
            f"day.{x}" for x in DAY_SHOWN)
        k = dict(k, **{f"day.{x}": day.get(x) for x in DAY_SHOWN})
    width = max(len(x) for x in keys)
    for key in keys:
        if key in k:
            print(f"{key:<{width}}  {k[key]}")
