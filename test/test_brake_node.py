"""Integration tests of the brake_diagnostic node over DDS.

* The whole graph runs ``mini_pad_fault`` (mini + the pad friction of train_01's instrumented
  car dropping to 0.10 at t = 270 s, an emergency-brake stop of train_01 at 275 s and of the
  healthy train_02 at 320 s): ``/diagnostics`` must report ERROR for train_01 within
  ``DETECT_WITHIN_S`` of the fault (its BrakeDiagnosis with ``pad_flaw``), and never for
  train_02, which must have been observed braking just as hard.
* The installed node alone, fed by the test: NaN, wrong-length, out-of-order and
  wrong-train samples are skipped with a log line; the node keeps running and never
  publishes NaN; with no data at all the timer still publishes ``/diagnostics``.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from harness import DomainAllocator, NodeProcess, TopicProbe

pytestmark = pytest.mark.integration

SCENARIO = "mini_pad_fault"
FAULT_TRAIN, HEALTHY_TRAIN = "train_01", "train_02"
FAULT_T_S = 270.0
"""Pad fault onset in mini_pad_fault.yaml [s]; the emergency brake follows at 275 s."""
DETECT_WITHIN_S = 10.0
"""Stated detection time: flaw announced within this long after the fault onset [s]: 5 s
until the first friction-brake application at speed (the emergency brake), then <= 5 s
(measured: 6.55 s, i.e. 1.55 s into the brake; offline study 1.1-2.3 s into the brake)."""
ERROR = 2


def _level(st: Any) -> int:
    """DiagnosticStatus.level is a ``bytes`` of length 1 in rclpy."""
    lv = st.level
    return lv[0] if isinstance(lv, (bytes, bytearray)) else int(lv)


def _stamp(h: Any) -> float:
    return float(h.stamp.sec) + 1e-9 * float(h.stamp.nanosec)


def _qos_all() -> Any:
    """Reliable, volatile, deep: matches /diagnostics and the latched diagnosis topics."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


