"""Record the planners' numpy reference outputs (run once, before the numpy twins go).

Writes test/data/dp_numpy_ref.npz, mmas_numpy_ref.npz and tours_numpy_ref.npz: the inputs
and outputs of the numpy paths of the DP (exact simulation, backward / forward passes, a
whole solve), the MMAS ant construction and colony, and the exact tour simulation.  The
compiled paths are then tested equal to these frozen outputs.
"""

from __future__ import annotations

import os
import sys
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from metro_atc.core.ato import dp  # noqa: E402
from metro_atc.core.ato.envelope import MODE_ACCEL, RunModel  # noqa: E402
from metro_atc.core.ato.mmas import MmasParams, evaluate_tours, solve_mmas  # noqa: E402
import metro_atc.core.ato.mmas as mmas_mod  # noqa: E402
from metro_atc.core.ato.mmas_kernel import construct_ants_numpy  # noqa: E402
from metro_atc.core.ato.sections import build_section_tables, simulate_tours  # noqa: E402
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track  # noqa: E402

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
J_STAGE_STEP = 20


def _hilly() -> RunModel:
    track = Track(np.array([-1e12, 300.0, 700.0, 1100.0]), np.array([0.0, 0.03, -0.035, 0.0]),
                  np.array([-1e12, 900.0, 1200.0]),
                  np.array([80.0 / 3.6, 45.0 / 3.6, 80.0 / 3.6]))
    return RunModel(TAIPEI_MRT_6CAR, track, 0.0, 1600.0)


def _graded_run(davis_b_zero: bool = False) -> RunModel:
    track = Track(np.array([-1e12, 150.0, 350.0]), np.array([0.0, -0.03, 0.025]),
                  np.array([-1e12, 250.0, 400.0]), np.array([70 / 3.6, 45 / 3.6, 70 / 3.6]))
    train = replace(TAIPEI_MRT_6CAR, davis_b_n_per_mps=0.0) if davis_b_zero else \
        TAIPEI_MRT_6CAR
    return RunModel(train, track, 0.0, 600.0)


