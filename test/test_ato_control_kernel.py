"""The compiled ATO control step gives the Python path's efforts and modes, bit for bit.

Closed loops (the graph's data flow, :mod:`metro_atc.core.closed_loop`) of the Blue line,
its delay/incident variant and generated incident lines (TSRs, breakdowns) run once with
the compiled step taken away from every ATO (``OnboardAto._kstep = None``: the Python path
for every step) and once as they run: every control step's effort,
mode, reason, last effort and guard state must be ``==``.  Replays of the recorded states
rebuild every ATO mid-run (a restarted node) and switch the kernel off and on at random
steps (the hand-over both ways), against the Python path.
"""

from __future__ import annotations

import json
import math
import os
import random
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from metro_atc.core.ato import control_kernel_pack as pack
from metro_atc.core.ato.onboard import OnboardAto, atp_model_for, envelope_limits, tsr_zones
from metro_atc.core.bridge import timetable_for, track_for, train_for
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import Scenario, load_scenario
from metro_atc.core.linegen import load_generated


def _record(scn: Scenario, kernel: str, duration_s: float, mp: pytest.MonkeyPatch,
            tracker: str = "fuzzy") -> tuple[list[Any], int, dict[int, list[Any]]]:
    """Every control step's outputs and ATO state, the kernel's step count, the inputs.

    ``kernel``: ``python`` (the compiled step taken away from every ATO) or ``numba``.
    """
    orig_c, orig_d = OnboardAto.control, OnboardAto.on_departure
    out: list[Any] = []
    logs: dict[int, list[Any]] = {}
    atos: dict[int, OnboardAto] = {}

    def control(self: OnboardAto, s: dict[str, Any]) -> Any:
        atos[id(self)] = self
        if kernel == "python":
            self._kstep = None
        res = orig_c(self, s)
        core = self.core
        out.append((res[0], res[1], core.last_reason, core.last_effort,
                    core.tracker.scalar_state(), self._peak_mps, self._next_stop_m,
                    self.authority_speed_mps, self._ma_prev, self._held_mps))
        logs.setdefault(id(self), []).append(("s", dict(s)))
        return res

    def on_departure(self: OnboardAto, *a: Any) -> Any:
        logs.setdefault(id(self), []).append(("d", a))
        return orig_d(self, *a)

    with mp.context() as m2:
        m2.setattr(OnboardAto, "control", control)
        m2.setattr(OnboardAto, "on_departure", on_departure)
        run_closed_loop(scn, duration_s=duration_s, tracker=tracker)
    assert all((a._kstep is None) == (kernel == "python") for a in atos.values())
    return out, sum(a.kernel_steps for a in atos.values()), logs


def _same(a: list[Any], b: list[Any]) -> None:
    assert len(a) == len(b)
    for i, (x, y) in enumerate(zip(a, b)):
        # NaN never equals itself: compare the tuples' reprs where a NaN may appear
        assert x == y or repr(x) == repr(y), (i, x, y)


@pytest.mark.parametrize("name,duration_s,tracker", [("taipei_blue", 1200.0, "fuzzy"),
                                                     ("taipei_blue_delay", 1500.0, "fuzzy"),
                                                     ("gen1", 1200.0, "fuzzy"),
                                                     ("gen2", 900.0, "fuzzy"),
                                                     ("taipei_blue", 1200.0, "pi"),
                                                     ("gen2", 900.0, "pi")])