@pytest.fixture(scope="module")
def fault_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Run mini_pad_fault through the multi-process graph, recording the diagnosis topics."""
    from diagnostic_msgs.msg import DiagnosticArray
    from metro_atc_msgs.msg import BrakeDiagnosis

    out = tmp_path_factory.mktemp("pad_fault")
    with DomainAllocator().allocate() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        probe = TopicProbe(dom, name="brake_probe")
        try:
            diags = probe.subscribe(DiagnosticArray, "/diagnostics", _qos_all())
            bd = {t: probe.subscribe(BrakeDiagnosis, f"/{t}/brake_diagnosis", _qos_all())
                  for t in (FAULT_TRAIN, HEALTHY_TRAIN)}
            t0 = time.monotonic()
            r = subprocess.run([sys.executable, "-m", "metro_atc", "run", "--scenario",
                                SCENARIO, "--json", "--no-plots", "--out", str(out)],
                               env=env, capture_output=True, text=True, timeout=240, cwd=out)
            wall = time.monotonic() - t0
            assert r.returncode == 0, r.stderr[-3000:]
            time.sleep(0.5)  # last messages in flight
            with probe.lock:
                res = {"diags": list(diags), "bd": {t: list(v) for t, v in bd.items()}}
        finally:
            probe.close()
    res["kpis"] = json.loads([ln for ln in r.stdout.splitlines() if ln.strip()][-1])
    res["log"] = (out / "logs" / "brake_diagnostic.log").read_text(errors="replace")
    res["wall_s"] = wall
    return res


def _statuses(run: dict[str, Any], train: str) -> list[tuple[float, int, dict[str, str]]]:
    """(stamp, level, key-values) of every /diagnostics status of ``train``."""
    out = []
    for arr in run["diags"]:
        for st in arr.status:
            if st.hardware_id.startswith(train + "/"):
                out.append((_stamp(arr.header), _level(st), {k.key: k.value for k in st.values}))
    return out


def test_pad_fault_flagged_within_stated_time(fault_run: dict[str, Any]) -> None:
    """/diagnostics: ERROR for the faulty train, announced within DETECT_WITHIN_S of the fault.

    The announcement time is the status key ``flaw_time_s`` (simulated time of the sample
    that completed the persistence window), so a /diagnostics message lost by the probe
    under CPU load does not change the measured delay.
    """
    st = _statuses(fault_run, FAULT_TRAIN)
    assert st, "no /diagnostics status for " + FAULT_TRAIN
    errors = [(t, kv) for t, lv, kv in st if lv == ERROR]
    assert errors, f"{FAULT_TRAIN} never reported ERROR; log:\n{fault_run['log'][-2000:]}"
    t_err, kv = errors[0]
    t_flaw = float(kv["flaw_time_s"])
    delay = t_flaw - FAULT_T_S
    print(f"\n{FAULT_TRAIN}: flaw announced at t={t_flaw:.2f} s, {delay:.2f} s after the pad "
          f"fault (first ERROR status received at t={t_err:.2f} s); mu_b_hat {kv['mu_b']} +- "
          f"{kv['mu_b_std']}; graph wall time {fault_run['wall_s']:.1f} s")
    assert 0.0 <= delay <= DETECT_WITHIN_S, delay
    assert t_flaw <= t_err + 1e-6 and kv["pad_flaw"] == "True"
    assert all(lv != ERROR for t, lv, _ in st if t < FAULT_T_S)
    # ERROR latches: it stays for the rest of the run
    assert all(lv == ERROR for t, lv, _ in st if t >= t_err)


def test_pad_flaw_in_brake_diagnosis(fault_run: dict[str, Any]) -> None:
    """The faulty train's BrakeDiagnosis carries pad_flaw, level ERROR and finite fields."""
    msgs = fault_run["bd"][FAULT_TRAIN]
    assert msgs
    flawed = [m for m in msgs if m.pad_flaw]
    assert flawed, "no BrakeDiagnosis with pad_flaw"
    m = flawed[0]
    assert m.level == ERROR and m.train_id == FAULT_TRAIN and "pad" in m.message
    # the decision's one-sided test (metro_atc.core.brake.train_watch.MU_B_SIGMAS = 3)
    assert 0.0 < m.friction_coefficient and 0.0 < m.friction_coefficient_std
    assert m.friction_coefficient + 3.0 * m.friction_coefficient_std < 0.2
    assert flawed[-1].level == ERROR  # latched until maintenance resets it
    assert len(m.longitudinal_force_n) == len(m.force_residual_n) == len(m.axle_flaw) == 4
    assert m.measurements_used > 100
    for msg in msgs:
        vals = [msg.friction_coefficient, msg.friction_coefficient_std,
                *msg.longitudinal_force_n, *msg.force_residual_n]
        assert all(math.isfinite(v) for v in vals)
    assert all(not x.pad_flaw for x in msgs if _stamp(x.header) < FAULT_T_S)


def test_healthy_train_stays_ok(fault_run: dict[str, Any]) -> None:
    """The healthy train is never ERROR, although it was observed in a hard brake."""
    st = _statuses(fault_run, HEALTHY_TRAIN)
    assert st, "no /diagnostics status for " + HEALTHY_TRAIN
    bad = [(t, kv["mu_b"]) for t, lv, kv in st if lv == ERROR]
    assert not bad, bad[:5]
    msgs = fault_run["bd"][HEALTHY_TRAIN]
    assert msgs and not any(m.pad_flaw or any(m.axle_flaw) for m in msgs)
    # the node's own record of every judged estimate (messages may be lost under CPU load);
    # the brake application itself gives a 0.1 s dip (the WARN seen at its onset)
    med = _judged_median(fault_run["log"], HEALTHY_TRAIN)
    assert med is not None, "the healthy train's mu_b was never observable (no hard brake)"
    assert 0.25 < med[0] < 0.45 and med[1] >= 20, med
    bad_med = _judged_median(fault_run["log"], FAULT_TRAIN)
    assert bad_med is not None and bad_med[0] < 0.2, bad_med
    print(f"\nmu_b_hat while judged (std < 0.012): {HEALTHY_TRAIN} median {med[0]:.3f} of "
          f"{med[1]} (true 0.35); {FAULT_TRAIN} median {bad_med[0]:.3f} of {bad_med[1]} "
          f"(true 0.10)")


