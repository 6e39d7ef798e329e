"""The line_simulator's brake-sensor outbox: batches, kept samples, re-sends, end drain.

The plant's brake sensor samples of a step are taken (:meth:`SensorOutbox.take`: every
sample while the instrumented car brakes, else one per idle period), published as one
``FleetBrakeSensorData`` per batch period (:meth:`SensorOutbox.flush`) and on the per-train
topics that have a reader, and kept for a re-send: to a reader that is new (a restarted
``brake_diagnostic``, :meth:`SensorOutbox.resend_new_readers`), after an acknowledgement
that stands still (:meth:`SensorOutbox.resend_tail`), and until every diagnosis
acknowledged its last sample at the end of a run (:meth:`SensorOutbox.drain`).

Simulated times are seconds of the plant clock (``t_s`` arguments); wall times are
``time.monotonic`` seconds. The pure decisions (:func:`unacknowledged`,
:func:`sensor_keep_floor`) are ROS-free functions.
"""

from __future__ import annotations

import math
import time
from collections import deque
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np
from rclpy.node import Node
from rclpy.publisher import Publisher

from metro_atc.nodes import conversions as conv
from metro_atc.nodes.common import stop_requested, subscriber_gids
from metro_atc.nodes.wire import fleet_sensors

RESEND_BATCH = 64
"""Kept sensor samples re-sent per FleetBrakeSensorData (a pause after each)."""
RESEND_PAUSE_S = 0.005
"""Pause between re-sent batches [s] (wall): a reader catching up is not flooded beyond the
reliable writer's history of 1 000 batches."""
TAIL_RESEND_S = 3.0
"""End of a run: wall seconds a train's diagnosis must have kept acknowledging the same
sample (a live, idle reader: its periodic diagnosis came again with that stamp) while its
sensor readers stayed the same, before the samples after it are published again (the last
samples of a best-effort stream can be lost). A reader busy catching up publishes nothing;
a dead one neither."""


class SensorBatch(NamedTuple):
    """Brake sensor samples in stamp order.

    ``t`` [s], ``trains`` (train indices), ``omega`` [rad/s] and ``clamp`` [N] (samples x
    axles), ``accel`` [m/s^2], ``vref`` [m/s], ``mass`` [kg] per sample.
    """

    t: np.ndarray
    trains: np.ndarray
    omega: np.ndarray
    clamp: np.ndarray
    accel: np.ndarray
    vref: np.ndarray
    mass: np.ndarray


def unacknowledged(ack_t: np.ndarray, last_t: np.ndarray) -> np.ndarray:
    """Trains whose brake diagnosis has not acknowledged their newest sensor sample.

    ``ack_t``: the acknowledged stamp [s] (-inf: no diagnosis heard yet, not pending);
    ``last_t``: the newest sample's stamp [s].
    """
    return np.isfinite(ack_t) & (last_t > ack_t + 1e-6)


def sensor_keep_floor(now_s: float, resend_s: float, ack_t: np.ndarray,
                      last_t: np.ndarray) -> float:
    """Oldest stamp [s] of the brake sensor samples the simulator must still keep.

    At least the last ``resend_s`` (for a reader that is new), and back to the
    acknowledgement ``ack_t`` of every train whose newest sample ``last_t`` is not yet
    acknowledged (a restarted reader catches up on all it missed, however long it was down).
    A train whose samples are all acknowledged (one out of service included) holds nothing
    back; a train never acknowledged (``-inf``) only the ``resend_s`` window.
    """
    floor = now_s - resend_s
    pending = unacknowledged(ack_t, last_t)
    if pending.any():
        floor = min(floor, float(ack_t[pending].min()))
    return floor


