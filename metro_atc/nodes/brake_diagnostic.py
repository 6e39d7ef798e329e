"""brake_diagnostic node: brake-by-wire active safety diagnosis of every train.

One node watches all trains of the scenario.  It subscribes to ``/line/brake_sensors``
(``metro_atc_msgs/FleetBrakeSensorData``, reliable: the samples of every train produced in
one lockstep step, in one message; the per-train ``/<train>/brake_sensors`` are for outside
tools), runs one :class:`~metro_atc.core.brake.metro_car.MetroBrakeObserver` (the
Lin 2010b UKF, metro variant) per train at the sensor rate, and publishes

* ``/<train>/brake_diagnosis`` (``metro_atc_msgs/BrakeDiagnosis``, latched) every
  ``diagnostics_period_s`` of wall time if it changed, at once when the train's level
  changes, and within
  :data:`ACK_PERIOD_S` (wall) of a new sample: its stamp is the train's newest sample, which
  the simulator takes as an acknowledgement (it keeps the samples after it for a restarted
  diagnosis, and at the end of a run waits until the last one is acknowledged);
* ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``): one status per train, OK / WARN /
  ERROR, with key-values (mu_b estimate and std, per-axle residuals and forces, counters),
  every ``diagnostics_period_s`` of wall time (a steady-clock timer, so ~1 Hz whatever the
  lockstep speed), stamped with the newest sample's simulated time.

**One process for all trains.**  The per-train work is one UKF step (19 states, 39 sigma
points) per used sample (the compiled kernel of :mod:`metro_atc.core.brake.metro_kernel`
plus the residuals and decision, ~0.3 ms under load; a sample of a standing train is
only validated, journaled and counted); the filters are independent, so a
single-threaded node serves ``N x rate`` samples per second as long as that stays below
those figures.  On Taipei Blue the used samples are few at any instant (0.4 trains per
sample instant on average over 1 800 s), so batching the filters across trains would
batch nothing; the per-sample costs are cut instead: one message per step for all trains,
validated in one vectorised pass (:func:`metro_atc.nodes.wire.fleet_sensors.samples`,
its samples as float lists that are their own journal entries, and their values packed),
each sample one packed journal line (:func:`packed_entries`), a train's lines of a burst
written at once, a standing or slow train's sample (most of them) counted by
:meth:`TrainBrakeWatch.feed_paused`, the per-axle arithmetic of the watch and the observer
done on plain floats (``test/brake_replay.py`` replays a run's batches bit for
bit against the code before).
The Taipei Blue scenario at 20 Hz needs at most 30 x 20 = 600 updates per simulated
second (every train braking at once), and the simulator sends the full rate only while a
car brakes (a 1 Hz heartbeat otherwise); one process per train would cost 30 Python
interpreters and DDS participants for no gain.  The sensor subscription is served by
:func:`sample_loop` (a direct wait set), not by the executor.

**Time.**  The filter's step and the decision logic's persistence are driven by the sample
stamps (simulated time), so the verdicts do not depend on wall-clock speed; only the
publication period of ``/diagnostics`` is wall time.

**Robustness.**  A batch whose arrays disagree in length (or are absurdly large) is one
rejection (kind ``length``); within a batch, a sample of a train not in the scenario, with a
wrong number of axles, a stamp outside the run's horizon, an implausible channel value
(:func:`metro_atc.nodes.wire.fleet_sensors.samples`, the rules of
:func:`~metro_atc.nodes.conversions.sensor_from_msg`), or a stamp not after the previous
one (out of order / duplicate) is rejected (not used at all; ``RESYNC_SAMPLES`` in-order
samples behind a future-stamped one re-synchronise the stream and restart the filter).
A rejected sample changes nothing but the rejection counters (and the journal line that
restores them after a restart): not the observer, not the journaled samples, not the
acknowledgement (a sample stamped 1e6 s used to raise its train's "newest received" stamp,
so every later BrakeDiagnosis acknowledged a stamp the simulator rejects, and the run's end
waited out its whole drain timeout);
a sample with NaN channels (dropouts) is used with those channels left out of the
measurement update (predict only when no speed channel is left; the clamp force is
held).  Each kind is logged at most once per ``log_period_s`` (wall) per train with the
number suppressed.  The observer never outputs NaN (see its robustness contract).

**Consist adaptation** (the instrumented car is a trailer inside a 6-car train): see
:mod:`metro_atc.core.brake.train_watch` (:class:`TrainBrakeWatch`, the ROS-free per-train
state this node runs, also used by the ROS-free closed loop).

**Restart.**  With ``checkpoint_dir`` every sample handed to a train's observer (and every
rejected one, for the counters) is appended to ``<checkpoint_dir>/brake_<train>.jsonl``
(:class:`metro_atc.core.journal.Journal`; one line per sample, :func:`packed_entries`:
its floats in binary, base64, ~5x cheaper than its JSON; lines of a JSON sample each, and
lines of several packed samples, are read too).  A restarted node replays the journals
into fresh observers: the UKF, the decision logic and the counters are where they were.
When the simulator resumes from a checkpoint and sends again a sample the journal holds
(same stamp, same channels), the train's observer is rebuilt from the journal up to that
sample; the newest sample sent again (the simulator's end-of-run re-send of what may have
been lost) is skipped.
"""