def _judged_median(log: str, train: str) -> tuple[float, int] | None:
    """(median, count) of the judged mu_b_hat from the node's shutdown summary."""
    m = re.search(rf"{train}: \w+.*?mu_b_hat judged: median ([0-9.]+) of (\d+)", log)
    return (float(m.group(1)), int(m.group(2))) if m else None


def test_node_reports_rate_and_exits_cleanly(fault_run: dict[str, Any]) -> None:
    """The node ran without a traceback and reports its observer update rate."""
    log = fault_run["log"]
    assert "Traceback" not in log, log[-3000:]
    m = re.search(r"observer: (\d+) updates, (\d+) updates per CPU second", log)
    assert m, log[-2000:]
    print(f"\nbrake_diagnostic: {m.group(1)} observer updates, {m.group(2)} updates/CPU-s")
    assert int(m.group(1)) > 200 and int(m.group(2)) > 0
    assert fault_run["kpis"]["completed_trains"] == fault_run["kpis"]["trains"]


def test_kpis_say_which_brakes_were_assessed(fault_run: dict[str, Any]) -> None:
    """kpis.json: per train whether its brake was assessed, as the node's summary says it
    (both trains of mini_pad_fault emergency-brake at speed: both assessed), from the last
    BrakeDiagnosis (``assessed``) the simulator took."""
    k = fault_run["kpis"]
    log = fault_run["log"]
    said = {t: re.search(rf"{t}: \w+.*?; brake (not )?assessed", log) for t in
            (FAULT_TRAIN, HEALTHY_TRAIN)}
    assert all(said.values()), log[-2000:]
    assert k["brake_assessed"] == {t: m.group(1) is None for t, m in said.items()}
    assert k["brake_assessed"] == {FAULT_TRAIN: True, HEALTHY_TRAIN: True}
    assert k["brake_trains_not_assessed"] == []
    assert fault_run["bd"][HEALTHY_TRAIN][-1].assessed


# ------------------------------------------------------------------ bad input, node alone

def _sample(train: str, t: float, v: float, omega: Any = None, clamp: Any = None,
            accel: float = -0.1, mass: float = 30_000.0) -> Any:
    """One sample as a FleetBrakeSensorData (what the simulator publishes), any axle count."""
    from metro_atc_msgs.msg import FleetBrakeSensorData

    from metro_atc.nodes.conversions import stamps_ns, to_time

    w = [float(x) for x in (omega if omega is not None else [v / 0.43] * 4)]
    m = FleetBrakeSensorData()
    m.header.stamp = to_time(t)
    m.train_id = [train]
    m.sample_train = [0]
    m.stamp_ns = [int(stamps_ns([t])[0])]
    m.axle_count = [len(w)]
    m.wheel_angular_speed_radps = w
    m.clamp_force_n = [float(x) for x in (clamp if clamp is not None else [0.0] * len(w))]
    m.longitudinal_acceleration_mps2 = [float(accel)]
    m.reference_speed_mps = [float(v)]
    m.car_mass_kg = [float(mass)]
    return m


