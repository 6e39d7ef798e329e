"""A lost ATO is a CBTC fault: the watchdog and its effect on the plant."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from background import job
from harness import DomainAllocator, TopicProbe

from metro_atc.core.ato_watchdog import STOP_EFFORT, AtoWatchdog
from metro_atc.core.plant.line import LineSim
from metro_atc.core.line.scenario import load_scenario


def test_counts_lost_and_back() -> None:
    """Lost after exactly max_missed consecutive misses; back at the first command."""
    wd = AtoWatchdog(2, max_missed=3)
    act = np.array([True, True])
    eff = np.array([0.7, 0.2])
    got = np.array([False, True])
    kinds = []
    for k in range(5):
        out, ev = wd.apply(k, act, got, eff)
        kinds += [(e.kind, e.train, e.step) for e in ev]
        want = STOP_EFFORT if k >= 2 else 0.7
        assert out[0] == want and out[1] == 0.2
    assert kinds == [("lost", 0, 2)] and wd.losses == 1 and wd.stop_steps == 3
    out, ev = wd.apply(5, act, np.array([True, True]), eff)
    assert [(e.kind, e.missed) for e in ev] == [("back", 5)] and out[0] == 0.7
    # a miss shorter than the limit never stops the train
    for k in range(6, 8):
        out, ev = wd.apply(k, act, got, eff)
        assert out[0] == 0.7 and not ev
    # inactive trains are not counted
    out, ev = wd.apply(8, np.array([False, True]), got, eff)
    assert wd.missed[0] == 2 and not ev
    with pytest.raises(ValueError):
        AtoWatchdog(1, 0)


def test_dead_ato_at_full_traction_is_braked_to_a_stop() -> None:
    """The issue's case: an ATO dies while commanding full traction.

    Without the watchdog the plant keeps the last command (the train runs on at traction);
    with it the train is braked to a standstill within the stopping time of the service
    brake plus the detection delay, and stays there.
    """
    scn = load_scenario("mini")
    speeds = {}
    for use_wd in (False, True):
        sim = LineSim(scn, seed=0)
        wd = AtoWatchdog(sim.n, max_missed=4)
        last = np.zeros(sim.n)
        k_dead = None
        v_dead = 0.0
        for k in range(1200):
            act = np.asarray(sim.active_mask(), dtype=bool)
            st = sim.states()
            moving = bool(act[0]) and st["mode"][0] != 1  # out of the first dwell
            if k_dead is None and moving and st["v_mps"][0] > 12.0:
                k_dead, v_dead = k, float(st["v_mps"][0])
            alive = k_dead is None
            if alive:
                last = np.where(act, 1.0, 0.0)  # full traction for everyone
            got = act.copy()
            got[0] = alive
            eff = wd.apply(k, act, got, last)[0] if use_wd else last
            sim.step(eff)
            if k_dead is not None and k > k_dead + 200:
                break
        assert k_dead is not None
        speeds[use_wd] = (float(sim.states()["v_mps"][0]), v_dead)
    v_end_wd, v_dead = speeds[True]
    assert v_end_wd < 0.05, speeds
    assert speeds[False][0] > 1.0, speeds  # the contrast: without it the train runs on


def _on_own_domain(fn: Any, tmp_path: Path) -> dict[str, Any]:
    """``fn(env, probe, tmp_path)`` on a DDS domain of its own, with a probe on it."""
    with DomainAllocator().allocate() as dom:
        probe = TopicProbe(dom)
        try:
            return dict(fn(dict(os.environ, ROS_DOMAIN_ID=str(dom)), probe, tmp_path))
        finally:
            probe.close()


@job("silent_ato_run")
def _silent_ato_run(tmp_path: Path) -> dict[str, Any]:
    """The line_simulator with a probe as the ATOs that goes silent for train_01 (a
    background job on its own domain; see the test): the speeds of train_01 by step, the
    step the train stood at, the node's exit code and log."""
    return _on_own_domain(_silent_ato, tmp_path)


