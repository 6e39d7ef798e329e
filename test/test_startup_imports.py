"""Node start-up imports only what it needs (graph start-up time).

Each check runs in a fresh interpreter (``sys.modules`` of this pytest process holds
whatever earlier tests imported).  torch costs ~2 s of CPU to import and only the learned
regulators (dhp / aoc) use it; scipy.linalg (~0.2 s) only the LQR regulators; numba only
the nodes with compiled kernels.  All five node processes start together on a 2-core
machine, so every import adds to the time before the lockstep's step 0.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("torch", "scipy.linalg", "scipy.optimize", "numba", "matplotlib")


def loaded_after(code: str) -> list[str]:
    """The HEAVY modules in ``sys.modules`` after running ``code`` in a new interpreter."""
    probe = (f"import sys, json\n{code}\n"
             f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    return list(json.loads(out.strip().splitlines()[-1]))


@pytest.mark.parametrize("module, allowed", [
    ("metro_atc.nodes.ats_regulator", ()),
    ("metro_atc.nodes.line_simulator", ("numba",)),
    ("metro_atc.nodes.ato_controller", ("numba",)),
    ("metro_atc.nodes.brake_diagnostic", ("numba", "scipy.linalg")),
    ("metro_atc.nodes.bag_recorder", ()),
    ("metro_atc.launcher", ()),
])
def test_node_module_imports_no_heavy_dependency(module: str, allowed: tuple[str, ...]) -> None:
    """Importing a node module loads neither torch nor (unless it uses them) scipy/numba."""
    extra = sorted(set(loaded_after(f"import {module}")) - set(allowed))
    assert extra == [], f"{module} imports {extra} at start-up"


def test_ats_dispatcher_none_and_lqr_without_torch() -> None:
    """The ATS dispatcher for 'none' loads no torch; 'lqr' loads scipy but no torch.

    The timetable (geometry, flat-out running times) is computed with the compiled laws of
    :mod:`metro_atc.core.laws`, so a dispatcher loads numba (and what numba itself imports,
    scipy.linalg among it); loading a scenario alone does not (next test).
    """
    none = loaded_after(
        "from metro_atc.core.line.scenario import load_scenario\n"
        "from metro_atc.core.atr.dispatch import make_dispatcher\n"
        "make_dispatcher(load_scenario('taipei_blue'), 'none')")
    assert "torch" not in none and "scipy.optimize" not in none
    lqr = loaded_after(
        "from metro_atc.core.line.scenario import load_scenario\n"
        "from metro_atc.core.atr.dispatch import make_dispatcher\n"
        "d = make_dispatcher(load_scenario('taipei_blue'), 'lqr')\n"
        "assert d.core is not None")
    assert "torch" not in lqr and "scipy.linalg" in lqr


def test_loading_a_scenario_compiles_nothing() -> None:
    """The loader's checks use the laws uncompiled (``laws.plain``): no numba, no scipy."""
    assert loaded_after("from metro_atc.core.line.scenario import load_scenario\n"
                        "for s in ('taipei_blue', 'thsr', 'mini'):\n"
                        "    load_scenario(s)") == []


def test_learned_regulator_still_loads_torch() -> None:
    """The lazy imports still reach torch where it is needed (aoc weights, shipped)."""
    got = loaded_after(
        "from metro_atc.core.line.scenario import load_scenario\n"
        "from metro_atc.core.atr.dispatch import make_dispatcher\n"
        "d = make_dispatcher(load_scenario('taipei_blue'), 'aoc')\n"
        "import numpy as np\n"
        "u = d.core.regulator.decide(np.zeros(d.core.regulator.n))\n"
        "assert u.shape == (d.core.regulator.n,)")
    assert "torch" in got


def test_lqr_gain_unchanged_by_the_lazy_model() -> None:
    """The LQR built from ``traffic.linear_model`` is the one built from ``AtrProblem``."""
    from metro_atc.core.atr.cost import CostWeights
    from metro_atc.core.atr.lines import atr_line_for
    from metro_atc.core.atr.problems import AtrProblem
    from metro_atc.core.atr.regulators import LqrRegulator, make_regulator
    from metro_atc.core.line.scenario import load_scenario
    line = atr_line_for(load_scenario("taipei_blue"))
    w = CostWeights()
    p = AtrProblem(line, w)
    ref = LqrRegulator(p.a_np, p.b_np, w)
    got = make_regulator("lqr", line, w)
    assert isinstance(got, LqrRegulator)
    assert (got.k == ref.k).all()
