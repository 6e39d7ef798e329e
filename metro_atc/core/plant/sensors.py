"""Brake-by-wire sensors of the instrumented cars: samples with noise and sensor faults.

Each step stores the noise-free truth it needs (:class:`SensorSnap`); the samples (wheel
speeds, clamp forces, acceleration, reference speed, load weigh) are generated on first
access of :attr:`StepResult.sensors` / :attr:`StepResult.sensor_arrays`, from a separate
random stream, so reading them or not never changes the plant trajectory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.scenario import Scenario

from .braking import AxleState
from .stations import TrainEvent

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

NORMAL_BLOCK = 16384
"""Standard normals drawn ahead at a time for the sensor noise (:meth:`Sensors.normals`)."""
CLOCK_BLOCK = 4096
"""Sample instants laid out ahead at a time by the sample clock (:meth:`Sensors.sample_times`)."""


@dataclass(frozen=True)
class BrakeSensorSample:
    """One brake-by-wire sensor sample of a train's instrumented car (NaN = dropout)."""

    train_idx: int
    t_s: float
    wheel_omega_radps: tuple[float, float, float, float]
    clamp_force_n: tuple[float, float, float, float]
    accel_x_mps2: float
    ref_speed_mps: float
    car_mass_kg: float = math.nan
    """Load-weigh signal of the instrumented car: train mass / cars [kg]."""


@dataclass
class SensorBlock:
    """Vectorised sensor samples of one step (converted to objects on demand)."""

    t: FloatArray
    trains: IntArray
    omega: FloatArray  # [n_samples, n_trains_sensed, 4]
    clamp: FloatArray
    accel: FloatArray  # [n_samples, n_trains_sensed]
    vref: FloatArray
    car_mass: FloatArray  # [n_trains_sensed] load-weigh signal [kg]


@dataclass(slots=True)
class SensorSnap:
    """Noise-free truth of one step for the sensor samples (built lazily)."""

    ts: FloatArray
    t0: float
    t1: float
    mask: BoolArray
    idx: IntArray
    ax0: AxleState
    ax1: AxleState
    r_w: FloatArray
    acc: FloatArray
    v0: FloatArray
    v1: FloatArray
    car_mass: FloatArray
    pre: Any = None
    """Samples computed with the step by the compiled kernel (:mod:`.fast`), or None."""


