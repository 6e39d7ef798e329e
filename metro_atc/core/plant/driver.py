"""Reference drivers for headless runs, tests and benchmarks (not the ATO of Ke 2010/002/004).

* :func:`simple_driver` -- flat-out (FOTP-like) with a service braking curve to the next
  stop point, the limit envelope and the movement authority; vectorised over trains.
* :func:`random_driver` / :func:`adversarial_driver` -- fuzzed commands for the ATP
  property test (they ignore every limit on purpose).

The drivers read the plant through :class:`PlantView` (fleet state, ATP view, geometry):
the ATP braking curve is the ATP's own (:attr:`AtpSupervisor.curve`).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.vehicle import TrainParams

from .atp import AtpSupervisor
from .fleet import Fleet

FloatArray = NDArray[np.float64]


class PlantView(Protocol):
    """What a driver sees of the plant (``LineSim`` provides it)."""

    n: int
    p: TrainParams
    fleet: Fleet
    atp: AtpSupervisor
    geometry: LineGeometry
    stepper: Any


def driver_command(sim: PlantView, gain: float = 1.5, lookahead_s: float = 0.7) -> FloatArray:
    """Normalised command [-1, 1] per train: track min(envelopes) with a P controller.

    Reference speed = min of the service-brake envelope of (limit - 2 km/h), the braking
    curve ``sqrt(2 b (d - v t_la))`` to the next stop point and to the movement authority
    (b = 0.6 x max service brake), and the ATP service-intervention speed 2 s ahead minus
    1 m/s.  Close to a stop the feed-forward ``-(v^2 / 2 d) / b_max`` of the constant
    deceleration that stops exactly there is added.  Stopped short: creep at 30 % traction.
    Computed by the compiled :func:`.kernel_step.driver` (curves of
    :mod:`metro_atc.core.laws`).
    """
    return np.asarray(sim.stepper.driver(sim, gain, lookahead_s, False))


def simple_driver(sim: PlantView) -> FloatArray:
    """Safe reference driver for the whole fleet (commands for inactive trains are 0)."""
    return np.asarray(sim.stepper.driver(sim, 1.5, 0.7, True))


def random_driver(sim: PlantView, rng: np.random.Generator) -> FloatArray:
    """Uniformly random commands in [-1, 1], NaN (keep last) and +-inf mixed in."""
    u = rng.uniform(-1.0, 1.0, sim.n)
    r = rng.random(sim.n)
    u = np.where(r < 0.05, np.nan, u)
    u = np.where((r >= 0.05) & (r < 0.07), np.inf, u)
    return u


def adversarial_driver(sim: PlantView, rng: np.random.Generator) -> FloatArray:
    """Worst-case fuzzing: full traction most of the time, brief random braking pulses."""
    u = np.ones(sim.n)
    pulse = rng.random(sim.n) < 0.03
    return np.asarray(np.where(pulse, -rng.random(sim.n), u))
