"""Monte-Carlo reproduction of the brake-by-wire diagnosis experiments.

Seed 000 (second paper), Table II: 80 km/h, 5 s, driver signals A1 straight brake /
A2 cornering / A3 lane change, road mu B1 0.85 / B2 0.3, cases normal / abnormal pad
(mu_b = 0.1) / abnormal front-right tyre; plus the same three kinds of case on the
metro car (service brake / ATO brake steps, dry / wet rail, normal / pad / wheel).

Every "noise seed" draws the sensor noise *and* a dispersion of the vehicle (mass, true
mu_b of a healthy pad, road/rail adhesion, gradient for the metro), so the normal runs
measure the decision logic's robustness, not only sensor noise.  Thresholds are
calibrated on separate normal runs (own random stream) and evaluated on fresh ones.

Dispersion (uniform): paper - mass x[0.97, 1.08], healthy mu_b [0.34, 0.42], road mu
x[0.95, 1.05]; metro - mass x[0.9, 1.25] (known from the load-weigh signal), healthy
mu_b [0.31, 0.39], creep curve x[0.85, 1.15], sin(gradient) [-0.03, 0.03].
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from metro_atc.core.brake import diagnosis as dg
from metro_atc.core.brake import metro_car as mc
from metro_atc.core.brake import paper_vehicle as pv

FloatArray = np.ndarray

PAPER_DECISION = {"persistence_s": 0.3, "gate_s": 0.3, "filter_tau_s": 0.1}
"""Decision timing of the paper vehicle (our choice; the paper gives none)."""
MARGIN = 1.5
"""Safety margin on the calibrated residual level."""
MANEUVER_CODES = ("A1", "A2", "A3")
ROAD_CODES = ("B1", "B2")


@dataclass(frozen=True)
class ExperimentConfig:
    """Monte-Carlo sizes and the seed."""

    n_normal: int = 50
    """Evaluation normal runs per condition (noise seeds)."""
    n_fault: int = 10
    """Runs per condition and fault."""
    n_cal: int = 30
    """Calibration normal runs per condition (disjoint random stream)."""
    seed: int = 0
    """Master seed."""


def convergence_time(est: FloatArray, true: FloatArray, t: FloatArray,
                     rel_tol: float = 0.1) -> FloatArray:
    """Time after which ``|est - true| <= rel_tol |true|`` holds to the end [s].

    Args:
        est: (B, n_t); true: (B,); t: (n_t,).

    Returns:
        (B,) times; NaN when the estimate is outside the band at the end.
    """
    bad = np.abs(est - true[:, None]) > rel_tol * np.abs(true[:, None])
    nt = t.size
    last_bad = nt - 1 - np.argmax(bad[:, ::-1], axis=1)
    any_bad = bad.any(axis=1)
    idx = np.where(any_bad, last_bad + 1, 0)
    out = np.where(idx < nt, t[np.minimum(idx, nt - 1)], np.nan)
    return np.where(bad[:, -1], np.nan, out)


def _nanmedian(x: FloatArray) -> Optional[float]:
    x = x[~np.isnan(x)]
    return float(np.median(x)) if x.size else None


def _nanmax(x: FloatArray) -> Optional[float]:
    x = x[~np.isnan(x)]
    return float(np.max(x)) if x.size else None


def summarise(name: str, vehicle: str, fault: str, sel: FloatArray, dec: dg.Decision,
              mu_hat: FloatArray, mu_true: FloatArray, t: FloatArray, f_est: FloatArray,
              f_true: FloatArray, extra: dict[str, Any]) -> dict[str, Any]:
    """Metrics of one case (condition x fault) over its runs ``sel``."""
    conv = convergence_time(mu_hat[sel], mu_true[sel], t)
    rmse = np.sqrt(((f_est[sel] - f_true[sel]) ** 2).mean(axis=(1, 2)))
    flaws = dec.flaw[sel]
    causes = []
    if dec.pad_flaw[sel].any():
        causes.append("mu_b")
    if dec.force_flaw[sel].any():
        causes.append("force")
    out: dict[str, Any] = {
        "name": name, "vehicle": vehicle, "fault": fault,
        "flaw": bool(flaws[0]), "flaw_rate": float(flaws.mean()),
        "detect_time_s": _nanmedian(dec.detect_time[sel]),
        "detect_time_max_s": _nanmax(dec.detect_time[sel]),
        "flaw_causes": causes,
        "mu_b_true": float(np.mean(mu_true[sel])),
        "mu_b_final": float(np.mean(mu_hat[sel, -1])),
        "mu_b_final_spread": float(np.std(mu_hat[sel, -1])),
        "mu_b_convergence_time_s": _nanmedian(conv),
        "mu_b_converged_fraction": float(np.mean(~np.isnan(conv))),
        "force_rmse_n": float(np.mean(rmse)),
        "runs": int(np.count_nonzero(sel)),
    }
    out.update(extra)
    return out


def paper_experiment(cfg: ExperimentConfig) -> dict[str, Any]:
    """All Table II conditions x 3 cases on the paper vehicle.

    Returns:
        dict with ``cases`` (list of metric dicts), ``thresholds_n`` {road mu: (6,)},
        ``false_alarms``, ``missed``, ``runs``, ``timing_s`` and ``plot`` (the first run
        of each A1-B1 case: time, truth, targets, estimates).
    """
    p = pv.PaperVehicleParams()
    t_start = time.perf_counter()
    conds = [(m, mu) for m in range(3) for mu in pv.ROAD_MU]
    rng = np.random.default_rng(cfg.seed)
    rng_cal = np.random.default_rng(cfg.seed + 1000)
    scen: list[pv.Scenario] = []
    cond_idx: list[int] = []
    kinds: list[str] = []
    for ci, (m, mu) in enumerate(conds):
        for kind, n, r in (("cal", cfg.n_cal, rng_cal), ("none", cfg.n_normal, rng),
                           ("pad", cfg.n_fault, rng), ("tyre", cfg.n_fault, rng)):
            for _ in range(n):
                fault = "none" if kind == "cal" else kind
                mu_b = None if fault == "pad" else float(r.uniform(0.34, 0.42))
                scen.append(pv.Scenario(m, mu, fault, mu_b=mu_b,
                                        mass_scale=float(r.uniform(0.97, 1.08)),
                                        mu_scale=float(r.uniform(0.95, 1.05))))
                cond_idx.append(ci)
                kinds.append(kind)
    ci_arr = np.array(cond_idx)
    kind_arr = np.array(kinds)
    log = pv.simulate(p, scen)
    meas = pv.measure(log, pv.PaperSensorNoise(), rng)
    t_sim = time.perf_counter()
    obs = pv.run_observer(p, meas)
    t_obs = time.perf_counter()
    ref = pv.simulate(p, [pv.Scenario(s.maneuver, s.mu) for s in scen], reference=True,
                      mu_b_in=obs["mu_b"])
    t_ref = time.perf_counter()
    t = log.t[0]
    res = dg.residuals(obs["forces"], ref.targets())
    cal = kind_arr == "cal"
    # thresholds scheduled on the road mu the vehicle-tyre model is given (B1 / B2):
    # on low mu the ABS is active and the residuals are an order of magnitude larger
    road = np.array([s.mu for s in scen])
    nb, nc = res.shape[0], res.shape[2]
    dec = dg.Decision(flaw=np.zeros(nb, bool), detect_time=np.full(nb, np.nan),
                      pad_flaw=np.zeros(nb, bool), force_flaw=np.zeros((nb, nc), bool),
                      pad_time=np.full(nb, np.nan), force_time=np.full((nb, nc), np.nan))
    thr_by_mu: dict[float, FloatArray] = {}
    for mu in pv.ROAD_MU:
        cls = road == mu
        thr = dg.calibrate_thresholds(res[cls & cal], t, PAPER_DECISION["persistence_s"],
                                      PAPER_DECISION["gate_s"], PAPER_DECISION["filter_tau_s"],
                                      margin=MARGIN, floor=50.0)
        thr_by_mu[mu] = thr
        d = dg.decide(obs["mu_b"][cls], obs["std"][cls][..., pv.I_MUB], res[cls], t,
                      dg.DecisionConfig(thresholds=thr,
                                        persistence_s=PAPER_DECISION["persistence_s"],
                                        gate_s=PAPER_DECISION["gate_s"],
                                        filter_tau_s=PAPER_DECISION["filter_tau_s"]))
        for name in ("flaw", "detect_time", "pad_flaw", "force_flaw", "pad_time",
                     "force_time"):
            getattr(dec, name)[cls] = getattr(d, name)
    mu_true = np.array([s.true_mu_b(p) for s in scen])
    truth = log.targets()
    cases = []
    for ci, (m, mu) in enumerate(conds):
        for fault, label in (("none", "normal"), ("pad", "abnormal pad"),
                             ("tyre", "abnormal front-right tyre")):
            sel = (ci_arr == ci) & (kind_arr == fault)
            name = (f"{MANEUVER_CODES[m]}-{ROAD_CODES[pv.ROAD_MU.index(mu)]} "
                    f"{pv.MANEUVERS[m]} mu={mu} {label}")
            cases.append(summarise(name, "paper", fault, sel, dec, obs["mu_b"], mu_true, t,
                                   obs["forces"], truth,
                                   {"maneuver": pv.MANEUVERS[m], "road_mu": mu,
                                    "brake_onset_s": pv.BRAKE_ONSET_S}))
    ev = ~cal
    normal = ev & (kind_arr == "none")
    faulty = ev & (kind_arr != "none")
    plot = {}
    for fault in ("none", "pad", "tyre"):
        b = int(np.flatnonzero((ci_arr == 0) & (kind_arr == fault))[0])
        plot[fault] = {"t": t, "est": obs["forces"][b], "est_std": obs["std"][b][:, pv.I_FORCES],
                       "target": ref.targets()[b], "truth": truth[b], "mu_b": obs["mu_b"][b],
                       "mu_b_std": obs["std"][b, :, pv.I_MUB], "mu_b_true": mu_true[b],
                       "res": dg.lowpass(res[b], float(t[1] - t[0]),
                                         PAPER_DECISION["filter_tau_s"]),
                       "thr": thr_by_mu[pv.ROAD_MU[0]]}
    return {"cases": cases, "thresholds_n": thr_by_mu,
            "false_alarms": int(np.count_nonzero(dec.flaw[normal])),
            "missed": int(np.count_nonzero(~dec.flaw[faulty])),
            "runs": int(np.count_nonzero(ev)), "cal_runs": int(np.count_nonzero(cal)),
            "timing_s": {"plant": t_sim - t_start, "observer": t_obs - t_sim,
                         "reference": t_ref - t_obs},
            "observer_steps": int(ev.size * t.size), "plot": plot}


def metro_experiment(cfg: ExperimentConfig) -> dict[str, Any]:
    """Metro car: (service brake, ATO steps) x (dry, wet) x (normal, pad, wheel)."""
    p = mc.MetroCarParams()
    t_start = time.perf_counter()
    conds = [(m, mu) for m in range(2) for mu in mc.METRO_RAILS]
    rng = np.random.default_rng(cfg.seed + 1)
    rng_cal = np.random.default_rng(cfg.seed + 1001)
    scen: list[mc.MetroScenario] = []
    cond_idx: list[int] = []
    kinds: list[str] = []
    for ci, (m, mu) in enumerate(conds):
        for kind, n, r in (("cal", cfg.n_cal, rng_cal), ("none", cfg.n_normal, rng),
                           ("pad", cfg.n_fault, rng), ("wheel", cfg.n_fault, rng)):
            for _ in range(n):
                fault = "none" if kind == "cal" else kind
                mu_b = None if fault == "pad" else float(r.uniform(0.31, 0.39))
                scen.append(mc.MetroScenario(m, mu, fault, mu_b=mu_b,
                                             mass_scale=float(r.uniform(0.9, 1.25)),
                                             adh_scale=float(r.uniform(0.85, 1.15)),
                                             grade=float(r.uniform(-0.03, 0.03))))
                cond_idx.append(ci)
                kinds.append(kind)
    ci_arr = np.array(cond_idx)
    kind_arr = np.array(kinds)
    log = mc.simulate_metro(p, scen)
    meas = mc.measure_metro(log, mc.MetroSensorNoise(), rng)
    t_sim = time.perf_counter()
    mu_rail = np.array([s.mu_rail for s in scen])
    obs = mc.run_metro_batch(p, meas, log.mass, mu_rail)
    t_obs = time.perf_counter()
    t = log.t[0]
    valid = (meas["fc"] > 2000.0) & (obs["x"][..., mc.M_IV] > 2.0 * p.v_min)[..., None]
    base = mc.default_metro_decision(p)
    cal = kind_arr == "cal"
    lv = dg.sustained_level(obs["res_norm"][cal], t, base.persistence_s, base.gate_s,
                            base.filter_tau_s, valid[cal])
    thr_scalar = float(MARGIN * lv.max())
    dcfg = mc.default_metro_decision(p, thr_scalar)
    dec = dg.decide(obs["mu_b"], obs["std"][..., mc.M_IMUB], obs["res_norm"], t, dcfg, valid)
    mu_true = log.mu_b[:, -1]
    cases = []
    for ci, (m, mu) in enumerate(conds):
        rail = "dry" if mu == mc.METRO_RAILS[0] else "wet"
        for fault, label in (("none", "normal"), ("pad", "abnormal pad"),
                             ("wheel", "defective wheelset axle 2")):
            sel = (ci_arr == ci) & (kind_arr == fault)
            name = f"metro {mc.METRO_MANEUVERS[m]} {rail} rail (mu_max {mu}) {label}"
            cases.append(summarise(name, "metro", fault, sel, dec, obs["mu_b"], mu_true, t,
                                   obs["forces"], log.force,
                                   {"maneuver": mc.METRO_MANEUVERS[m], "rail_mu": mu,
                                    "brake_onset_s": mc.METRO_BRAKE_ONSET_S}))
    ev = ~cal
    normal = ev & (kind_arr == "none")
    faulty = ev & (kind_arr != "none")
    plot = {}
    for fault in ("none", "pad", "wheel"):
        b = int(np.flatnonzero((ci_arr == 0) & (kind_arr == fault))[0])
        plot[fault] = {"t": t, "est": obs["forces"][b], "target": obs["target"][b],
                       "truth": log.force[b], "mu_b": obs["mu_b"][b],
                       "mu_b_std": obs["std"][b, :, mc.M_IMUB], "mu_b_true": mu_true[b],
                       "res": dg.lowpass(obs["res_norm"][b], float(t[1] - t[0]),
                                         dcfg.filter_tau_s), "thr": thr_scalar}
    return {"cases": cases, "threshold": thr_scalar, "cal_level": float(lv.max()),
            "false_alarms": int(np.count_nonzero(dec.flaw[normal])),
            "missed": int(np.count_nonzero(~dec.flaw[faulty])),
            "runs": int(np.count_nonzero(ev)), "cal_runs": int(np.count_nonzero(cal)),
            "timing_s": {"plant": t_sim - t_start, "observer": t_obs - t_sim},
            "observer_steps": int(ev.size * t.size), "plot": plot}


def speed_metro(n_steps: int = 3000, seed: int = 0) -> dict[str, float]:
    """Single-core speed of the metro observer on a recorded service-brake run.

    Rates are per CPU second of this process (``time.process_time``), so that other
    load on a shared machine does not distort them; ``*_wall`` are per wall second.

    Returns:
        ``ukf_steps_per_s`` (predict + update of the bare UKF) and
        ``observer_updates_per_s`` (the full :class:`MetroBrakeObserver.update`, with
        residuals and decision logic), plus the wall-clock variants.
    """
    p = mc.MetroCarParams()
    log = mc.simulate_metro(p, [mc.MetroScenario(0, 0.3)], t_end=8.0)
    meas = mc.measure_metro(log, mc.MetroSensorNoise(), np.random.default_rng(seed))
    y, fc = meas["y"][0], meas["fc"][0]
    nt = y.shape[0]
    ukf = mc.make_metro_ukf(p, 0.02, float(y[0, 5]), omega0=y[0, :4])
    us = np.concatenate((fc, np.zeros_like(fc), np.full((nt, 1), p.mass)), axis=1)
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n_steps):
        i = k % nt
        ukf.predict(us[i], 0.02)
        ukf.update(y[i], us[i])
    t1, c1 = time.perf_counter(), time.process_time()
    n_obs = min(n_steps, nt)
    reps = max(n_steps // nt, 1)
    for _ in range(reps):
        obs = mc.MetroBrakeObserver(p, 0.02)
        for k in range(n_obs):
            obs.update(0.02 * k, y[k, :4], fc[k], y[k, 4], y[k, 5])
    t2, c2 = time.perf_counter(), time.process_time()
    return {"ukf_steps_per_s": n_steps / (c1 - c0),
            "observer_updates_per_s": reps * n_obs / (c2 - c1),
            "ukf_steps_per_s_wall": n_steps / (t1 - t0),
            "observer_updates_per_s_wall": reps * n_obs / (t2 - t1),
            "state_dim": float(mc.M_NX)}


def speed_paper(n_steps: int = 1500, seed: int = 0) -> dict[str, float]:
    """UKF steps per CPU second of the paper observer (L = 26) on a recorded A1-B1 run."""
    p = pv.PaperVehicleParams()
    log = pv.simulate(p, [pv.Scenario(0, 0.85)])
    meas = pv.measure(log, pv.PaperSensorNoise(), np.random.default_rng(seed))
    y, fc, delta = meas["y"][0], meas["fc"][0], meas["delta"][0]
    u = np.concatenate((delta[:, None], fc), axis=1)
    nt = y.shape[0]
    ukf = pv.make_observer(p)
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n_steps):
        i = k % nt
        if i == 0:
            ukf = pv.make_observer(p)
        ukf.predict(u[i], 0.01)
        ukf.update(y[i], u[i])
    t1, c1 = time.perf_counter(), time.process_time()
    return {"ukf_steps_per_s": n_steps / (c1 - c0), "ukf_steps_per_s_wall": n_steps / (t1 - t0),
            "state_dim": float(pv.N_X)}