def test_kernel_equals_python_in_closed_loops(name: str, duration_s: float, tracker: str,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Identical steps with either path and either tracker; the kernel takes most of them."""
    scn = load_generated(int(name[3:]), incidents=True) if name.startswith("gen") \
        else load_scenario(name)
    ref, k_py, _ = _record(scn, "python", duration_s, monkeypatch, tracker)
    got, k_nb, _ = _record(scn, "numba", duration_s, monkeypatch, tracker)
    assert k_py == 0
    moving = sum(1 for o in ref if o[1] != 1)
    assert moving > 5000, moving  # a run with real tracking in it
    # the kernel ran most moving steps (the Python path the hostile ones: the hand-over)
    assert 0 < k_nb < len(ref)
    assert k_nb > 0.4 * moving, (k_nb, moving)
    _same(ref, got)


def _replay(scn: Scenario, logs: dict[int, list[Any]], kernel: str, rebuild: bool,
            toggle_seed: int | None) -> list[Any]:
    """Replay the recorded inputs into fresh ATOs (one process's shared cache)."""
    train, track, tt = train_for(scn), track_for(scn), timetable_for(scn)
    limits, atp, tsrs = envelope_limits(scn, train), atp_model_for(scn, train), tsr_zones(scn)
    shared: dict[str, Any] = {}
    rng = random.Random(toggle_seed)

    def make() -> OnboardAto:
        ato = OnboardAto(train, track, tt.station_positions_m,
                         control_period_s=float(scn.sim.control_period_s), limits=limits,
                         shared=shared, tsrs=tsrs, atp=atp)
        if kernel == "python":
            ato._kstep = None
        return ato

    out: list[Any] = []
    for lg in logs.values():
        ato = make()
        steps = [i for i, (k, _) in enumerate(lg) if k == "s"]
        cut = steps[len(steps) // 2] if rebuild and steps else -1
        for i, (kind, a) in enumerate(lg):
            if i == cut:
                ato = make()  # the node restarted: no commands, plans from the state
            if kind == "d":
                ato.on_departure(*a)
                continue
            if toggle_seed is not None:
                ato._kstep = pack.control_step_fn() if rng.random() < 0.5 else None
            try:
                u, mode, _ = ato.control(a)
            except ValueError as exc:  # what the Python path raises on a NaN position
                out.append(("raised", str(exc)))
                continue
            out.append((u, mode, ato.core.last_reason, ato.core.last_effort,
                        ato.core.tracker.scalar_state(), ato._peak_mps, ato._next_stop_m,
                        ato.authority_speed_mps, ato._held_mps))
    return out


@pytest.mark.parametrize("name", ["taipei_blue_delay", "gen3"])
def test_restart_and_hand_over(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Rebuilt ATOs and a kernel switched off/on at random steps give the Python floats."""
    scn = load_generated(int(name[3:]), incidents=True) if name.startswith("gen") \
        else load_scenario(name)
    _, _, logs = _record(scn, "python", 900.0, monkeypatch)
    ref = _replay(scn, logs, "python", True, None)
    _same(ref, _replay(scn, logs, "numba", True, None))
    _same(ref, _replay(scn, logs, "numba", True, 7))
    _same(_replay(scn, logs, "python", False, None), _replay(scn, logs, "numba", False, 3))


def test_hostile_states_are_handed_back(monkeypatch: pytest.MonkeyPatch) -> None:
    """NaN, duplicate, backwards and stale-looking states: the Python path's answers.

    (The node validates states before ``control``; a NaN position raises in the Python path
    and so it does with the kernel, which hands such a state back.)
    """
    scn = load_scenario("taipei_blue")
    _, _, logs = _record(scn, "python", 400.0, monkeypatch)
    lg = max(logs.values(), key=len)
    rng = random.Random(5)
    bad: list[Any] = []
    last: dict[str, Any] | None = None
    for kind, a in lg:
        if kind == "d":
            bad.append((kind, a))
            continue
        s = dict(a)
        r = rng.random()
        if r < 0.03:
            s[rng.choice(["v_mps", "x_m", "t_s"])] = math.nan
        elif r < 0.06 and last is not None:
            s = dict(last)  # a duplicate
        elif r < 0.08 and last is not None:
            s["t_s"] = float(last["t_s"]) - 5.0  # time going backwards
        elif r < 0.10:
            s["supervision_speed_mps"] = rng.choice([math.inf, math.nan, 0.0, -3.0])
        elif r < 0.12:
            s["movement_authority_m"] = rng.choice([math.inf, math.nan, float(s["x_m"]) - 50.0])
        bad.append((kind, s))
        last = s
    logs2 = {0: bad}
    _same(_replay(scn, logs2, "python", False, None), _replay(scn, logs2, "numba", False, None))


def test_every_ato_takes_the_compiled_step(monkeypatch: pytest.MonkeyPatch) -> None:
    """No switch: an ATO holds the compiled step whatever the environment says (the only way
    to the Python path for the steps it takes is to take it away, as these tests do)."""
    monkeypatch.setenv("METRO_ATC_ATO_KERNEL", "python")  # the switch this package had
    scn = load_scenario("mini")
    train = train_for(scn)
    ato = OnboardAto(train, track_for(scn), np.array([0.0, 500.0]))
    assert ato._kstep is pack.control_step_fn()


_MINI_LOOP = """
import json
from metro_atc.core.ato.onboard import OnboardAto
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import load_scenario
out = []
orig = OnboardAto.control
def control(self, s):
    r = orig(self, s)
    out.append((r[0], r[1], self.kernel_steps))
    return r
OnboardAto.control = control
run_closed_loop(load_scenario("mini"), duration_s=120.0)
print(json.dumps([[a.hex(), b, k] for a, b, k in out]))
"""


@pytest.mark.parametrize("disable_jit", ["0", "1"])
def test_the_same_source_runs_as_python(disable_jit: str) -> None:
    """``NUMBA_DISABLE_JIT=1`` (debugging) runs the planners and the control step as Python:
    a ``mini`` closed loop gives the compiled run's efforts (bit for bit) and modes, the
    "kernel" (as Python) taking the same steps."""
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, NUMBA_DISABLE_JIT=disable_jit,
               PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", _MINI_LOOP], env=env, capture_output=True,
                       text=True, timeout=600, cwd=root)
    assert r.returncode == 0, r.stderr[-2000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    out: list[Any] = []
    orig = OnboardAto.control

    def control(self: OnboardAto, s: dict[str, Any]) -> Any:
        res = orig(self, s)
        out.append([float(res[0]).hex(), res[1], self.kernel_steps])
        return res

    OnboardAto.control = control  # type: ignore[method-assign]
    try:
        run_closed_loop(load_scenario("mini"), duration_s=120.0)
    finally:
        OnboardAto.control = orig  # type: ignore[method-assign]
    assert got == out
    assert max(k for _, _, k in out) > 100
