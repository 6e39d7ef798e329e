"""``scripts/install.sh`` step 5: the warm-up compiles every kernel a graph run calls.

After :func:`metro_atc.core.precompile.precompile_graph_kernels` (the ``mini`` closed loop),
a ``taipei_blue`` closed loop with the brake diagnosis (30 trains, the default planner and
tracker) adds no type signature to any numba kernel of the plant, the ATO or the brake
observer, nor to the laws of :mod:`metro_atc.core.laws` that Python code calls: a graph run
after an install loads them all from the on-disk cache.
"""

from __future__ import annotations

from types import ModuleType

from numba.core.registry import CPUDispatcher

from metro_atc.core import laws
from metro_atc.core.ato import control_kernel, control_kernel_step, step_kernel, switching_kernel
from metro_atc.core.brake import metro_kernel
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant import kernel, kernel_aux, kernel_run, kernel_step
from metro_atc.core.plant.line import LineSim
from metro_atc.core.precompile import precompile_graph_kernels

MODULES: tuple[ModuleType, ...] = (laws, kernel, kernel_aux, kernel_step, kernel_run,
                                   step_kernel, switching_kernel, metro_kernel, control_kernel,
                                   control_kernel_step)


def _signatures() -> dict[str, int]:
    """Number of compiled type signatures of every kernel of :data:`MODULES`."""
    return {f"{m.__name__}.{name}": len(obj.signatures)
            for m in MODULES for name, obj in vars(m).items()
            if isinstance(obj, CPUDispatcher)}


def test_warm_up_compiles_what_a_taipei_blue_run_calls() -> None:
    """No new signature in a 120 s taipei_blue closed loop after the warm-up."""
    assert precompile_graph_kernels() == 3
    before = _signatures()
    used = {k for k, n in before.items() if n > 0}
    # the plant step, the driver and the brake filter kernels ran in the warm-up
    assert any("kernel_step" in k for k in used), before
    assert any("metro_kernel" in k for k in used), before
    assert "metro_atc.core.plant.kernel_run.run_rows" in used, before
    # the compiled ATO control step ran in the warm-up's closed loop
    assert "metro_atc.core.ato.control_kernel_step.control_step" in used, before
    row = run_closed_loop(load_scenario("taipei_blue"), duration_s=120.0, brake=True).row()
    assert row["atp_violations"] == 0
    assert _signatures() == before
    # the headless multi-step run (bench perf), with and without the samples read
    sim = LineSim(load_scenario("taipei_blue"), seed=1)
    sim.run_driven(60.0, samples=False)
    assert sim.run_driven(120.0).kernel_steps > 0
    assert _signatures() == before
