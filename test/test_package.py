"""Packaging and launch: package.xml matches the imports, setup.py's patterns match files,
and the launch file starts what ``python -m metro_atc run`` starts (no launch_ros needed)."""

from __future__ import annotations

import ast
import importlib.util
import sys
import types
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent

PYTHON_KEYS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml",
               "matplotlib": "python3-matplotlib", "torch": "python3-torch",
               "mcap": "python3-mcap", "numba": "python3-numba",
               "rosbags": "python3-rosbags-pip", "llvmlite": "python3-llvmlite",
               "foxglove": "python3-foxglove-sdk-pip"}
"""Imported Python distributions -> their rosdep keys."""

LAUNCH_ONLY = {"launch", "launch_ros"}
"""Imported by the launch file only (exec_depend)."""


def _imports(paths: list[Path]) -> set[str]:
    mods: set[str] = set()
    for p in paths:
        for n in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(n, ast.Import):
                mods.update(a.name.split(".")[0] for a in n.names)
            elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
                mods.add(n.module.split(".")[0])
    return {m for m in mods if m not in sys.stdlib_module_names and m != "metro_atc"}


def _deps() -> dict[str, set[str]]:
    root = ET.parse(ROOT / "package.xml").getroot()
    out: dict[str, set[str]] = {}
    for tag in ("depend", "exec_depend", "build_depend", "test_depend"):
        out[tag] = {e.text.strip() for e in root.findall(tag) if e.text}
    return out


def test_package_xml_matches_imports() -> None:
    """Every imported ROS package is a <depend>, every <depend> is imported; Python keys too."""
    imported = _imports(list((ROOT / "metro_atc").rglob("*.py"))
                        + list((ROOT / "launch").glob("*.py")))
    deps = _deps()
    ros = {m for m in imported if m not in PYTHON_KEYS and m not in LAUNCH_ONLY}
    assert ros == deps["depend"], (f"imported but not <depend>: {sorted(ros - deps['depend'])}; "
                                   f"<depend> not imported: {sorted(deps['depend'] - ros)}")
    unknown = imported - ros - LAUNCH_ONLY - set(PYTHON_KEYS)
    assert not unknown, unknown
    want_exec = {PYTHON_KEYS[m] for m in imported if m in PYTHON_KEYS} | \
        (imported & LAUNCH_ONLY)
    assert want_exec == deps["exec_depend"], (sorted(want_exec ^ deps["exec_depend"]))


def test_setup_py_patterns_match_files_and_executables() -> None:
    """package_data / data_files patterns all match files; console scripts = node executables."""
    from metro_atc.launcher import NODE_EXECUTABLES

    tree = ast.parse((ROOT / "setup.py").read_text(encoding="utf-8"))
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
                and getattr(n.func, "id", "") == "setup")
    kw = {k.arg: k.value for k in call.keywords}
    pkg_data = ast.literal_eval(kw["package_data"].values[0])  # type: ignore[attr-defined]
    for pattern in pkg_data:
        assert list((ROOT / "metro_atc").glob(pattern)), f"dead package_data pattern {pattern}"
    scripts = ast.unparse(kw["entry_points"])
    for exe in NODE_EXECUTABLES:
        assert f"{exe} = " in scripts, exe
    for pattern in ("config/*.yaml", "config/*.xml", "launch/*.launch.py"):
        assert list(ROOT.glob(pattern)), pattern


class _Action:
    """Records the keyword arguments of a launch action (stand-in for launch/launch_ros)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs


def _stub_launch(monkeypatch: pytest.MonkeyPatch, values: dict[str, str]) -> None:
    """Minimal ``launch``/``launch_ros`` modules (used when they are not installed)."""
    mods = {name: types.ModuleType(name) for name in
            ("launch", "launch.actions", "launch.event_handlers", "launch.substitutions",
             "launch_ros", "launch_ros.actions")}

    class LaunchConfiguration:
        def __init__(self, name: str) -> None:
            self.name = name

        def perform(self, context: Any) -> str:
            return context[self.name]

    class LaunchDescription(_Action):
        pass

    for name in ("DeclareLaunchArgument", "OpaqueFunction", "RegisterEventHandler",
                 "Shutdown"):
        setattr(mods["launch.actions"], name, type(name, (_Action,), {}))
    mods["launch"].LaunchDescription = LaunchDescription  # type: ignore[attr-defined]
    mods["launch.event_handlers"].OnProcessExit = type(  # type: ignore[attr-defined]
        "OnProcessExit", (_Action,), {})
    mods["launch.substitutions"].LaunchConfiguration = LaunchConfiguration  # type: ignore
    mods["launch_ros.actions"].Node = type("Node", (_Action,), {})  # type: ignore
    for name, m in mods.items():
        monkeypatch.setitem(sys.modules, name, m)


@pytest.mark.parametrize("record", ["", "/tmp/some_bag"])
def test_launch_file_starts_what_run_starts(monkeypatch: pytest.MonkeyPatch,
                                            record: str) -> None:
    """Same executables, parameter files and parameters; shutdown when the simulator exits."""
    from metro_atc import launcher
    from metro_atc.core.line.scenario import load_scenario

    _stub_launch(monkeypatch, {})
    spec = importlib.util.spec_from_file_location("metro_line_launch",
                                                  ROOT / "launch" / "metro_line.launch.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    ld = mod.generate_launch_description()
    items = ld.args[0]
    context = {a.args[0]: a.kwargs["default_value"] for a in items
               if type(a).__name__ == "DeclareLaunchArgument"}
    context.update(scenario="taipei_blue", regulator="lqr", out_dir="/tmp/x", record=record)
    opaque = next(a for a in items if type(a).__name__ == "OpaqueFunction")
    actions = opaque.kwargs["function"](context)
    nodes = [a for a in actions if type(a).__name__ == "Node"]
    launched = [(n.kwargs["executable"], n.kwargs["parameters"]) for n in nodes]

    argv = ["--scenario", "taipei_blue", "--regulator", "lqr", "--out", "/tmp/x"]
    if record:
        argv += ["--record", record]
    a = launcher._parser().parse_args(argv)
    ids = launcher.scenario_train_ids(load_scenario("taipei_blue"))
    resume = ("checkpoint_dir", "checkpoint_period_s")  # launch: only with checkpoints:=true
    run = [(p.executable, ([p.params_file] if p.params_file else [])
            + [{k: v for k, v in p.params.items() if k not in resume}])
           for p in launcher.processes_for(a, ids, Path("/tmp/x"))]
    assert launched == run
    # 30 trains, 30 per ATO process by default: 1 ATO process, not 30
    assert a.ato_per_process == 30 and len(ids) == 30
    assert sum(1 for e, _ in launched if e == "ato_controller") == 1
    assert ("bag_recorder" in [e for e, _ in launched]) == bool(record)
    # the graph goes down when the simulator exits
    handlers = [a for a in actions if type(a).__name__ == "RegisterEventHandler"]
    assert len(handlers) == 1
    on_exit = handlers[0].args[0]
    assert on_exit.kwargs["target_action"] is nodes[0]
    assert nodes[0].kwargs["executable"] == "line_simulator"
    assert type(on_exit.kwargs["on_exit"][0]).__name__ == "Shutdown"
    # every node but the simulator is respawned, as ``run`` does
    assert [n.kwargs["respawn"] for n in nodes] == [e != "line_simulator" for e, _ in launched]
    # the regulator description lists every regulator the ATS accepts
    desc = next(a.kwargs["description"] for a in items
                if type(a).__name__ == "DeclareLaunchArgument" and a.args[0] == "regulator")
    assert all(r in desc for r in launcher.REGULATORS)
