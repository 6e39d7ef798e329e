"""The compiled plant step on generated lines, against recorded reference traces.

Generated lines (:mod:`metro_atc.core.linegen`; some with incidents, some on a wet rail
with traction pulses that make axles slide and ATP intervene) run with the reference
driver's command, NaN and out-of-range entries and traction pulses mixed in, and ATS
departure commands on the way.  Every step's sums of the fleet, ATP, energy, axle and
sensor state, the full state every ``FULL_EVERY`` steps, the events and the KPIs must equal
``test/data/plant_gen/*.npz`` bit for bit.  The traces were recorded by ``main()`` below
when the plant still had a numpy reference path beside the compiled one, and both gave
these traces exactly (the numpy path then was the independent reference; it is gone, the
laws live once in :mod:`metro_atc.core.laws`).  Re-record only for a change whose every
moved number is explained.
"""

from __future__ import annotations

import json
from operator import attrgetter
import sys
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from metro_atc.core.line.scenario import parse_scenario
from metro_atc.core.linegen import generate_line, scenario_yaml
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim

STATE = {"x": "fleet.x", "v": "fleet.v", "acc": "fleet.acc", "a_dem": "fleet.a_dem",
         "u_last": "fleet.u_last", "eb": "atp.eb", "sb": "atp.sb", "eoa": "atp.eoa",
         "atp_limit": "atp.atp_limit", "speed_code": "atp.speed_code",
         "interventions": "atp.interventions", "violations": "atp.violations",
         "e_trac": "energy.e_trac", "e_elec": "energy.e_elec", "e_fric": "energy.e_fric",
         "e_res": "energy.e_res", "e_curve": "energy.e_curve", "e_grade": "energy.e_grade",
         "e_stop_corr": "energy.e_stop_corr", "n_in_service": "energy.n_in_service",
         "status": "fleet.status", "load": "fleet.load", "fx": "fx", "clamp": "clamp",
         "slip": "slip"}
"""Recorded state: its key in the traces -> its path on :class:`LineSim`."""
SENSORS = ("omega", "clamp", "accel", "vref", "car_mass")
CASES = [(1, False, False, False), (2, True, False, False), (3, True, True, True),
         (4, False, True, True), (5, True, False, True), (6, False, False, True)]
"""(seed, incidents, wet rail, traction pulses) of each generated line."""
T_END_S = 600.0
FULL_EVERY = 200
DATA = Path(__file__).parent / "data" / "plant_gen"


def _line(seed: int, incidents: bool, wet: bool) -> Any:
    d = generate_line(seed, incidents=incidents)
    if wet:
        d["line"]["adhesion"] = "wet"
    return parse_scenario(scenario_yaml(d), src=f"gen_{seed}")


def _name(case: tuple[int, bool, bool, bool]) -> str:
    seed, inc, wet, pulses = case
    return f"gen{seed}_{'i' if inc else 'n'}{'w' if wet else 'd'}{'p' if pulses else 'c'}"