from __future__ import annotations

import base64
import json
import math
import struct
import sys
import time
from functools import partial
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from metro_atc_msgs.msg import BrakeDiagnosis, FleetBrakeSensorData
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from metro_atc.core.brake.train_watch import (  # noqa: F401  (re-exported for callers)
    BRAKED_CLAMP_N, LEVEL_NAMES, MAX_GAP_S, MU_B_STD_JUDGE, N_AXLES, PERSISTENCE_S,
    PSEUDO_ACCEL_STD, PSEUDO_MAX_AGE_S, PSEUDO_SPEED_GATE_MPS, Q_COUPLER, Q_FORCE,
    RESYNC_SAMPLES, SLIDE_AXLES, V_MIN_CREEP, V_PAUSE_MPS, V_PSEUDO_MPS, ObserverSetup,
    TrainBrakeWatch, observer_setup)
from metro_atc.core.journal import Journal
from metro_atc.core.line.scenario import ScenarioError
from metro_atc.core.service.dayrun import load_run_scenario
from metro_atc.core.validate import Rejections, bounds_for
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.wire import fleet_sensors
from metro_atc.nodes.common import (FLEET_SENSOR_TOPIC, QOS_FLEET_SENSOR, QOS_LATCHED,
                                    NodeConfigError, RuntimeParams,
                                    SubscriptionPoller, bulk_publisher, run_nodes, static,
                                    stop_requested)

SLOW_PERIOD_S = 0.2
"""The executor (parameter services, the /diagnostics timer) is spun this often [s, wall]:
each spin rebuilds rclpy's wait set in Python (~1 ms); a parameter request waits at most
this long.  The sample wait itself is at most ``POLL_S``."""
POLL_S = 0.05
"""Longest wait for samples [s, wall] (the stop flag is checked in between)."""

ACK_PERIOD_S = 0.5
"""Wall period of the acknowledgement: a train whose newest sample is newer than the stamp
of its last BrakeDiagnosis gets one within this time."""
IDLE_ACK_S = 0.02
"""Wall time without a new sample after which the samples received are acknowledged at
once (not at the next :data:`ACK_PERIOD_S` tick) [s]: the end of a run, where the simulator
waits for the acknowledgement of its last samples before it writes its outputs (up to
~0.6 s of every run's end).  A running lockstep sends a batch every simulated second
(~10 ms of wall time at 100x), so this adds no acknowledgement while samples flow; a
slower stream is acknowledged at most every :data:`IDLE_ACK_GAP_S`."""
IDLE_ACK_GAP_S = 0.1
"""Least wall time between two idle acknowledgements (:data:`IDLE_ACK_S`) [s]: at most 10
BrakeDiagnosis per train and wall second besides the :data:`ACK_PERIOD_S` ones."""

HOLD_MAX_S = 10.0
"""After a restart: wall seconds at most that a train's acknowledgement stays at its newest
journaled sample while no re-sent sample has reached back to it (see
:attr:`BrakeDiagnostic.held`): a train whose samples the simulator no longer keeps is then
acknowledged as usual."""


