"""Compile the numba kernels of a graph run into their on-disk caches (install step 5).

Every kernel is ``cache=True``: compiled once, then loaded from the cache next to the
installed module (numba's user cache or ``NUMBA_CACHE_DIR`` where that is read-only).
Without this step the first run after an install compiles them in every node process that
needs them (~20 s of CPU in the simulator and each ATO process: `make demo` on a fresh
clone paid it).  A short ROS-free closed loop of the ``mini`` scenario with the brake
diagnosis on calls the plant, ATO and brake kernels with the argument types a graph run
passes (one type signature each; the test checks that a ``taipei_blue`` run then compiles
nothing new; its ATOs run the compiled control step of :mod:`.ato.control_kernel_step`).
A short :meth:`LineSim.run_driven` of the same scenario compiles the multi-step kernel of
``bench perf`` and the headless runs (:mod:`.plant.kernel_run`).
"""

from __future__ import annotations

from metro_atc.core.brake.metro_car import precompile_metro_kernels
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant.line import LineSim

WARMUP_SCENARIO = "mini"
"""The scenario of the warm-up run (two trains: every kernel, little time)."""
WARMUP_S = 300.0
"""Simulated time of the warm-up run [s]: both trains depart, brake and stop."""


def precompile_graph_kernels() -> int:
    """Compile (or load) every kernel a graph run uses; return the brake kernel steps (3).

    Fewer than 3 brake kernel steps means the brake observer ran its numpy path.
    """
    steps = precompile_metro_kernels()
    run_closed_loop(load_scenario(WARMUP_SCENARIO), duration_s=WARMUP_S, brake=True)
    LineSim(load_scenario(WARMUP_SCENARIO)).run_driven(WARMUP_S)
    return steps
