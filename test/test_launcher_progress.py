"""`python -m metro_atc run` progress: the simulator's progress lines with horizon and ETA."""

from __future__ import annotations

import io
from pathlib import Path

from metro_atc.launcher import ProgressTail


def test_progress_tail_prints_new_lines_with_eta(tmp_path: Path) -> None:
    """Only complete new progress lines are echoed; ETA = simulated time left / RTF."""
    log = tmp_path / "line_simulator.log"
    out = io.StringIO()
    tail = ProgressTail(log, 6000.0, out)
    assert tail.poll() == 0  # no log yet
    log.write_text("[INFO] [1.0] [line_simulator]: scenario 'x': 30 trains\n"
                   "[INFO] [2.0] [line_simulator]: t=600 s: 5 trains in service, 0 lockstep "
                   "misses, 20.0x real time\n[INFO] [3.0] [line_simulator]: t=1200 s: 9 tra")
    assert tail.poll() == 1
    first = out.getvalue().strip()
    assert "t = 600 / 6000 s" in first and "5 trains" in first and "ETA 4 min 30 s" in first
    with log.open("a") as fh:  # the rest of the partial line arrives
        fh.write("ins in service, 1 lockstep misses, 10.0x real time\n")
    assert tail.poll() == 1
    last = out.getvalue().strip().splitlines()[-1]
    assert "t = 1200 / 6000 s" in last and "1 lockstep misses" in last and "ETA 8 min 00 s" in last
    assert tail.poll() == 0


def test_progress_runs_late_past_the_estimate(tmp_path: Path) -> None:
    """Past the end estimate the horizon follows the simulated time (no negative ETA)."""
    log = tmp_path / "line_simulator.log"
    out = io.StringIO()
    tail = ProgressTail(log, 6000.0, out)
    log.write_text("[INFO] [2.0] [line_simulator]: t=6100 s: 1 trains in service, 0 lockstep "
                   "misses, 40.0x real time\n")
    assert tail.poll() == 1
    row = out.getvalue().strip()
    assert "t = 6100 / 6100 s" in row and "last trains arriving" in row


def test_progress_horizon_is_the_estimated_end_of_service() -> None:
    """The ETA counts to the estimated end of service, or the duration when that comes first.

    The estimate (last scheduled arrival + terminus dwell + tail track + turnback) is within
    a few minutes of the end of a real run: the ROS-free closed loop of ``taipei_blue``.
    """
    import numpy as np

    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.line.service import timetable_for
    from metro_atc.launcher import progress_horizon_s

    scn = load_scenario("taipei_blue")
    last = float(np.nanmax(timetable_for(scn).arrival_s))
    end = progress_horizon_s(scn, 0.0)
    assert last + scn.line.turnback_s < end < float(scn.sim.duration_s)
    assert progress_horizon_s(scn, 900.0) == 900.0
    assert progress_horizon_s(scn, 1e9) == end


def test_progress_echoes_start_and_end_of_the_run(tmp_path: Path) -> None:
    """The simulator's 'graph ready' and 'scenario finished' lines are echoed as they come."""
    log = tmp_path / "line_simulator.log"
    out = io.StringIO()
    tail = ProgressTail(log, 6000.0, out)
    log.write_text("[INFO] [1.0] [line_simulator]: scenario 'x': 30 trains\n"
                   "[INFO] [1.5] [line_simulator]: graph ready after 0.87 s\n")
    assert tail.poll() == 1
    assert out.getvalue().strip() == "metro_atc run: graph ready after 0.87 s; stepping"
    with log.open("a") as fh:
        fh.write("[INFO] [9.0] [line_simulator]: scenario finished at t=6337.0 s after "
                 "25348 steps, 109.2 s wall\n")
    assert tail.poll() == 1
    assert out.getvalue().strip().splitlines()[-1] == (
        "metro_atc run: scenario finished at t=6337.0 s after 25348 steps, 109.2 s wall; "
        "writing the outputs")
