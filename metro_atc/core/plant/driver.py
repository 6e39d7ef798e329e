"""Reference drivers for headless runs, tests and benchmarks (not the ATO of seed 001/002/004).

* :func:`simple_driver` -- flat-out (FOTP-like) with a service braking curve to the next
  stop point, the limit envelope and the movement authority; vectorised over trains.
* :func:`random_driver` / :func:`adversarial_driver` -- fuzzed commands for the ATP
  property test (they ignore every limit on purpose).

The drivers read the plant through :class:`PlantView` (fleet state, ATP view, geometry):
the ATP braking curve is the ATP's own (:attr:`AtpSupervisor.curve`).
"""

from __future__ import annotations

from typing import Protocol

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

    def active_mask(self) -> NDArray[np.bool_]:
        """Trains that must send a command this step."""
        ...


def driver_command(sim: PlantView, gain: float = 1.5, lookahead_s: float = 0.7) -> FloatArray:
    """Normalised command [-1, 1] per train: track min(envelopes) with a P controller.

    Reference speed = min of the service-brake envelope of (limit - 2 km/h), the braking
    curve ``sqrt(2 b (d - v t_la))`` to the next stop point and to the movement authority
    (b = 0.6 x max service brake), and the ATP service-intervention speed 2 s ahead minus
    1 m/s.  Close to a stop the feed-forward ``-(v^2 / 2 d) / b_max`` of the constant
    deceleration that stops exactly there is added.  Stopped short: creep at 30 % traction.
    """
    stepper = getattr(sim, "stepper", None)
    if stepper is not None:  # compiled twin (plant kernel numba)
        return np.asarray(stepper.driver(sim, gain, lookahead_s, False))
    fl, atp, g = sim.fleet, sim.atp, sim.geometry
    x, v = fl.x, fl.v
    la = v * lookahead_s
    kl = ((x + la - g.x0) * g.inv_dx).astype(np.int64)
    np.minimum(kl, g.n_cells - 1, out=kl)
    b2 = 2.0 * atp.b_drive
    d_stop = fl.stop_x - x
    d_ma = atp.eoa - x - 3.0
    d_eff = np.minimum(d_stop, d_ma)
    v_curve = np.sqrt(b2 * np.maximum(d_eff - la, 0.0))
    lead = v * (atp.t_sbi + 2.0)
    c0, c2 = atp.curve.coef(atp.a_w)  # worst case at standstill
    v_atp = atp.curve.speed_from(c0, c2, d_ma - lead, below_mps=1.0)
    v_ref = np.minimum(np.minimum(atp.drive_env[kl], v_curve),
                       np.minimum(v_atp, atp.sbi_static[kl] - 1.0))
    if atp.fixed_block:
        v_ref = np.minimum(v_ref, atp.speed_code - 0.5)
    err = gain * (v_ref - v)
    # programmed stopping: feed-forward of the constant deceleration that stops at the point
    near = d_eff < (0.65 / atp.b_drive) * v * v + 1.0
    ff = (v * v) / (-2.0 * sim.p.max_service_brake_mps2 * np.maximum(d_eff, 0.05))
    u = np.where(near, np.minimum(err, ff + err), err)
    # creep when stopped short of the stop point; hold once there
    tol = 0.5 * g.tol_stop
    u = np.where((v < 0.3) & (d_stop > tol) & (v_ref > 1.0), np.maximum(u, 0.3), u)
    u = np.where((d_stop <= tol) & (v < 0.5), -1.0, u)
    return np.minimum(np.maximum(u, -1.0), 1.0)


def simple_driver(sim: PlantView) -> FloatArray:
    """Safe reference driver for the whole fleet (commands for inactive trains are 0)."""
    stepper = getattr(sim, "stepper", None)
    if stepper is not None:
        return np.asarray(stepper.driver(sim, 1.5, 0.7, True))
    u = driver_command(sim)
    return np.asarray(np.where(sim.active_mask(), u, 0.0))


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