class BrakeDiagnostic(Node):
    """The brake diagnosis node (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, build one observer per train, subscribe to their sensors."""
        super().__init__("brake_diagnostic", **kwargs)
        self.scenario_name = static(self, "scenario", "taipei_blue",
                                    "embedded scenario name or path to a scenario YAML")
        try:
            scn = load_run_scenario(self.scenario_name)
        except ScenarioError as exc:
            raise NodeConfigError(str(exc)) from None
        setup = observer_setup(scn)
        self.setup = setup
        self.bounds = bounds_for(scn)
        self.rejections = Rejections()
        """Rejected samples per kind (:mod:`metro_atc.core.validate`; out_of_order too)."""
        self.ids = list(scn.sensors.trains or scn.train_ids)
        self.watch = {t: TrainBrakeWatch(t, setup) for t in self.ids}
        self._logged: dict[tuple[str, str], tuple[float, int]] = {}
        self._levels = {t: -1 for t in self.ids}
        # /diagnostics (one status per train) and every BrakeDiagnosis on a wall-clock
        # period; a train's BrakeDiagnosis also at once when its level changes
        self.rt = RuntimeParams(self, self.health, stamp=self.last_sample_t)
        self.log_period_s = self.rt.dynamic(
            "log_period_s", 2.0, "at most one log line per train and kind this often "
            "(wall clock) [s]", partial(setattr, self, "log_period_s"), 0.0, 3600.0)
        self.pubs = {t: bulk_publisher(self, BrakeDiagnosis, f"/{t}/brake_diagnosis",
                                       QOS_LATCHED) for t in self.ids}
        self._recv_t = {t: -math.inf for t in self.ids}
        """Stamp of the newest valid sample this process received per train [s] (what the
        acknowledgement covers besides the observer's newest sample).  A rejected sample
        never raises it (one stamped beyond the run would be every later acknowledgement's
        stamp, which the simulator rejects); a future-stamped valid one only until the
        stream behind it re-synchronises the watch (``RESYNC_SAMPLES``)."""
        self._pub_stamp = {t: math.nan for t in self.ids}
        self._sample_count = 0
        """Samples handled (:meth:`_on_sample`), rejected ones included."""
        self._acked_count = 0
        """:attr:`_sample_count` at the last acknowledgement (:meth:`acknowledge_pending`)."""
        """Stamp of each train's last BrakeDiagnosis [s] (the acknowledged sample)."""
        self._pub_key: dict[str, tuple[Any, ...]] = {}
        """What each train's last BrakeDiagnosis was built from (its watch's generation,
        samples received, stamp, level): the /diagnostics tick publishes it again only if
        changed."""
        self._status_cache: dict[str, tuple[tuple[Any, ...], DiagnosticStatus]] = {}
        """Each train's last /diagnostics status and the key it was built for."""
        self._gen = {t: 0 for t in self.ids}
        """Times each train's watch was rebuilt from its journal (part of those keys)."""
        self.ack_timer = self.create_timer(ACK_PERIOD_S, self._acknowledge,
                                           clock=Clock(clock_type=ClockType.STEADY_TIME))
        ck_dir = static(self, "checkpoint_dir", "",
                        "directory of the per-train sample journals ('' : none): a restarted "
                        "node replays them, a simulator resumed behind is followed back")
        self.journals: dict[str, Journal] = {}
        self._unwritten: dict[str, list[dict[str, Any] | bytes]] = {}
        """Journal entries not written yet (written by :meth:`flush`)."""
        self._kv: dict[str, dict[str, KeyValue]] = {t: {} for t in self.ids}
        """The /diagnostics key-values of each train (reused: only their values change)."""
        self.held: dict[str, float] = {}
        """After a restart, per train: its newest journaled sample [s], acknowledged instead
        of the newest received until a sample at or before it arrives (the simulator's
        re-send to this new reader reached back) or :data:`HOLD_MAX_S` passed.  The live
        stream reaching the node first would otherwise acknowledge what was published while
        it was down: at the end of a run the simulator would then see nothing pending and
        stop before its re-send."""
        self._level_changed = False
        """A train's level changed since the last /diagnostics (published after the batch)."""
        self.catching_up: set[str] = set()
        """Trains out of :attr:`held` whose observer has not yet taken every sample received
        (the re-send): acknowledged at the observer's newest sample until it has."""
        self._held_until = math.inf
        """Wall time (monotonic) [s] at which :attr:`held` and :attr:`catching_up` lapse
        (:data:`HOLD_MAX_S` after the restart or the last re-send reaching back)."""
        self.down_since: set[str] = set()
        """Trains that, after a restart, have not caught up yet: their samples after the last
        journaled one and before the live stream were missed while down (one catch-up each)."""
        if ck_dir:
            for t in self.ids:
                j = self.journals[t] = Journal(Path(ck_dir) / f"brake_{t}.jsonl")
                entries, whole = unpacked_entries(j.entries)
                if not whole:  # a damaged packed line: read up to it, like a torn line
                    self.get_logger().error(f"{t}: journal read up to a damaged line")
                    j.reset(entries)
                j.entries = entries
                if j.entries:
                    self._replay(t, j.entries)
                    self.get_logger().warning(f"restarted: replayed {len(j.entries)} journaled "
                                              f"samples of {t}")
            if any(j.entries for j in self.journals.values()):
                # a restart: every train catches up once, also one that had sent nothing
                # before the kill (empty journal: its whole re-send was missed)
                self.down_since = set(self.ids)
                self.held = {t: w.t_last for t, w in self.watch.items()
                             if math.isfinite(w.t_last)}
                self._held_until = time.monotonic() + HOLD_MAX_S
        # one FleetBrakeSensorData per lockstep step with samples (all trains); no QoS-event
        # waitables (see common.bulk_subscription)
        self.index = {t: i for i, t in enumerate(self.ids)}
        self.fast_subs = [self.create_subscription(
            FleetBrakeSensorData, FLEET_SENSOR_TOPIC, self._on_batch, QOS_FLEET_SENSOR,
            event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))]
        self.get_logger().info(
            f"watching {len(self.ids)} trains of scenario '{scn.name}' "
            f"({scn.line.adhesion} rail, {scn.sensors.rate_hz:g} Hz samples)")

    # ------------------------------------------------------------------ logging
    def _log_bounded(self, train_id: str, kind: str, text: str) -> None:
        """Warn at most once per ``log_period_s`` per (train, kind); count the rest."""
        now = time.monotonic()
        last, suppressed = self._logged.get((train_id, kind), (-math.inf, 0))
        if now - last >= self.log_period_s:
            more = f" ({suppressed} more suppressed)" if suppressed else ""
            self.get_logger().warning(f"{text}{more}")
            self._logged[(train_id, kind)] = (now, 0)
        else:
            self._logged[(train_id, kind)] = (last, suppressed + 1)

    # ------------------------------------------------------------------ restart
    def _replay(self, train_id: str, entries: list[dict[str, Any]]) -> None:
        """A fresh observer of ``train_id`` fed with journaled samples (no publication)."""
        w = self.watch[train_id] = TrainBrakeWatch(train_id, self.setup)
        self._gen[train_id] = self._gen.get(train_id, 0) + 1
        for e in entries:
            if "rejected" in e:
                w.reject()
            else:
                try:
                    w.feed(_sample_of(e))
                except (KeyError, TypeError, ValueError) as exc:
                    self.get_logger().error(f"{train_id}: journal entry not replayed: {exc}")
        self._levels[train_id] = -1  # publish the diagnosis again at the next sample

    def _is_newest(self, train_id: str, s: dict[str, Any]) -> bool:
        """``s`` is the newest sample the observer had, sent again (same stamp, channels)."""
        j = self.journals.get(train_id)
        if j is None or not j.entries or s["t_s"] != self.watch[train_id].t_last:
            return False
        return json.dumps(j.entries[-1], sort_keys=True) == \
            json.dumps(_sample_entry(s), sort_keys=True)

    def _rewind(self, train_id: str, s: dict[str, Any]) -> bool:
        """A sample behind the stream that the journal holds: the simulator resumed.

        Rebuild the train's observer from the journal up to that sample; True when done.
        """
        j = self.journals.get(train_id)
        if j is None or not s["t_s"] <= self.watch[train_id].t_last:
            return False
        key = _sample_entry(s)
        text = json.dumps(key, sort_keys=True)
        cut = -1
        for n in range(len(j.entries) - 1, -1, -1):
            if j.entries[n].get("t_s") == key["t_s"] \
                    and json.dumps(j.entries[n], sort_keys=True) == text:
                cut = n  # a sample the observer had: rebuild up to it
                break
        if cut < 0 and train_id in self.down_since:
            # the first re-sent sample after a restart that the journal lacks: published
            # while this node was down, or lost on the best-effort topic before the kill
            # (the journal holds only what was received).  Either way the observer never
            # had it: rebuild up to the first later entry, then take the re-sent stream
            cut = next((n for n, e in enumerate(j.entries)
                        if "t_s" in e and e["t_s"] > key["t_s"]), len(j.entries))
        if cut < 0:
            return False
        self.down_since.discard(train_id)  # one catch-up per restart
        self._replay(train_id, j.entries[:cut])
        j.entries = j.entries[:cut]
        self._unwritten.pop(train_id, None)  # written by the reset if before the cut
        j.reset(j.entries)
        self.get_logger().warning(f"{train_id}: samples from t={s['t_s']:.3f} s again (a "
                                  "resumed simulator or a re-send): observer rebuilt from the "
                                  "journal")
        return True

    def _journal(self, train_id: str, entry: dict[str, Any], row: bytes = b"") -> None:
        """Keep ``entry`` in the train's journal (written to the file by :meth:`flush`).

        ``row``: the sample's values packed (the decoder's ``rows``), written instead of
        the entry's JSON.
        """
        j = self.journals.get(train_id)
        if j is not None:
            j.entries.append(entry)
            self._unwritten.setdefault(train_id, []).append(row or entry)

    def flush(self) -> None:
        """Write the journal entries of the samples handled since the last call.

        Called after each burst of samples (one wait of the sample loop), before every
        BrakeDiagnosis (the acknowledgement), by the /diagnostics tick and at shutdown: one
        write per journal and burst instead of one per sample.  A kill between a sample and
        its write loses it from the journal like a sample lost before the kill (see
        :meth:`_rewind`).
        """
        if not self._unwritten:
            return
        pending, self._unwritten = self._unwritten, {}
        for train_id, entries in pending.items():
            self.journals[train_id].append_all(_journal_lines(entries), _line_json)

    # ------------------------------------------------------------------ samples
    def _on_batch(self, msg: FleetBrakeSensorData) -> None:
        """Validate a batch of samples (one lockstep step, every train) and run the observers.

        Each train's samples are handled in their order in the batch (stamp order); a
        message that cannot be attributed sample by sample is one rejection (kind
        ``length``), a sample of an unknown train one of kind ``train_id``.
        """
        rows: list[bytes] = []  # each sample's values packed, for the journal
        try:
            items = fleet_sensors.samples(msg, FLEET_SENSOR_TOPIC, self.index, N_AXLES,
                                          self.bounds, lists=True, rows=rows)
        except conv.MessageRejected as exc:
            self.rejections.add(exc.kind)
            self._log_bounded("", exc.kind, f"skipped sample batch ({exc.kind}): {exc}")
            return
        except Exception as exc:  # noqa: BLE001 - no callback may raise out of the node
            self.rejections.add("error")
            self._log_bounded("", "error", f"skipped sample batch: {type(exc).__name__}: {exc}")
            return
        recv, watch, levels, held = self._recv_t, self.watch, self._levels, self.held
        if len(rows) != len(items):
            rows = [b""] * len(items)  # (never: then each sample a JSON line)
        for (train_id, stamp, s), row in zip(items, rows):
            if train_id is None:
                assert isinstance(s, conv.MessageRejected)
                self.rejections.add(s.kind)
                self._log_bounded("", s.kind, f"skipped sample ({s.kind}): {s}")
                continue
            if s.__class__ is not dict:
                # a rejected sample changes nothing but its counters: not acknowledged (a
                # stamp beyond the run would be every later acknowledgement's), not journaled
                # as a sample, not seen by the observer
                self._on_sample(train_id, s, row)
                continue
            if stamp > recv[train_id]:
                recv[train_id] = stamp
            if held and stamp <= held.get(train_id, -math.inf) + 1e-9:
                # the re-send reached back to the journal: acknowledged as far as taken
                del held[train_id]
                self.catching_up.add(train_id)
                self._held_until = time.monotonic() + HOLD_MAX_S
            # a slow or standing train's sample after the last one (most samples):
            # what _on_sample does with it (neither a re-send nor behind the stream:
            # nothing to rewind), without the observer's sample handling
            w = watch[train_id]
            if w.feed_paused(s["t_s"], s["ref_speed"], s["car_mass"]):
                self._sample_count += 1
                self._journal(train_id, s, row)
                if w.level() != levels[train_id]:
                    self._publish_train(train_id, s["t_s"])
                continue
            self._on_sample(train_id, s, row)
        if self._level_changed:
            # a new level goes to /diagnostics at once, not at the next wall-clock tick (a
            # fast run's last tick can come before it; diagnostic_updater's force_update)
            self._level_changed = False
            self.rt.publish()

    def _on_sample(self, train_id: str, s: dict[str, Any] | conv.MessageRejected,
                   row: bytes = b"") -> None:
        """Run the observer on one validated sample (or count its rejection).

        ``row``: the sample's values packed for the journal (see :meth:`_journal`).
        """
        topic = FLEET_SENSOR_TOPIC
        self._sample_count += 1
        try:
            if isinstance(s, conv.MessageRejected):
                raise s
            if self._is_newest(train_id, s):
                return  # nothing new (a re-send of what the topic may have lost)
            self._rewind(train_id, s)
            w = self.watch[train_id]
            self._journal(train_id, s, row)  # float lists: its own journal entry
            resyncs = w.resyncs
            what = conv.guarded(topic, w.feed, s)
            if w.resyncs != resyncs:
                # the stream was followed again behind a future-stamped sample: that stamp
                # is no longer what this train's acknowledgement covers
                self._recv_t[train_id] = w.t_last
        except conv.MessageRejected as exc:
            w = self.watch[train_id]
            w.reject()
            self._journal(train_id, {"rejected": exc.kind})
            self.rejections.add(exc.kind)
            self._log_bounded(train_id, exc.kind, f"skipped sample of {train_id} "
                              f"({exc.kind}): {exc}")
            return
        if what == "out_of_order":
            self.rejections.add(what)
            self._log_bounded(train_id, what,
                              f"skipped sample: {topic}: stamp {s['t_s']:.3f} s is not after "
                              f"{w.t_last:.3f} s (out of order)")
            return
        if what in ("degraded", "waiting"):
            bad = [k for k, v in (("wheel_angular_speed_radps", s["omega"]),
                                  ("clamp_force_n", s["clamp"]),
                                  ("longitudinal_acceleration_mps2", s["accel"]),
                                  ("reference_speed_mps", s["ref_speed"]))
                   if not np.isfinite(v).all()]
            action = ("predict only / partial update" if what == "degraded"
                      else "no speed channel, observer waits")
            self._log_bounded(train_id, "nan",
                              f"{topic}: non-finite {', '.join(bad)} at t={s['t_s']:.3f} s "
                              f"(dropout): {action}")
        if w.level() != self._levels[train_id]:
            self._publish_train(train_id, s["t_s"])

    # ------------------------------------------------------------------ outputs
    def _publish_train(self, train_id: str, stamp_s: float) -> tuple[int, str]:
        """Publish the train's BrakeDiagnosis; return its (level, message).

        The journals are written first: the simulator takes the stamp as the acknowledgement
        of every sample up to it and sends none of them again to a restarted node.
        """
        self.flush()
        w = self.watch[train_id]
        level, text = w.level_message()
        if level != self._levels[train_id] and self._levels[train_id] >= 0:
            self._level_changed = True
            line = (f"{train_id}: {LEVEL_NAMES[self._levels[train_id]]} -> "
                    f"{LEVEL_NAMES[level]} at t={stamp_s:.2f} s: {text}")
            if level == 2:  # rclpy: one severity per logging call site
                self.get_logger().error(line)
            else:
                self.get_logger().info(line)
        self._levels[train_id] = level
        self._pub_stamp[train_id] = stamp_s
        self._pub_key[train_id] = (self._gen[train_id], w.counts["received"], stamp_s, level)
        c = w.counts
        msg = conv.diagnosis_msg(train_id, stamp_s, w.result, level, text,
                                 c["used"] + c["degraded"], c["rejected"] + c["waiting"])
        msg.assessed = w.assessed  # (cumulative: the simulator's kpis.json takes the last)
        self.pubs[train_id].publish(msg)
        return level, text

    def _status(self, train_id: str, level: int, text: str) -> DiagnosticStatus:
        """The /diagnostics status of one train."""
        w = self.watch[train_id]
        r = w.result
        c = w.counts
        st = DiagnosticStatus(level=bytes([level]), name=f"brake_diagnostic: {train_id}",
                              message=text, hardware_id=f"{train_id}/car_1")
        kvs = self._kv[train_id]
        kv = [("mu_b", f"{r.mu_b:.4f}"), ("mu_b_std", f"{r.mu_b_std:.4f}"),
              ("pad_flaw", str(bool(r.pad_flaw))),
              ("axle_flaw", ",".join(str(bool(x)) for x in r.wheel_flaw)),
              ("flaw_time_s", "" if w.flaw_time is None else f"{w.flaw_time:.2f}"),
              ("mu_b_last_judged", f"{w.last_judged[0]:.4f}"),
              ("mu_b_last_judged_std", f"{w.last_judged[1]:.4f}"),
              ("mu_b_last_judged_t_s", f"{w.last_judged[2]:.2f}"),
              ("speed_mps", f"{r.speed:.2f}"), ("observer", w.state)]
        kv += [(f"residual_axle{j + 1}", f"{r.residuals[j]:.4f}") for j in range(N_AXLES)]
        kv += [(f"force_axle{j + 1}_n", f"{r.forces[j]:.1f}") for j in range(N_AXLES)]
        kv += [(f"samples_{k}", str(v)) for k, v in c.items()]
        if w.update_s > 0.0:
            kv.append(("observer_updates_per_s", f"{w.updates / w.update_s:.0f}"))
        out = []
        for k, v in kv:  # a KeyValue per key and train, its value set (cheaper than new)
            e = kvs.get(k)
            if e is None:
                e = kvs[k] = KeyValue(key=k)
            e.value = v
            out.append(e)
        st.values = out
        return st

    def _train_stamp(self, train_id: str) -> float:
        """The train's newest sample, received or replayed [s] (simulated time; 0: none).

        What its BrakeDiagnosis acknowledges; after a restart, its newest journaled sample
        while :attr:`held`, then the observer's newest while :attr:`catching_up`.
        """
        if self.held or self.catching_up:
            if time.monotonic() >= self._held_until:
                self.held.clear()
                self.catching_up.clear()
            elif train_id in self.held:
                return self.held[train_id]
            elif train_id in self.catching_up:
                taken = self.watch[train_id].t_last
                if taken < self._recv_t[train_id] - 1e-9:
                    return taken if math.isfinite(taken) else 0.0
                self.catching_up.discard(train_id)
        t = max(self.watch[train_id].t_last, self._recv_t[train_id])
        return t if math.isfinite(t) else 0.0

    def acknowledge_pending(self) -> bool:
        """:meth:`_acknowledge` if a sample came since the last acknowledgement; True if so."""
        if self._acked_count == self._sample_count:
            return False
        self._acknowledge()
        return True

    def _acknowledge(self) -> None:
        """Publish the BrakeDiagnosis of every train with a sample newer than its last one."""
        self._acked_count = self._sample_count
        for t in self.ids:
            stamp = self._train_stamp(t)
            if stamp != self._pub_stamp[t]:
                self._publish_train(t, stamp)

    def last_sample_t(self) -> float:
        """Stamp of the newest sample of any train [s] (simulated time), 0 before any."""
        last = max((w.t_last for w in self.watch.values()), default=-math.inf)
        return last if math.isfinite(last) else 0.0

    def health(self) -> list[DiagnosticStatus]:
        """/diagnostics: one status per train (and its BrakeDiagnosis, published now if new).

        Each BrakeDiagnosis is stamped with its train's newest sample; one that would say
        what the train's last one said (same watch, samples received, stamp and level: the
        latched message is still there) is not published again, and a status is rebuilt
        only when its train's diagnosis changed (thirty trains' messages every
        tick cost more than the samples between ticks).
        """
        self.flush()
        out = []
        for t in self.ids:
            w = self.watch[t]
            stamp = self._train_stamp(t)
            key = (self._gen[t], w.counts["received"], stamp, w.level())
            if self._pub_key.get(t) == key and self._levels[t] == key[3]:
                level, text = w.level_message()
            else:
                level, text = self._publish_train(t, stamp)
            cached = self._status_cache.get(t)
            skey = (self._gen[t], w.counts["received"], level, text)
            if cached is None or cached[0] != skey:
                cached = self._status_cache[t] = (skey, self._status(t, level, text))
            out.append(cached[1])
        return out

    def observer_rate(self) -> tuple[int, float]:
        """Total observer updates and their rate [updates per CPU second in the filter]."""
        n = sum(w.updates for w in self.watch.values())
        s = sum(w.update_s for w in self.watch.values())
        return n, (n / s if s > 0.0 else 0.0)

    def summary(self) -> list[str]:
        """Shutdown lines: the observer rate, the trains assessed, one line per train.

        A train's line: verdict, assessed or not, mu_b judged, longest gap, counters.
        """
        n, rate = self.observer_rate()
        lost = [t for t in self.ids if not self.watch[t].assessed]
        out = [f"observer: {n} updates, {rate:.0f} updates per CPU second",
               f"brake assessed on {len(self.ids) - len(lost)} of {len(self.ids)} trains"
               + (f"; not assessed: {', '.join(lost)}" if lost else "")]
        for t in self.ids:
            w = self.watch[t]
            lo, hi = w.mu_b_range
            rng = (f"mu_b_hat judged: median {np.median(w.judged):.3f} of {len(w.judged)}, "
                   f"range [{lo:.3f}, {hi:.3f}]" if w.judged else "mu_b not judged")
            flaw = f", flaw at t={w.flaw_time:.2f} s" if w.flaw_time is not None else ""
            gap = f"longest gap {w.max_gap[0]:.2f} s at t={w.max_gap[1]:.2f} s"
            judged = (f"brake assessed ({w.braked_updates} braked updates at speed)"
                      if w.assessed else "brake not assessed (no friction-brake update at "
                      "speed, mu_b never judged: the level says nothing about the pads)")
            out.append(f"{t}: {LEVEL_NAMES[max(self._levels[t], 0)]}{flaw}; {judged}; {rng}; "
                       f"{gap}; " +
                       ", ".join(f"{k} {v}" for k, v in w.counts.items()))
        return out

    def close(self) -> None:
        """Write the journals; log :meth:`summary` (stderr if the context is shut down)."""
        self.flush()
        for line in self.summary():
            if self.context.ok():
                self.get_logger().info(line)
            else:
                print(f"[brake_diagnostic] {line}", file=sys.stderr, flush=True)