def record_dp() -> dict[str, np.ndarray]:
    dp.kernel = "numpy"
    run = _hilly()
    tab = dp.build_dp_tables(run)
    n = tab.n_stages
    rng = np.random.default_rng(7)
    ctrl = np.repeat(rng.integers(0, 4, (16, 10)), n // 10 + 1, axis=1)[:, :n]
    lev = np.asarray(dp.CONTROL_LEVELS)[ctrl] * rng.uniform(0.1, 1.0, ctrl.shape)
    ks = rng.integers(0, n, 300)
    e0 = rng.uniform(0.0, 1.1 * float(np.max(tab.cap_sub)), 300)
    modes = rng.choice(np.array([dp.MODE_ACCEL, dp.MODE_CRUISE, dp.MODE_COAST]), 300)
    lv = rng.uniform(0.05, 1.0, 300)
    sp_e, sp_j, sp_t = dp.simulate_path(run, tab, ctrl, lev)
    st_e, st_j, st_t = dp._simulate_stages(run, tab, ks, e0, modes, lv)
    mus = np.array([3e3, 2e4, 1e5, 4e5, 2e6])
    rng = np.random.default_rng(2)
    pol = rng.integers(0, mus.size, (6, n))
    k0 = rng.integers(0, n, 50)
    pm = rng.integers(0, mus.size, 50)
    fe0 = rng.uniform(0.0, 150.0, 50)
    j_all = dp._backward(tab, mus)
    fw = dp._forward(tab, mus, j_all, pol)
    fm = dp._forward_multi(tab, mus, j_all, pm, fe0, k0)
    short = RunModel(run.train, run.track, 0.0, 900.0)
    res = dp.solve_dp(short, 80.0)
    return dict(
        sim_controls=ctrl.astype(np.int8), sim_levels=lev, sim_e=sp_e, sim_j=sp_j, sim_t=sp_t,
        stage_k=ks.astype(np.int16), stage_e0=e0, stage_mode=modes.astype(np.int8),
        stage_level=lv, stage_e=st_e, stage_j=st_j, stage_t=st_t,
        mus=mus, j_stage_step=np.array(J_STAGE_STEP), j_sub=j_all[:, ::J_STAGE_STEP],
        fw_policy=pol.astype(np.int8), fw_controls=fw.controls.astype(np.int8),
        fw_e=fw.energy_j, fw_t=fw.time_s, fw_path=fw.e_path,
        fm_k0=k0.astype(np.int16), fm_pol=pm.astype(np.int8), fm_e0=fe0,
        fm_controls=fm.controls.astype(np.int8), fm_e=fm.energy_j, fm_t=fm.time_s,
        solve_controls=res.controls.astype(np.int8), solve_levels=np.asarray(res.levels),
        solve_e=np.array(res.energy_j), solve_t=np.array(res.time_s),
        solve_v=res.v_profile, solve_feasible=np.array(res.feasible))


def record_mmas() -> dict[str, np.ndarray]:
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    rng = np.random.default_rng(11)
    n_s, n_c, n_k = tab.n_sections, tab.n_codes, 64
    tau_m = rng.uniform(0.2, 2.0, (n_s, 3, 3))
    tau_c = rng.uniform(0.2, 2.0, (n_s, 3, n_c))
    cum_m = np.cumsum(tau_m * rng.uniform(0.1, 1.0, (n_s, 1, 3)), axis=2)
    cum_c = np.cumsum(tau_c * tab.code_allowed.astype(float)[:, None, :], axis=2)
    u = rng.random((n_s, 2, n_k))
    m = np.empty((n_k, n_s), dtype=np.int64)
    c = np.empty((n_k, n_s), dtype=np.int64)
    t, en = np.empty(n_k), np.empty(n_k)
    construct_ants_numpy(cum_m, cum_c, u, tab.packed, 1.0 / tab.h_e, int(tab.e_grid.size),
                         m, c, t, en)
    t_fast = float(evaluate_tours(tab, np.zeros((1, 12), dtype=np.int64),
                                  np.full((1, 12), tab.n_codes - 1, dtype=np.int64))[0][0])
    mmas_mod._construct = construct_ants_numpy
    res = solve_mmas(tab, t_fast * 1.15, MmasParams(seed=2, n_iterations=15,
                                                    local_search=False))
    return dict(cum_m=cum_m, cum_c=cum_c, u=u, ants_modes=m.astype(np.int8),
                ants_codes=c.astype(np.int8), ants_t=t, ants_e=en,
                colony_history=np.asarray(res.history), colony_modes=res.modes,
                colony_codes=res.codes)


def record_tours() -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for b0 in (False, True):
        run = _graded_run(b0)
        tab = build_section_tables(run, n_sections=12)
        rng = np.random.default_rng(5)
        modes = rng.integers(0, 3, (30, 12))
        modes[:, 0] = MODE_ACCEL
        speeds = rng.uniform(15.0, 75.0, (30, 12)) / 3.6
        t, e, end, st, s_grid, hist = simulate_tours(tab, modes, np.zeros_like(modes),
                                                     record=True, code_speeds_mps=speeds)
        key = "b0_" if b0 else "b_"
        out.update({key + "modes": modes.astype(np.int8), key + "speeds": speeds,
                    key + "t": t, key + "e": e, key + "end": end, key + "stalled": st,
                    key + "hist": hist})
    return out


if __name__ == "__main__":
    np.savez_compressed(os.path.join(OUT, "dp_numpy_ref.npz"), **record_dp())
    np.savez_compressed(os.path.join(OUT, "mmas_numpy_ref.npz"), **record_mmas())
    np.savez_compressed(os.path.join(OUT, "tours_numpy_ref.npz"), **record_tours())
