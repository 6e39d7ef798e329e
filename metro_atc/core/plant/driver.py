"""Reference drivers for headless runs, tests and benchmarks (not the ATO of seed 001/002/004).

* :func:`simple_driver` -- flat-out (FOTP-like) with a service braking curve to the next
  stop point, the limit envelope and the movement authority; vectorised over trains.
* :func:`random_driver` / :func:`adversarial_driver` -- fuzzed commands for the ATP
  property test (they ignore every limit on purpose).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # pragma: no cover
    from .line import LineSim

FloatArray = NDArray[np.float64]


def driver_command(sim: "LineSim", gain: float = 1.5, lookahead_s: float = 0.7) -> FloatArray:
    """Normalised command [-1, 1] per train: track min(envelopes) with a P controller.

    Reference speed = min of the service-brake envelope of (limit - 2 km/h), the braking
    curve ``sqrt(2 b (d - v t_la))`` to the next stop point and to the movement authority
    (b = 0.6 x max service brake), and the ATP service-intervention speed 2 s ahead minus
    1 m/s.  Close to a stop the feed-forward ``-(v^2 / 2 d) / b_max`` of the constant
    deceleration that stops exactly there is added.  Stopped short: creep at 30 % traction.
    """
    x, v = sim.x, sim.v
    inv_dx = sim.inv_dx
    la = v * lookahead_s
    kl = ((x + la - sim.x0) * inv_dx).astype(np.int64)
    np.minimum(kl, sim.n_cells - 1, out=kl)
    b2 = 2.0 * sim.b_drive
    d_stop = sim.stop_x - x
    d_ma = sim.eoa - x - 3.0
    d_eff = np.minimum(d_stop, d_ma)
    v_curve = np.sqrt(b2 * np.maximum(d_eff - la, 0.0))
    lead = v * (sim.t_sbi + 2.0)
    v_atp = np.sqrt(np.maximum(sim._c0 + sim._c1 * (d_ma - lead), 0.0)) - (sim._c2 + 1.0)
    v_ref = np.minimum(np.minimum(sim.drive_env[kl], v_curve),
                       np.minimum(v_atp, sim.sbi_static[kl] - 1.0))
    if sim.fixed_block:
        v_ref = np.minimum(v_ref, sim.speed_code - 0.5)
    err = gain * (v_ref - v)
    # programmed stopping: feed-forward of the constant deceleration that stops at the point
    near = d_eff < (0.65 / sim.b_drive) * v * v + 1.0
    ff = (v * v) / (-2.0 * sim.p.max_service_brake_mps2 * np.maximum(d_eff, 0.05))
    u = np.where(near, np.minimum(err, ff + err), err)
    # creep when stopped short of the stop point; hold once there
    tol = 0.5 * sim.tol_stop
    u = np.where((v < 0.3) & (d_stop > tol) & (v_ref > 1.0), np.maximum(u, 0.3), u)
    u = np.where((d_stop <= tol) & (v < 0.5), -1.0, u)
    return np.minimum(np.maximum(u, -1.0), 1.0)


def simple_driver(sim: "LineSim") -> FloatArray:
    """Safe reference driver for the whole fleet (commands for inactive trains are 0)."""
    u = driver_command(sim)
    return np.asarray(np.where(sim.active_mask(), u, 0.0))


def random_driver(sim: "LineSim", rng: np.random.Generator) -> FloatArray:
    """Uniformly random commands in [-1, 1], NaN (keep last) and +-inf mixed in."""
    u = rng.uniform(-1.0, 1.0, sim.n)
    r = rng.random(sim.n)
    u = np.where(r < 0.05, np.nan, u)
    u = np.where((r >= 0.05) & (r < 0.07), np.inf, u)
    return u


def adversarial_driver(sim: "LineSim", rng: np.random.Generator) -> FloatArray:
    """Worst-case fuzzing: full traction most of the time, brief random braking pulses."""
    u = np.ones(sim.n)
    pulse = rng.random(sim.n) < 0.03
    return np.asarray(np.where(pulse, -rng.random(sim.n), u))