def _sample_entry(s: dict[str, Any]) -> dict[str, Any]:
    """A validated sample as a journal entry (arrays as lists of floats).

    Equal to its own JSON round trip (what :meth:`Journal.entries` holds after a restart):
    the channels are Python floats (NaN stays NaN), the arrays float lists.  The keys of
    :func:`metro_atc.nodes.conversions.sensor_from_msg` are built directly (a generic
    comprehension over the items was a visible share of the per-sample time).
    """
    if s.keys() == _SAMPLE_KEYS:
        return {"t_s": float(s["t_s"]), "omega": _floats(s["omega"]),
                "clamp": _floats(s["clamp"]), "accel": float(s["accel"]),
                "ref_speed": float(s["ref_speed"]), "car_mass": float(s["car_mass"])}
    return {k: (_floats(v) if isinstance(v, (np.ndarray, list))
                else float(v) if isinstance(v, (float, np.floating)) else v)
            for k, v in s.items()}


_SAMPLE_KEYS = {"t_s": 0, "omega": 0, "clamp": 0, "accel": 0, "ref_speed": 0,
                "car_mass": 0}.keys()
"""The keys of a validated sample (see :func:`_sample_entry`)."""


PACKED_KEY = "f64x12"
"""Key of a journal line holding a sample packed: the base64 text of its 12 float64,
little-endian (t_s, omega x4, clamp x4, accel, ref_speed, car_mass).  Exact (every bit of
every float, NaN included) and several times cheaper to write than the sample's JSON (a
float's ``repr`` is ~0.7 us).  Still one line per sample: the journal's text does
not depend on how samples were grouped into bursts (two runs leave the same journals).
Lines of the sample's JSON (what main wrote) are read too, and lines of several packed
samples."""
_PACKED_WIDTH = 4 + 2 * N_AXLES
"""Floats per packed sample."""
_PACKED_CHARS = 4 * _PACKED_WIDTH * 8 // 3
"""base64 characters of one packed sample (its 96 bytes: no padding, so the base64 of
several samples is theirs end to end)."""