def trace(case: tuple[int, bool, bool, bool], t_end: float = T_END_S,
          make: Callable[[Any, int], LineSim] = lambda s, seed: LineSim(s, seed=seed),
          tamper: Any = None, slid: list[int] | None = None) -> dict[str, np.ndarray]:
    """Run one case; per-step sums, strided full states, events and KPIs."""
    seed, incidents, wet, pulses = case
    sim = make(_line(seed, incidents, wet), seed)
    if tamper is not None:
        tamper(sim)
    rng = np.random.default_rng(seed)
    rows: list[list[float]] = []
    full: dict[str, list[np.ndarray]] = {name: [] for name in STATE}
    events: list[str] = []
    k = 0
    while not sim.done and sim.t < t_end:
        u = simple_driver(sim).copy()
        r = rng.random(sim.n)
        u[r < 0.03] = np.nan
        u[(r >= 0.03) & (r < 0.04)] = 7.0
        if pulses and (k // 200) % 3 == 0:  # bursts of full traction (ATP, wheel slides)
            u[: max(sim.n // 3, 1)] = 1.0
        res = sim.step(u)
        row = [float(np.sum(np.asarray(attrgetter(path)(sim), dtype=float)))
               for path in STATE.values()]
        sa = res.sensor_arrays
        for ch in SENSORS:
            a = np.asarray(getattr(sa, ch), dtype=float) if sa is not None else np.zeros(0)
            row += [float(np.nansum(a)), float(np.count_nonzero(np.isnan(a)))]
        row += [float(res.atp_interventions), sim.atp.min_sep, float(sim.atp.steps_above_civil)]
        rows.append(row)
        if k % FULL_EVERY == 0:
            for name in STATE:
                full[name].append(np.asarray(attrgetter(STATE[name])(sim), dtype=float).copy())
        events += [repr(e) for e in res.events]
        if slid is not None:
            slid.append(int(sim.brakes.any_slide))
        if k % 40 == 0 and sim.t > 60.0:  # ATS departure commands on the way
            i = int(rng.integers(sim.n))
            j = int(rng.integers(sim.n_st))
            cut = float(rng.uniform(20, 60))
            sim.set_departure(i, j, sim.t + 30.0, 95.0, cut)
        k += 1
    out = {"rows": np.asarray(rows), "events": np.asarray(events, dtype=str),
           "kpis": np.asarray(json.dumps(sim.kpis(), sort_keys=True))}
    for name, arrs in full.items():  # per-train arrays, or axle arrays of varying shape
        out[f"full_{name}"] = np.concatenate([a.ravel() for a in arrs])
    return out


def compare(got: dict[str, np.ndarray], exp: dict[str, np.ndarray], where: str) -> None:
    """Every array equal bit for bit (the first differing step named)."""
    assert set(got) == set(exp), where
    g, e = got["rows"], exp["rows"]
    assert g.shape == e.shape, f"{where}: {g.shape} steps x sums, expected {e.shape}"
    same = (g == e) | (np.isnan(g) & np.isnan(e))
    if not same.all():
        k, j = np.argwhere(~same)[0]
        names = list(STATE) + [f"sensor_{c}_{s}" for c in SENSORS for s in ("sum", "nan")] \
            + ["interventions", "min_sep", "steps_above_civil"]
        raise AssertionError(f"{where}: step {k}, {names[j]}: {g[k, j]!r} != {e[k, j]!r}")
    for key in exp:
        np.testing.assert_array_equal(got[key], exp[key], err_msg=f"{where}: {key}")


@pytest.mark.parametrize("case", CASES, ids=_name)
def test_generated_lines_reproduce_the_reference(case: tuple[int, bool, bool, bool]) -> None:
    """States, events, samples and KPIs of the recorded reference, bit for bit."""
    exp = dict(np.load(DATA / f"{_name(case)}.npz"))
    got = trace(case)
    assert got["rows"].shape[0] > 1000
    compare(got, exp, _name(case))


def test_wet_pulses_exercise_the_slide_path() -> None:
    """The wet-rail case reaches the numpy slide model from the compiled step."""
    slid: list[int] = []
    trace(CASES[2], slid=slid)
    assert sum(slid) > 0


def test_comparison_detects_a_kernel_change() -> None:
    """A 0.01 % change of one kernel constant is caught (the comparison can fail)."""
    from metro_atc.core.plant import kernel as kn

    def tamper(sim: LineSim) -> None:
        sim.stepper.c.view(kn.CONSTANTS)[0]["davis_a"] *= 1.0001

    exp = dict(np.load(DATA / f"{_name(CASES[0])}.npz"))
    with pytest.raises(AssertionError):
        compare(trace(CASES[0], tamper=tamper), exp, "tampered")


def test_interp_matches_numpy() -> None:
    """The kernel's interp reproduces np.interp bit for bit, edge cases included."""
    from metro_atc.core.plant.kernel import interp1
    rng = np.random.default_rng(0)
    for _ in range(20):
        xp = np.sort(rng.uniform(-5.0, 5.0, int(rng.integers(2, 60))))
        xp[rng.random(xp.size) < 0.1] = xp[0]  # repeated abscissae
        xp = np.maximum.accumulate(xp)
        fp = rng.normal(size=xp.size)
        x = np.concatenate([rng.uniform(-6.0, 6.0, 200), xp, [np.nan, np.inf, -np.inf]])
        got = np.array([interp1(float(v), xp, fp) for v in x])
        np.testing.assert_array_equal(got, np.interp(x, xp, fp))


def test_samples_read_out_of_order_or_skipped() -> None:
    """Samples the compiled step computed ahead are used only while they are the next ones.

    Reading patterns: every step, every other step, none, and held results read later in
    reverse order.  A twin plant read in the same pattern but never computing ahead
    (``sensors.want`` cleared after each read: every block assembled at access, from the
    next normals of the stream) must give exactly the same samples.
    """
    scn = _line(2, True, False)
    a, b = LineSim(scn, seed=2), LineSim(scn, seed=2)
    held: list[tuple[Any, Any]] = []
    n_cmp = n_pre = 0
    for k in range(1600):
        ra, rb = a.step(simple_driver(a)), b.step(simple_driver(b))
        mode = (k // 200) % 4
        pairs = []
        if mode == 0 or (mode == 1 and k % 2):
            pairs = [(ra, rb)]
        elif mode == 3:
            held.append((ra, rb))
            if len(held) == 3:
                pairs, held = held[::-1], []
        for pa, pb in pairs:
            n_pre += pb._snap is not None and pb._snap.pre is not None
            sa, sb = pa.sensor_arrays, pb.sensor_arrays
            a.sensors.want = False
            assert (sa is None) == (sb is None), k
            if sa is not None:
                n_cmp += 1
                for ch in ("t", "trains") + SENSORS:
                    np.testing.assert_array_equal(getattr(sa, ch), getattr(sb, ch),
                                                  err_msg=f"step {k}: sensor {ch}")
    assert b.sensors.want and n_cmp > 300 and n_pre > 100
    assert json.dumps(a.kpis(), sort_keys=True) == json.dumps(b.kpis(), sort_keys=True)
    np.testing.assert_array_equal(a.sensors.normals(5000), b.sensors.normals(5000))


def main(names: list[str]) -> None:
    """Record the named cases, or every case (overwrites the reference traces)."""
    DATA.mkdir(parents=True, exist_ok=True)
    for case in CASES:
        if names and _name(case) not in names:
            continue
        data = trace(case)
        np.savez_compressed(DATA / f"{_name(case)}.npz", **data)
        print(f"{_name(case)}: {data['rows'].shape[0]} steps, {data['events'].size} events")


if __name__ == "__main__":
    main(sys.argv[1:])


def test_constants_are_named_records_of_plain_vectors() -> None:
    """The run / driver constants: float vectors whose record fields hold the parts' values."""
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.plant import kernel as kn
    from metro_atc.core.plant import kernel_step as ks
    sim = LineSim(load_scenario("mini_pad_fault"), seed=1)
    st = sim.stepper
    assert st is not None
    assert st.c.dtype == np.float64 and st.c.size * 8 == kn.CONSTANTS.itemsize
    cr = st.c.view(kn.CONSTANTS)[0]
    assert cr["dt"] == sim.control_period_s and cr["substeps"] == sim.substeps
    assert cr["davis_a"] == sim.p.davis_a_n and cr["tol"] == sim.tol_stop
    assert cr["train_length"] == sim.geometry.length_m and cr["n_sid"] == sim.geometry.n_sid
    np.testing.assert_array_equal(cr["noise"], st.noise)
    st.driver(sim, 1.25, 0.5, False)
    dr = st.dcs[0].view(ks.DRIVER)[0]
    assert (dr["gain"], dr["lookahead"], dr["x0"]) == (1.25, 0.5, sim.geometry.x0)
    assert st.dcs.shape[1] * 8 == ks.DRIVER.itemsize


def test_record_vector_needs_every_field_once() -> None:
    """A constants vector with a field missing or unknown is refused (no silent zero)."""
    from metro_atc.core.plant.fast import _record_vector
    from metro_atc.core.plant.kernel_step import DRIVER, DRIVER_FIELDS
    vals = tuple((f, float(i)) for i, f in enumerate(DRIVER_FIELDS))
    np.testing.assert_array_equal(_record_vector(DRIVER, vals), np.arange(len(vals)))
    with pytest.raises(ValueError):
        _record_vector(DRIVER, vals[1:])
    with pytest.raises(ValueError):
        _record_vector(DRIVER, vals[1:] + (("speed", 1.0),))


def test_plant_kernels_read_constants_by_name() -> None:
    """No numbered constant slots left: only the per-train / per-cell row indices remain.

    The rows kept (``O_*`` output rows, ``F_*`` / ``I_*`` / ``B_*`` state rows, ``M_*`` /
    ``P_*`` / ``G_*`` copied rows) are arrays of n trains or cells whose rows the components'
    attributes are; ``STOP_*`` are reason codes.
    """
    import re

    from metro_atc.core.plant import fast, fast_run, kernel, kernel_run, kernel_step
    kept = re.compile(r"(?:O|F|I|B|M|P|G|N|STOP)_[A-Z0-9_]+$")
    plant = Path(kernel.__file__).parent
    for mod in (kernel, kernel_step, kernel_run, fast, fast_run):
        slots = [n for n in vars(mod) if re.match(r"[A-Z]_[A-Z0-9_]+$", n)
                 and isinstance(vars(mod)[n], int) and not isinstance(vars(mod)[n], bool)]
        assert [n for n in slots if not kept.match(n)] == [], mod.__name__
    for path in sorted(plant.glob("kernel*.py")) + sorted(plant.glob("fast*.py")):
        src = path.read_text()
        assert not re.search(r"\b(?:c|dc|rf|ri)\s*\[\s*[A-Z]+_", src), path.name
        for m in re.finditer(r"\(?([A-Z_, \n]+)\)?\s*=\s*range\(\d+\)", src):
            names = [n.strip() for n in m.group(1).replace("\n", " ").split(",")]
            assert all(kept.match(n) for n in names if n), (path.name, names)
    assert kernel.CONSTANTS.names == kernel.CONSTANT_FIELDS + ("noise",)
    assert kernel_step.DRIVER.names == kernel_step.DRIVER_FIELDS
    assert kernel_run.RESULT_I.names == kernel_run.RESULT_INTS
    assert kernel_run.RESULT_F.names == kernel_run.RESULT_FLOATS