class Sensors:
    """Sample clock, instrumented trains and sensor faults of a line."""

    checkpoint_transient = ("clock", "clock_l", "cpos")
    """A cache: the sample instants ahead, laid out again from ``next_sample_t``."""
    clock: FloatArray = np.zeros(0)
    clock_l: list[float] = []
    cpos = 0

    def __init__(self, scn: Scenario, seed: int, faults: list[dict[str, Any]]) -> None:
        """Instrumented trains of ``scn`` (all if none listed); own random stream."""
        tid = {t: i for i, t in enumerate(scn.train_ids)}
        ids = scn.sensors.trains or scn.train_ids
        self.spec = scn.sensors
        self.sensed = np.array(sorted(tid[t] for t in ids), dtype=np.int64)
        self.sensed_mask = np.zeros(scn.trains.count, dtype=bool)
        self.sensed_mask[self.sensed] = True
        self.sensor_dt = 1.0 / scn.sensors.rate_hz
        self.next_sample_t = self.sensor_dt
        self.clock = np.zeros(0)  # sample instants ahead, clock[cpos] == next_sample_t
        self.clock_l = []  # the same as a list
        self.cpos = 0
        self.rng = np.random.default_rng([seed, 1])
        self.zbuf = np.zeros(0)
        self.zpos = 0
        self.want = False
        self.pre: Any = None  # this step's samples from the compiled step (see SensorSnap)
        self.faults = faults
        self.any_sensed = False
        self.mask = np.zeros(scn.trains.count, dtype=bool)
        self.idx = np.zeros(0, dtype=np.int64)

    def set_running(self, run: BoolArray) -> None:
        """Instrumented trains in service (after every discrete change of the fleet)."""
        self.mask = run & self.sensed_mask
        self.idx = self.mask.nonzero()[0]
        self.any_sensed = self.idx.size > 0

    def due(self, t1: float) -> bool:
        """A sample falls in the step ending at ``t1`` and an instrumented train runs."""
        return self.next_sample_t <= t1 + 1e-9 and self.any_sensed

    def normals(self, k: int) -> FloatArray:
        """The next ``k`` standard normals of the sensor stream.

        Drawn ahead in blocks of :data:`NORMAL_BLOCK` (``zbuf``, read from ``zpos``): a
        ``Generator``'s standard normals do not depend on how the draws are split, so the
        values are those of one ``rng.standard_normal(k)`` call per step (checkpoints keep
        the buffer and its position with the generator).
        """
        pos = self.zpos
        if pos + k > self.zbuf.size:
            self.zbuf = np.concatenate((self.zbuf[pos:],
                                        self.rng.standard_normal(max(NORMAL_BLOCK, k))))
            pos = 0
        self.zpos = pos + k
        return self.zbuf[pos:pos + k]

    def sample_times(self, t1: float) -> FloatArray:
        """Sample instants up to ``t1`` [s] (advances the sample clock).

        The instants are those of the loop ``nxt += sensor_dt`` from ``next_sample_t``,
        laid out :data:`CLOCK_BLOCK` at a time (``np.add.accumulate`` adds in that same
        order, so the values are identical); setting ``next_sample_t`` restarts the layout.
        """
        lim = t1 + 1e-9
        cl, pos = self.clock_l, self.cpos
        last = len(cl) - 1
        if pos >= last or cl[pos] != self.next_sample_t:
            self.clock_ready()
            cl, pos, last = self.clock_l, 0, CLOCK_BLOCK - 1
        end = pos
        while cl[end] <= lim:
            end += 1
            if end == last:  # a step longer than the layout: lay out more
                self.cpos, self.next_sample_t = last, cl[last]
                return np.concatenate((self.clock[pos:last], self.sample_times(t1)))
        self.cpos, self.next_sample_t = end, cl[end]
        return self.clock[pos:end]

    def clock_ready(self) -> None:
        """Lay the instants out again from ``next_sample_t`` when :meth:`sample_times` would.

        ``clock[cpos]`` is then ``next_sample_t`` (nothing is advanced).
        """
        cl, pos = self.clock_l, self.cpos
        if pos >= len(cl) - 1 or cl[pos] != self.next_sample_t:
            seq = np.full(CLOCK_BLOCK, self.sensor_dt)
            seq[0] = self.next_sample_t
            self.clock = np.add.accumulate(seq)
            self.clock_l = self.clock.tolist()  # Python floats: cheap to compare
            self.cpos = 0

    def reserve(self, k: int) -> None:
        """Make the next ``k`` normals available in ``zbuf`` from ``zpos`` (draws ahead)."""
        if self.zpos + k > self.zbuf.size:
            self.normals(k)
            self.zpos -= k

    def snapshot(self, ts: FloatArray, t0: float, t1: float, ax0: AxleState, ax1: AxleState,
                 r_w: FloatArray, acc: FloatArray, v0: FloatArray, v1: FloatArray,
                 car_mass: FloatArray) -> SensorSnap:
        """Noise-free truth for the samples at ``ts`` in (t0, t1] (samples built on demand).

        ``ts``: :meth:`sample_times` of the step.
        """
        pre, self.pre = self.pre, None
        # r_w and the speeds are never changed in place (faults and set_xv copy on write)
        return SensorSnap(ts, t0, t1, self.mask, self.idx, ax0, ax1, r_w, acc, v0, v1,
                          car_mass, pre)

    def block(self, sn: SensorSnap) -> SensorBlock:
        """Samples with noise and injected sensor faults from a snapshot.

        Assembled by the compiled :func:`.kernel_aux.sensor_block`
        (:class:`metro_atc.core.plant.fast.FastSensors`, the plant's sensors).
        """
        raise NotImplementedError("the plant's sensors are FastSensors")

    def apply_faults(self, tt: FloatArray, idx: IntArray, omega: FloatArray,
                     clamp: FloatArray, accel: FloatArray, vref: FloatArray) -> None:
        """Dropout (NaN) or stuck (value frozen at the fault onset) channels, in place."""
        pos = {int(tr): c for c, tr in enumerate(idx)}
        chans = {"wheel_omega": omega, "clamp_force": clamp, "accel": accel, "ref_speed": vref}
        for f in self.faults:
            c = pos.get(f["train"])
            if c is None:
                continue
            act = (tt >= f["t0"]) & (tt < f["t1"])
            if not act.any():
                continue
            names = list(chans) if f["channel"] == "all" else [f["channel"]]
            for name in names:
                arr = chans[name]
                if f["kind"] == "sensor_dropout":
                    val: Any = math.nan
                else:
                    if f.get("stuck_" + name) is None:  # first faulty sample seen
                        first = int(np.flatnonzero(act)[0])
                        f["stuck_" + name] = arr[first, c].copy()
                    val = f["stuck_" + name]
                if arr.ndim == 3:
                    for a in f["axles"]:
                        arr[act, c, a] = val if np.ndim(val) == 0 else val[a]
                else:
                    arr[act, c] = val


class StepResult:
    """Outcome of one :meth:`LineSim.step` (events, sensor samples, ATP interventions).

    Sensor samples are generated (noise, faults) on first access of :attr:`sensors` or
    :attr:`sensor_arrays`, from a separate random stream, so reading them or not never
    changes the plant trajectory.
    """

    def __init__(self, events: list[TrainEvent], snap: SensorSnap | None,
                 atp_interventions: int, sensors: Sensors) -> None:
        """Wrap the step outputs; sensor samples are built lazily on first access."""
        self.events = events
        self.atp_interventions = atp_interventions
        self._snap = snap
        self._source = sensors
        self._block: SensorBlock | None = None
        self._sensors: list[BrakeSensorSample] | None = None

    @property
    def sensor_arrays(self) -> SensorBlock | None:
        """Vectorised samples: t [s], trains, omega/clamp [s, train, 4], accel/vref [s, train]."""
        if self._block is None and self._snap is not None:
            self._block = self._source.block(self._snap)
            self._snap = None
        return self._block

    @property
    def sensors(self) -> list[BrakeSensorSample]:
        """Brake sensor samples taken during this step, in time order."""
        if self._sensors is None:
            out: list[BrakeSensorSample] = []
            b = self.sensor_arrays
            if b is not None:
                for s in range(b.t.size):
                    for ii, tr in enumerate(b.trains):
                        om = b.omega[s, ii]
                        cf = b.clamp[s, ii]
                        out.append(BrakeSensorSample(
                            int(tr), float(b.t[s]),
                            (float(om[0]), float(om[1]), float(om[2]), float(om[3])),
                            (float(cf[0]), float(cf[1]), float(cf[2]), float(cf[3])),
                            float(b.accel[s, ii]), float(b.vref[s, ii]),
                            float(b.car_mass[ii])))
            self._sensors = out
        return self._sensors