def test_bad_samples_are_skipped_node_stays_alive(installed: Path, ros_env: dict[str, str],
                                                  probe: TopicProbe, tmp_path: Path) -> None:
    """NaN, wrong-length, out-of-range, out-of-order and unknown-train samples on the fleet
    sensor topic: logged, skipped, no NaN out."""
    from diagnostic_msgs.msg import DiagnosticArray
    from metro_atc_msgs.msg import BrakeDiagnosis, FleetBrakeSensorData

    from metro_atc.nodes.common import FLEET_SENSOR_TOPIC, QOS_FLEET_SENSOR

    diags = probe.subscribe(DiagnosticArray, "/diagnostics", _qos_all())
    bd = probe.subscribe(BrakeDiagnosis, "/train_01/brake_diagnosis", _qos_all())
    pub = probe.publisher(FleetBrakeSensorData, FLEET_SENSOR_TOPIC, QOS_FLEET_SENSOR)
    p = NodeProcess.installed("brake_diagnostic", ["-p", "scenario:=mini",
                                                   "-p", "diagnostics_period_s:=0.5",
                                                   "-p", "log_period_s:=0.0"],
                              ros_env, tmp_path)
    try:
        # no data at all: the timer publishes "waiting" for both trains
        assert probe.wait_for(lambda: len(diags) > 0, timeout=30), p.log()
        first = diags[0]
        assert {s.hardware_id for s in first.status} == {"train_01/car_1", "train_02/car_1"}
        assert all(_level(s) == 0 and "waiting" in s.message for s in first.status)
        assert probe.wait_for(lambda: pub.get_subscription_count() > 0, timeout=30)
        time.sleep(0.3)
        t = 0.0
        rng = np.random.default_rng(1)

        def good(n: int) -> None:
            nonlocal t
            for _ in range(n):
                t += 0.05
                v = 20.0 - 0.1 * t
                pub.publish(_sample("train_01", t, v,
                                    omega=v / 0.43 + rng.normal(0.0, 0.02, 4)))
                time.sleep(0.002)

        good(40)
        assert probe.wait_for(lambda: any(m.measurements_used >= 20 for m in bd), 20), p.log()
        t += 0.05
        nan4 = [math.nan] * 4
        pub.publish(_sample("train_01", t, math.nan, omega=nan4, accel=math.nan))
        assert p.wait_for_log("non-finite", timeout=20), p.log()
        t += 0.05
        pub.publish(_sample("train_01", t, 19.0, omega=[44.0, 44.0, 44.0]))
        assert p.wait_for_log("expected 4 axles", timeout=20), p.log()
        pub.publish(_sample("train_01", 0.5, 19.0))
        assert p.wait_for_log("out of order", timeout=20), p.log()
        pub.publish(_sample("train_99", t + 0.05, 19.0))
        assert p.wait_for_log("not a train of the scenario", timeout=20), p.log()
        t += 0.05
        pub.publish(_sample("train_01", t, 19.0, accel=100.0))
        assert p.wait_for_log("longitudinal_acceleration_mps2[0] outside", timeout=20), p.log()
        # a 3 s total dropout (every channel NaN), then good data again
        for _ in range(60):
            t += 0.05
            pub.publish(_sample("train_01", t, math.nan, omega=nan4, clamp=nan4,
                                accel=math.nan, mass=math.nan))
            time.sleep(0.002)
        good(40)
        assert probe.wait_for(lambda: any(m.measurements_rejected >= 3 for m in bd), 20)
        n_used = max(m.measurements_used for m in bd)
        assert probe.wait_for(lambda: max(m.measurements_used for m in bd) >= n_used, 10)
        assert p.alive(), p.log()
        for m in list(bd):
            vals = [m.friction_coefficient, m.friction_coefficient_std,
                    *m.longitudinal_force_n, *m.force_residual_n]
            assert all(math.isfinite(x) for x in vals), m
        # /diagnostics is periodic in wall time (0.5 s here): wait for a tick after the above

        def rejected_seen() -> bool:
            last = [s for a in diags for s in a.status if s.hardware_id == "train_01/car_1"]
            kv = {k.key: k.value for k in last[-1].values} if last else {}
            return int(kv.get("samples_rejected", 0)) >= 3

        assert probe.wait_for(rejected_seen, 10)
        last = [s for a in list(diags) for s in a.status if s.hardware_id == "train_01/car_1"]
        kv = {k.key: k.value for k in last[-1].values}
        assert int(kv["samples_rejected"]) >= 3 and int(kv["samples_degraded"]) >= 1
        assert math.isfinite(float(kv["mu_b"]))
    finally:
        code = p.stop()
    assert code == 0, p.log()
    assert "Traceback" not in p.log()
    assert "updates per CPU second" in p.log()