@pytest.fixture
def silent_ato_run(installed: Any, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_silent_ato_run`."""
    return dict(background_jobs.result("silent_ato_run"))


@pytest.mark.integration
def test_simulator_stops_a_train_whose_ato_goes_silent(silent_ato_run: dict[str, Any]
                                                       ) -> None:
    """The line_simulator node with a probe as the ATOs: train_01's ATO commands full
    traction, then goes silent; the node logs the loss, brakes the train to a standstill,
    and hands it back when the ATO answers again."""
    speeds, n0, k_stop = (silent_ato_run[k] for k in ("speeds", "n0", "k_stop"))
    code, log = silent_ato_run["code"], silent_ato_run["log"]
    assert code == 0 and "Traceback" not in log
    # silent ATO: the last command (full traction) for at most the 4 missed steps (+1 in
    # flight), then only deceleration until the train stands
    tail = [v for k, v in speeds[n0:] if k <= k_stop]
    j = int(np.argmax(tail))
    assert j <= 6, tail[:10]
    assert all(b <= a + 1e-6 for a, b in zip(tail[j:], tail[j + 1:])), tail


def _silent_ato(ros_env: dict[str, str], probe: Any, tmp_path: Path) -> dict[str, Any]:
    """Run the simulator with the probe as ATOs; train_01's goes silent, then back."""
    import threading

    from metro_atc_msgs.msg import TractionCommand, TrainState

    from harness import NodeProcess
    from metro_atc.nodes.common import QOS_RELIABLE

    alive = threading.Event()
    alive.set()
    speeds: list[tuple[int, float]] = []
    pubs = {t: probe.publisher(TractionCommand, f"/{t}/command", QOS_RELIABLE)
            for t in ("train_01", "train_02")}

    def answer(m: Any) -> None:
        if m.train_id == "train_01":
            speeds.append((int(m.step), float(m.speed_mps)))
            if not alive.is_set():
                return
        c = TractionCommand(train_id=m.train_id, step=m.step, mode=2,
                            effort=1.0 if m.train_id == "train_01" else 0.0)
        c.header.stamp = m.header.stamp
        pubs[m.train_id].publish(c)

    for t in pubs:
        probe.node.create_subscription(TrainState, f"/{t}/state", answer, QOS_RELIABLE)
    p = NodeProcess.installed("line_simulator", ["-p", "scenario:=mini",
                                                 "-p", "startup_timeout_s:=5.0",
                                                 "-p", "step_timeout_s:=0.05",
                                                 "-p", "ato_lost_steps:=4"],
                              ros_env, tmp_path)
    try:
        assert probe.wait_for(lambda: any(v > 8.0 for _, v in speeds), timeout=60), p.log()
        alive.clear()
        n0 = len(speeds)
        assert p.wait_for_log("ATO of train_01", timeout=30), p.log()
        assert "lost: no command for 4 steps" in p.log()
        assert probe.wait_for(lambda: speeds[-1][1] < 0.01, timeout=60), speeds[-5:]
        k_stop = speeds[-1][0]
        alive.set()
        assert p.wait_for_log("back after", timeout=30), p.log()
        assert probe.wait_for(lambda: speeds[-1][0] > k_stop + 20, timeout=30)
    finally:
        code = p.stop()
    with probe.lock:
        return {"speeds": list(speeds), "n0": n0, "k_stop": k_stop, "code": code,
                "log": p.log()}


@job("lost_fleet_state_run")
def _lost_fleet_state_run(tmp_path: Path) -> dict[str, Any]:
    """The simulator and an ATS with a probe as the fleet ATO that ignores one fleet state
    (a background job on its own domain; see the test): fleet states seen per step, the
    simulator's exit code and log."""
    return _on_own_domain(_lost_fleet_state, tmp_path)


@pytest.fixture
def lost_fleet_state_run(installed: Any, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_lost_fleet_state_run`."""
    return dict(background_jobs.result("lost_fleet_state_run"))


@pytest.mark.integration
def test_a_fleet_state_lost_on_its_way_is_sent_again(lost_fleet_state_run: dict[str, Any]
                                                     ) -> None:
    """Lockstep without a lost step: a fleet state the ATO never got (lost with a killed ATO
    process whose successor matched unnoticed) is published again for the trains that did
    not answer, well before the step timeout; the step completes without a lockstep miss.

    A probe is the fleet ATO beside a real ATS: it ignores the first fleet state of step
    ``drop`` (train_01 in service, dwelling) and answers every other one. With a step timeout
    of 120 s, a simulator that only waited would show the miss in its log.
    """
    seen, code, log = (lost_fleet_state_run[k] for k in ("seen", "code", "log"))
    drop = lost_fleet_state_run["drop"]
    assert code == 0 and "Traceback" not in log
    assert seen[drop] >= 2, seen  # sent again
    assert "no command from" not in log, log


def _lost_fleet_state(ros_env: dict[str, str], probe: Any, tmp_path: Path) -> dict[str, Any]:
    """Run the simulator and an ATS with the probe as a fleet ATO that drops a state."""
    import threading

    from metro_atc_msgs.msg import FleetCommand, FleetState

    from harness import NodeProcess
    from metro_atc.nodes import conversions as conv
    from metro_atc.nodes.wire import fleet_command
    from metro_atc.nodes.common import QOS_RELIABLE

    drop = 110
    seen: dict[int, int] = {}
    lock = threading.Lock()
    pub = probe.publisher(FleetCommand, "/line/fleet_command", QOS_RELIABLE)

    def answer(m: Any) -> None:
        k = int(m.step)
        with lock:
            seen[k] = seen.get(k, 0) + 1
            if k == drop and seen[k] == 1:
                return  # lost on its way
        n = len(m.train_id)
        pub.publish(fleet_command.to_msg(k, conv.from_time(m.header.stamp),
                                         list(m.train_id), [0.0] * n, [2] * n))

    probe.node.create_subscription(FleetState, "/line/fleet_state", answer, QOS_RELIABLE)
    ats = NodeProcess.installed("ats_regulator", ["-p", "scenario:=mini"], ros_env,
                                tmp_path)
    p = NodeProcess.installed("line_simulator", ["-p", "scenario:=mini",
                                                 "-p", "startup_timeout_s:=3.0",
                                                 "-p", "step_timeout_s:=120.0"],
                              ros_env, tmp_path)
    try:
        assert probe.wait_for(lambda: max(seen, default=-1) >= drop + 3, timeout=100), \
            (seen, p.log())
    finally:
        code = p.stop()
        ats.stop()
    with lock:
        return {"seen": dict(seen), "drop": drop, "code": code, "log": p.log()}
