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