def packed_entries(entries: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Journal lines of ``entries``, one each: a 4-axle sample entry of floats packed.

    Every other entry (a rejection, a sample of another axle count or with a value that is
    not a float: never from the decoder) is its JSON.  :func:`unpacked_entries` gives
    ``entries`` back (the sample values as Python floats, their arrays as float lists).
    """
    out: list[dict[str, Any]] = []
    for e in entries:
        if e.keys() == _SAMPLE_KEYS:
            om, cl = e["omega"], e["clamp"]
            if len(om) == N_AXLES and len(cl) == N_AXLES:
                row = (e["t_s"], *om, *cl, e["accel"], e["ref_speed"], e["car_mass"])
                if set(map(type, row)) == {float}:
                    data = struct.pack(f"<{_PACKED_WIDTH}d", *row)
                    out.append({PACKED_KEY: base64.b64encode(data).decode("ascii")})
                    continue
        out.append(e)
    return out


def _journal_lines(items: Sequence[dict[str, Any] | bytes]) -> list[dict[str, Any]]:
    """Journal lines, one per item: entries (dicts) and samples already packed (bytes).

    The packed ones are base64-encoded together and cut per sample.
    """
    out: list[dict[str, Any]] = []
    run: list[bytes] = []
    k = _PACKED_CHARS
    for it in [*items, {}]:
        if it.__class__ is bytes:
            run.append(it)  # type: ignore[arg-type]
            continue
        if run:
            text = base64.b64encode(b"".join(run)).decode("ascii")
            out += [{PACKED_KEY: text[i:i + k]} for i in range(0, len(text), k)]
            run = []
        if it:
            out += packed_entries([it])  # type: ignore[list-item]
    return out


def _line_json(e: dict[str, Any]) -> str:
    """``json.dumps(e)`` of a journal line (a packed sample's formatted directly)."""
    if len(e) == 1:
        text = e.get(PACKED_KEY)
        if text.__class__ is str:
            return '{"%s": "%s"}' % (PACKED_KEY, text)
    return json.dumps(e)


def unpacked_entries(entries: Sequence[dict[str, Any]]) -> tuple[list[dict[str, Any]], bool]:
    """The journal entries of journal lines (:func:`packed_entries` undone).

    Returns (entries, whole): ``whole`` is False when a packed line is damaged (not base64
    of whole samples); the entries then end before it.
    """
    out: list[dict[str, Any]] = []
    n = _PACKED_WIDTH
    for e in entries:
        text = e.get(PACKED_KEY) if len(e) == 1 else None
        if text is None:
            out.append(e)
            continue
        try:
            if not isinstance(text, str):
                raise ValueError("not a string")
            raw = base64.b64decode(text, validate=True)
            if not raw or len(raw) % (8 * n):
                raise ValueError("not whole samples")
        except ValueError:  # binascii.Error too
            return out, False
        k = N_AXLES
        out.extend({"t_s": r[0], "omega": r[1:1 + k], "clamp": r[1 + k:1 + 2 * k],
                    "accel": r[n - 3], "ref_speed": r[n - 2], "car_mass": r[n - 1]}
                   for r in np.frombuffer(raw, dtype="<f8").reshape(-1, n).tolist())
    return out, True


def _floats(v: Any) -> list[float]:
    """A float list of an array or list."""
    if isinstance(v, np.ndarray) and v.dtype == np.float64:
        return v.tolist()  # type: ignore[no-any-return]
    return np.asarray(v, dtype=float).tolist()  # type: ignore[no-any-return]


def _sample_of(e: dict[str, Any]) -> dict[str, Any]:
    """The sample dict of a journal entry (the arrays back as float arrays)."""
    return {k: (np.asarray(v, dtype=float) if isinstance(v, list) else v)
            for k, v in e.items()}


def build_nodes(args: Optional[Sequence[str]] = None) -> list[Node]:
    """The node list of the executable."""
    return [BrakeDiagnostic()]


def sample_loop(executor: SingleThreadedExecutor, nodes: Sequence[Node]) -> None:
    """Serve the sensor topics with a direct wait set, the rest every ``SLOW_PERIOD_S``.

    Like :func:`metro_atc.nodes.common.spin_fast`, with the journals written after each
    burst of samples (:meth:`BrakeDiagnostic.flush`).
    """
    diag = [n for n in nodes if isinstance(n, BrakeDiagnostic)]
    ctx = nodes[0].context if nodes else executor.context
    poller = SubscriptionPoller(ctx, [s for n in diag for s in n.fast_subs])
    last_slow = 0.0
    idle_s = POLL_S
    last_idle_ack = -math.inf
    while ctx.ok() and not stop_requested():
        got = poller.poll(idle_s)
        for n in diag:
            n.flush()
        if got:
            idle_s = IDLE_ACK_S  # samples came: acknowledge once the stream pauses
        elif idle_s == IDLE_ACK_S and time.monotonic() - last_idle_ack >= IDLE_ACK_GAP_S:
            # (within IDLE_ACK_GAP_S of the last one: polled again, acknowledged after it)
            idle_s = POLL_S
            last_idle_ack = time.monotonic()
            for n in diag:
                n.acknowledge_pending()
        now = time.monotonic()
        if now - last_slow >= SLOW_PERIOD_S:
            last_slow = now
            executor.spin_once(timeout_sec=0.0)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``brake_diagnostic`` executable (sensor topics on the fast path)."""
    factory: Callable[[], Sequence[Node]] = build_nodes
    return run_nodes(factory, sample_loop, args)


if __name__ == "__main__":
    raise SystemExit(main())