class SensorOutbox:
    """The brake sensor samples of every train, from the plant to their readers.

    ``node``: the simulator (its logger and graph queries); ``ids``: the train ids;
    ``fleet_pub``: the ``/line/brake_sensors`` publisher; ``train_pubs``: the
    ``/<train>/brake_sensors`` publishers (in ``ids`` order); ``params``: an object with
    the node's ``sensor_idle_period_s``, ``sensor_batch_period_s``, ``sensor_resend_s`` [s
    simulated], ``sensor_keep_max`` [samples] and ``sensor_drain_timeout_s`` [s wall], read
    when used (the idle period is set at runtime); ``ids_block(idx)``: the serialized train
    id list of the indices ``idx``; ``warn(key, text)``: a rate-limited warning.
    """

    def __init__(self, node: Node, ids: Sequence[str], fleet_pub: Publisher,
                 train_pubs: Sequence[Publisher], params: Any,
                 ids_block: Callable[[np.ndarray], bytes],
                 warn: Callable[[str, str], None]) -> None:
        """Start empty: nothing kept, nothing acknowledged, no reader seen."""
        n = len(ids)
        self.node = node
        self.ids = list(ids)
        self.fleet_pub = fleet_pub
        """``/line/brake_sensors`` (one FleetBrakeSensorData per batch)."""
        self.train_pubs = list(train_pubs)
        """``/<train>/brake_sensors`` (best effort, only while read)."""
        self.params = params
        self._ids_block = ids_block
        self._warn = warn
        self.last_t = np.full(n, -np.inf)
        """Per train: the stamp of the newest sample taken [s] (in a checkpoint)."""
        self.log: deque[SensorBatch] = deque()
        """Recent brake sensor samples, batch by batch as published, for a restarted
        reader."""
        self._log_n = 0
        """Samples in :attr:`log`."""
        self._pending: list[SensorBatch] = []
        """Samples of the steps since the last fleet sensor message (not yet published)."""
        self._flush_t = -math.inf
        """Simulated time [s] from which the pending samples are published."""
        self._out = [conv.sensor_sample_msg(t, 0.0, [], [], math.nan, math.nan, math.nan)
                     for t in self.ids]
        """The BrakeSensorData of each train, refilled for every sample published."""
        self._readers: set[bytes] = set()
        """Endpoint GIDs of the fleet sensor topic's readers seen so far."""
        self._read = np.zeros(n, dtype=bool)
        """Trains whose ``/<train>/brake_sensors`` had a reader at the last check (only
        those are published: a topic nobody reads costs nothing)."""
        self._resend_due = np.zeros(n, dtype=bool)
        self._readers_known = False
        self.ack_t = np.full(n, -np.inf)
        self.assessed = [False] * n
        """Per train: its brake diagnosis said the brake was assessed (a braked update at
        speed, or mu_b judged)."""
        """Per train: the newest sensor sample its BrakeDiagnosis acknowledged [s] (-inf: no
        diagnosis heard). Samples after it are kept for a re-send however old."""
        self._ack_wall = np.full(n, -np.inf)
        """Wall time the acknowledgement of each train last changed, or its sensor topic
        gained a reader (monotonic) [s]."""
        self._ack_seen_wall = np.full(n, -np.inf)
        """Wall time a diagnosis of each train was last received (monotonic) [s]."""
        self.dropped = 0
        """Kept samples dropped beyond ``sensor_keep_max``."""

    def acknowledge(self, i: int, t_s: float, assessed: bool = False) -> None:
        """Train ``i``'s brake diagnosis acknowledged the sample of stamp ``t_s`` [s].

        ``assessed``: the diagnosis says the train's brake was assessed (kept per train in
        :attr:`assessed` for the KPIs; once assessed a brake stays assessed, so a resumed
        simulator keeps what its checkpoint holds whichever diagnosis reaches it next).
        """
        self.assessed[i] = self.assessed[i] or bool(assessed)
        now = time.monotonic()
        self._ack_seen_wall[i] = now
        if t_s != self.ack_t[i]:
            # the latest, not the largest: a restarted diagnosis acknowledges less
            self.ack_t[i] = t_s
            self._ack_wall[i] = now

    def take(self, block: Any) -> None:
        """Take the step's brake sensor samples (all while braking, else at the idle period).

        ``block``: the plant step's sensor arrays (``t`` [s], ``trains``, ``omega``
        [rad/s], ``clamp`` [N], ``accel`` [m/s^2], ``vref`` [m/s], ``car_mass`` [kg]) or
        None. The UKF learns the pad friction only while the clamp force is applied; between
        brake applications a sparse heartbeat keeps the diagnosis alive at a fraction of the
        message load (20 Hz x 30 trains would be ~600 messages per simulated second).  The
        samples wait for :meth:`flush` (``sensor_batch_period_s``).
        """
        if block is None:
            return
        # plain Python floats here: numpy scalar indexing per sample was most of the node's
        # time with ~10 samples per step at the peak
        t = np.asarray(block.t, dtype=float).tolist()
        clamp = np.asarray(block.clamp, dtype=np.float64)
        # braked: some axle clamp force well above the sensor noise (50 N scale)
        braking = np.nanmax(clamp, axis=2, initial=0.0) > 1000.0
        idle = float(self.params.sensor_idle_period_s)
        tr_all = np.asarray(block.trains, dtype=np.int64)
        last = self.last_t[tr_all]
        # the sample instants of the step in order, all trains at once: braking trains
        # every instant, the others once per idle period (the first instant due)
        take = np.empty(braking.shape, dtype=bool)
        for a, ts in enumerate(t):
            due = braking[a] | (idle <= 0.0) | (ts - last >= idle - 1e-9)
            take[a] = due
            last = np.where(due, ts, last)
        self.last_t[tr_all] = last
        aa, bb = np.nonzero(take)  # instant-major: the samples in stamp order
        if aa.size:
            self._pending.append(SensorBatch(
                np.asarray(block.t, dtype=float)[aa], tr_all[bb],
                np.asarray(block.omega, dtype=np.float64)[aa, bb], clamp[aa, bb],
                np.asarray(block.accel, dtype=float)[aa, bb],
                np.asarray(block.vref, dtype=float)[aa, bb],
                np.asarray(block.car_mass, dtype=float)[bb]))

    def flush(self, t_s: float, force: bool = False) -> None:
        """Publish the pending samples as one FleetBrakeSensorData when the batch is due.

        ``t_s``: the simulated time now [s]. Due once ``sensor_batch_period_s`` of simulated
        time passed since the last one, or ``force`` (a checkpoint: the samples of the steps
        before it are all out, a resumed simulator makes the later ones again; the end of
        the run).  The published samples are kept for a re-send; the kept ones older than
        :func:`sensor_keep_floor` dropped.
        """
        t = t_s
        if not force and t < self._flush_t:
            return
        p = self.params
        self._flush_t = t + float(p.sensor_batch_period_s) - 1e-9
        pend = self._pending
        if pend:
            self._pending = []
            batch = pend[0] if len(pend) == 1 else SensorBatch(
                *(np.concatenate(parts) for parts in zip(*pend)))
            self._send(t, batch, live=True)
        log = self.log
        floor = sensor_keep_floor(t, p.sensor_resend_s, self.ack_t, self.last_t)
        while log and log[0].t[-1] < floor:
            self._log_n -= log.popleft().t.size
        extra = self._log_n - int(p.sensor_keep_max)
        if extra > 0:
            self.dropped += extra
            self._log_n -= extra
            while extra > 0:
                first = log[0]
                if first.t.size <= extra:
                    extra -= log.popleft().t.size
                else:
                    log[0] = SensorBatch(*(a[extra:] for a in first))
                    extra = 0
            self._warn("sensor_keep_max", f"{self.dropped} kept brake "
                       f"sensor samples dropped (sensor_keep_max="
                       f"{p.sensor_keep_max}): a brake_diagnostic that is "
                       "down cannot catch up on them")

    def resend_new_readers(self, t_s: float, started: bool) -> int:
        """Send the kept samples of every train again when the fleet sensor topic gained a reader.

        A restarted ``brake_diagnostic`` misses what was published while it was down
        (volatile); it takes the samples it already has as the point to rebuild its
        observer from, then the ones it missed.  A reader is new when its endpoint GID was
        not seen before (a count can stay the same: the dead reader's lease expiring while
        the new one matches); the samples are sent at the next call (about 1 s later), once
        the new reader had time to match.  Also notes which ``/<train>/brake_sensors`` have
        a reader (only those are published).  ``t_s``: the simulated time now [s];
        ``started``: the lockstep has started (the readers before it are not new).  Returns
        the number of samples re-sent.
        """
        due = self._resend_due
        self._resend_due = np.zeros(len(self.ids), dtype=bool)
        gids = subscriber_gids(self.node, self.fleet_pub)
        if gids - self._readers and self._readers_known:
            self._resend_due[:] = True
            self._ack_wall[:] = time.monotonic()  # no tail re-send for a while
        self._readers |= gids
        self._read = np.array([p.get_subscription_count() > 0
                               for p in self.train_pubs], dtype=bool)
        self._readers_known = started  # the readers at step 0 are not new
        sent = self._publish_kept(t_s, due, np.full(len(self.ids), -np.inf))
        if sent:
            self.node.get_logger().info(f"sent {sent} kept brake sensor samples again to a "
                                        "new reader")
        return sent

    def _send(self, t_s: float, batch: SensorBatch, live: bool) -> None:
        """Publish samples (in order) as one FleetBrakeSensorData stamped ``t_s``; keep live ones.

        Live samples also go to the ``/<train>/brake_sensors`` that had a reader at the last
        check, and are kept for a re-send (``sensor_resend_s``).
        """
        trains = batch.trains
        names, which = np.unique(trains, return_inverse=True)
        n = trains.size
        omega = batch.omega.reshape(n, -1)
        self.fleet_pub.publish(fleet_sensors.encode(t_s, self._ids_block(
            names), (which, conv.stamps_ns(batch.t), np.full(n, omega.shape[1]), omega,
                     batch.clamp, batch.accel, batch.vref, batch.mass)))
        if not live:
            return
        read = self._read
        if read.any():
            for j in np.flatnonzero(read[trains]).tolist():
                i = int(trains[j])
                # one message object per train, refilled (publish copies it out at once)
                self.train_pubs[i].publish(conv.fill_sensor_msg(
                    self._out[i], float(batch.t[j]), omega[j], batch.clamp[j],
                    float(batch.accel[j]), float(batch.vref[j]), float(batch.mass[j])))
        if self.params.sensor_resend_s > 0.0:
            self.log.append(batch)
            self._log_n += n

    def _publish_kept(self, t_s: float, trains: np.ndarray, after_t: np.ndarray) -> int:
        """Publish again the kept samples of ``trains`` newer than ``after_t`` [s] (per train).

        In batches of :data:`RESEND_BATCH` samples on the fleet topic, paused in between.
        """
        if not trains.any():
            return 0
        parts = []
        for b in self.log:
            sel = trains[b.trains] & (b.t > after_t[b.trains])
            if sel.any():
                parts.append(SensorBatch(*(a[sel] for a in b)))
        if not parts:
            return 0
        picked = SensorBatch(*(np.concatenate(p) for p in zip(*parts)))
        total = picked.t.size
        for n in range(0, total, RESEND_BATCH):
            if n:
                time.sleep(RESEND_PAUSE_S)
            self._send(t_s, SensorBatch(*(a[n:n + RESEND_BATCH] for a in picked)), live=False)
        return total

    def unacknowledged(self) -> np.ndarray:
        """Trains whose brake diagnosis (once heard) has not acknowledged their last sample."""
        return unacknowledged(self.ack_t, self.last_t)

    def resend_tail(self, t_s: float, pending: np.ndarray) -> int:
        """Publish again the kept samples after each pending train's acknowledgement.

        Only for a train whose diagnosis kept acknowledging the same sample for
        :data:`TAIL_RESEND_S` (a live reader that has taken all it got) while its readers
        stayed the same (a new reader gets the whole re-send of :meth:`resend_new_readers`,
        and restarts ``_ack_wall``); they are samples the reader lost (a keep-last
        history of 1 000 batches overrun). ``t_s``: the simulated time now [s]. Returns the
        number of samples sent.
        """
        due = pending & (self._ack_seen_wall - self._ack_wall >= TAIL_RESEND_S) \
            & ~self._resend_due
        if due.any():
            self._ack_wall[due] = time.monotonic()  # once per TAIL_RESEND_S
        return self._publish_kept(t_s, due, self.ack_t + 1e-6)

    def drain(self, t_s: float, spin: Callable[[float], Any]) -> bool:
        """End of a run: wait until every train's brake diagnosis acknowledged its last sample.

        A ``brake_diagnostic`` killed near the end of a fast run comes back after the
        simulator finished: without this wait it would never get the samples it missed.
        Bounded by ``sensor_drain_timeout_s`` (wall); new readers get the kept samples
        (:meth:`resend_new_readers`), a train whose acknowledgement stands still gets the
        samples after it again (:meth:`resend_tail`). ``t_s``: the run's last simulated time
        [s]; ``spin(timeout_s)`` serves the subscriptions.  True when everything was
        acknowledged (or no diagnosis was ever heard).
        """
        log = self.node.get_logger()
        timeout_s = float(self.params.sensor_drain_timeout_s)
        t0 = time.monotonic()
        end = t0 + timeout_s
        next_check = t0 + 1.0
        while True:
            pending = self.unacknowledged()
            now = time.monotonic()
            if not pending.any():
                if now - t0 > 2.0:
                    log.info(f"every brake diagnosis acknowledged its last "
                             f"sensor sample after {now - t0:.1f} s")
                return True
            if now >= end or stop_requested():
                names = ", ".join(self.ids[i] for i in np.flatnonzero(pending))
                log.warning(
                    f"brake diagnosis of {names} did not acknowledge the last sensor samples "
                    f"within {timeout_s:g} s (brake_diagnostic down?)")
                return False
            spin(0.05)
            if now >= next_check:
                next_check = now + 1.0
                self.resend_new_readers(t_s, started=True)
                self.resend_tail(t_s, pending)
