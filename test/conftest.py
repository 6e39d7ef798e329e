"""pytest harness: private DDS domains, node processes, and an in-test topic probe.

Every test that touches DDS gets its own ``ROS_DOMAIN_ID`` (fixture ``ros_domain``) and
discovery stays on loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless set).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Iterator

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "test"))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("PYTHONDONTWRITEBYTECODE", "1")

import background  # noqa: E402
import graph_runs  # noqa: E402,F401 - registers its background jobs
from harness import DomainAllocator, NodeProcess, TopicProbe  # noqa: E402

_DOMAINS = DomainAllocator()
_JOB_SUMMARIES: list[str] = []


@pytest.fixture(scope="session", autouse=True)
def background_jobs(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
                    ) -> Iterator[background.Scheduler]:
    """The background jobs (:mod:`background`) the selected tests need, started at once.

    A job feeds the fixture of its name; jobs run in the order of their first consumer.
    """
    names = background.registered()
    first: dict[str, int] = {}
    for i, item in enumerate(request.session.items):
        for f in getattr(item, "fixturenames", ()):
            if f in names and f not in first:
                first[f] = i
    jobs = [background.Job(n, tmp_path_factory.mktemp(f"job_{n}"))
            for n in sorted(first, key=first.__getitem__)]
    sched = background.Scheduler(jobs)
    try:
        yield sched
    finally:
        _JOB_SUMMARIES.extend(sched.close())


def pytest_sessionfinish(session: Any, exitstatus: int) -> None:
    """Remove the Fast DDS shared memory of the node processes the tests killed."""
    from metro_atc.dds import clean_killed_shm

    clean_killed_shm()


def pytest_terminal_summary(terminalreporter: Any) -> None:
    """With ``-v`` or ``--durations``: how each background job ran."""
    cfg = terminalreporter.config
    if _JOB_SUMMARIES and (cfg.option.verbose > 0 or cfg.option.durations is not None):
        terminalreporter.write_sep("-", f"background jobs ({background.LANES} lane(s))")
        for line in _JOB_SUMMARIES:
            terminalreporter.write_line(line)


@pytest.fixture
def ros_domain() -> Iterator[int]:
    """A DDS domain id used by this test only."""
    with _DOMAINS.allocate() as dom:
        yield dom


@pytest.fixture
def ros_env(ros_domain: int) -> dict[str, str]:
    """Environment for node subprocesses of this test (own domain, loopback discovery)."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(ros_domain)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return env


@pytest.fixture
def probe(ros_domain: int) -> Iterator[TopicProbe]:
    """An rclpy node in the test process on the test's domain, spinning in a thread."""
    p = TopicProbe(ros_domain)
    try:
        yield p
    finally:
        p.close()


@pytest.fixture
def node_procs(ros_env: dict[str, str], tmp_path: Path) -> Iterator[list[NodeProcess]]:
    """A list to register started node processes in; all are stopped (by PID) at teardown."""
    procs: list[NodeProcess] = []
    try:
        yield procs
    finally:
        for p in procs:
            p.stop()


@pytest.fixture(scope="session")
def installed() -> Path:
    """The installed executables directory (``install/metro_atc/lib/metro_atc``)."""
    d = ROOT / "install" / "metro_atc" / "lib" / "metro_atc"
    if not (d / "line_simulator").exists():
        pytest.fail("metro_atc is not built: run `make test` (it builds first)")
    return d


@pytest.fixture(scope="session")
def mini_graph_runs(installed: Path, background_jobs: background.Scheduler) -> dict[str, Any]:
    """Two clean runs of the mini graph, probed (:func:`graph_runs.mini_graph_runs`, a
    background job started with the session).

    Session-wide: ``test_graph`` asserts on them and ``test_resume`` takes run 1 as the
    uninterrupted reference of its runs with killed nodes.
    """
    return dict(background_jobs.result("mini_graph_runs"))


@pytest.fixture(scope="session")
def day_graph_run(installed: Path, background_jobs: background.Scheduler) -> dict[str, Any]:
    """The first part of the Taipei service day through the graph (:func:`graph_runs.
    day_graph_run`, a background job)."""
    return dict(background_jobs.result("day_graph_run"))
