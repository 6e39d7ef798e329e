"""Traffic model, truth variant, TSK model and timetable (Lin 2010a, eq. 1-10) vs hand values."""

import numpy as np
import pytest

from metro_atc.core.atr.blue_line import Period, small_line, taipei_blue
from metro_atc.core.atr.lines import get_line
from metro_atc.core.atr.traffic import (
    control_bounds, exponential_disturbance, linear_model, propagate_linear, schedule_offsets,
    scheduled_d, split_adjustment, timetable_state, truth_step, truth_step_dev, unstagger)
from metro_atc.core.atr.tsk import dispatch_instants, membership, timetable, tsk_step

OFF = dict(saturation=False, knock_on=False, crowding=False)


def test_linear_model_structure():
    a, b = linear_model(np.array([0.1, 0.2, 0.05]))
    # diagonal -c/(1-c), sub-diagonal 1/(1-c_i) of the receiving station, B = diag(1/(1-c))
    assert a[0, 0] == pytest.approx(-0.1 / 0.9)
    assert a[1, 1] == pytest.approx(-0.25)
    assert a[1, 0] == pytest.approx(1.25)
    assert a[2, 1] == pytest.approx(1.0 / 0.95)
    assert a[0, 1] == 0.0 and a[2, 0] == 0.0 and a[0, 2] == 0.0
    np.testing.assert_allclose(np.diag(b), [1 / 0.9, 1.25, 1 / 0.95])
    with pytest.raises(ValueError):
        linear_model(np.array([0.6]))


def test_schedule_offsets_by_hand():
    line = small_line(3, headway_s=120.0)   # c = 0.06 * 3000 / 3600 = 0.05
    assert line.c()[0] == pytest.approx(0.05)
    # dwell 20 + 0.05*120 = 26; run 80
    np.testing.assert_allclose(schedule_offsets(line), [26.0, 132.0, 238.0])
    np.testing.assert_allclose(timetable_state(line, 0), [-94.0, -108.0, -122.0])


def test_one_step_propagation_by_hand():
    line = small_line(3, headway_s=120.0)
    x1 = truth_step_dev(line, np.array([30.0, 0.0, 0.0]), np.zeros(3), **OFF)
    # train 0 at station 0: arrives 0, predecessor left -94+30 = -64, gap 84 s,
    # boarding 0.05*84/0.95 -> dep 24.4211 vs 26 scheduled
    d0 = 0.0 + 20.0 + 0.05 * 84.0 / 0.95 - 26.0
    # train -1 at station 1: arrives -64+80 = 16, predecessor left -108, gap 144 s
    d1 = 16.0 + 20.0 + 0.05 * 144.0 / 0.95 - 12.0
    np.testing.assert_allclose(x1, [d0, d1, 0.0], atol=1e-9)
    np.testing.assert_allclose([d0, d1], [-1.5789473684, 31.5789473684], atol=1e-8)
    a, b = linear_model(line.c())
    np.testing.assert_allclose(a @ np.array([30.0, 0.0, 0.0]), x1, atol=1e-9)


def test_knock_on_and_crowding_by_hand():
    line = small_line(3, headway_s=120.0)
    x1 = truth_step_dev(line, np.array([100.0, 0.0, 0.0]), np.zeros(3))
    # follower may arrive only 60 s after the predecessor left at -94+100 = 6 -> 66
    d0 = 66.0 + 20.0 + 0.05 * (66.0 - 6.0 + 20.0) / 0.95 - 26.0
    # delayed train at station 1: arrives 86, gap 86+108+20 = 214 > 0.95*120 = 114 (crowding)
    gap = 214.0
    board = 0.05 * gap / 0.95 * (1.0 + 0.5 * min(gap / 114.0 - 1.0, 1.0))
    d1 = 86.0 + 20.0 + board - 12.0
    np.testing.assert_allclose(x1, [d0, d1, 0.0], atol=1e-9)


def test_saturation_split_by_hand():
    line = small_line(3)
    du_run, du_dwell = split_adjustment(line, np.array([-30.0, -30.0, 100.0]))
    # station 0 has no run: dwell cut to its minimum (-5); station 1: run -6, dwell -5;
    # station 2: run +12 (max running time 92), holding capped at 60
    np.testing.assert_allclose(du_run, [0.0, -6.0, 12.0])
    np.testing.assert_allclose(du_dwell, [-5.0, -5.0, 60.0])
    lo, hi = control_bounds(line)
    np.testing.assert_allclose(lo, [-5.0, -11.0, -11.0])
    np.testing.assert_allclose(hi, [60.0, 72.0, 72.0])


def test_truth_equals_linear_model_without_nonlinearities():
    line = taipei_blue()
    a, b = linear_model(line.c())
    rng = np.random.default_rng(3)
    x = rng.normal(0, 20, size=(5, line.n_stations))
    u = rng.normal(0, 5, size=(5, line.n_stations))
    w = rng.exponential(2.0, size=(5, line.n_stations))
    got = truth_step_dev(line, x, u, w_dep=w, **OFF)
    np.testing.assert_allclose(got, x @ a.T + (u + w) @ b.T, atol=1e-9)


def test_steady_state_is_fixed_point_of_truth():
    line = taipei_blue()
    np.testing.assert_allclose(truth_step_dev(line, np.zeros(23), np.zeros(23)), 0.0,
                               atol=1e-9)


def test_truth_respects_saturation_and_separation():
    line = taipei_blue()
    t0 = timetable_state(line, 0)
    t1 = truth_step(line, t0, np.full(23, -500.0), 0.0)
    # a departure cannot come earlier than minimum run + minimum dwell allow
    lo, _ = control_bounds(line)
    free = truth_step(line, t0, lo, 0.0)
    np.testing.assert_allclose(t1, free)
    assert np.all(t1[1:] - t0[:-1] >= line.run_min_s + line.dwell_fixed_min_s[1:] - 1e-9)
    # arrival (departure minus dwell >= fixed min) never within 60 s of the predecessor
    t2 = truth_step(line, t0 + 200.0 * (np.arange(23) == 5), np.zeros(23), 0.0)
    assert t2[5] - (t0[5] + 200.0) >= line.separation_min_s + line.dwell_fixed_min_s[5]


def test_staggered_propagation_matches_unstaggered_recursion():
    line = small_line(4, headway_s=100.0)
    h = 100.0
    a, b = linear_model(line.c())
    c = line.c()
    off = schedule_offsets(line, h)
    n_steps = 6
    drive = np.tile(scheduled_d(line, 0.0), (n_steps, 1))
    drive[:, 0] += np.arange(n_steps) * h          # dispatch z_k = k H
    drive[2, 1] += 7.0                              # t(3) entry 1 = train 1 at station 1
    tab = unstagger(propagate_linear(a, b, timetable_state(line, 0, h), drive))
    # hand recursion t_i^m = (t_{i-1}^m + R + S + w - c_i t_i^{m-1}) / (1 - c_i)
    dep = {(m, i): m * h + off[i] for m in range(-5, 0) for i in range(4)}
    for m in range(3):
        for i in range(4):
            up = m * h if i == 0 else dep[(m, i - 1)] + 80.0
            w = 7.0 if (m, i) == (1, 1) else 0.0
            dep[(m, i)] = (up + 20.0 + w - c[i] * dep[(m - 1, i)]) / (1.0 - c[i])
            assert tab[(m, i)] == pytest.approx(dep[(m, i)], abs=1e-9)
    assert dep[(1, 1)] - (h + off[1]) == pytest.approx(7.0 / (1.0 - c[1]))


def test_tsk_membership_is_crisp_and_closed_at_the_end():
    per = [Period(0.0, 10.0, 5.0, 1.0), Period(10.0, 20.0, 2.0, 0.5)]
    np.testing.assert_array_equal(membership(0.0, per), [1, 0])
    np.testing.assert_array_equal(membership(9.999, per), [1, 0])
    np.testing.assert_array_equal(membership(10.0, per), [0, 1])
    np.testing.assert_array_equal(membership(20.0, per), [0, 1])
    np.testing.assert_array_equal(membership(20.5, per), [0, 0])
    np.testing.assert_allclose(dispatch_instants(per), [0, 5, 10, 12, 14, 16, 18])


def test_timetable_single_period_is_steady_state():
    line = small_line(3, headway_s=120.0)
    tt = timetable(line, n_trains=5)
    expected = np.arange(5)[:, None] * 120.0 + schedule_offsets(line)[None, :]
    np.testing.assert_allclose(tt, expected, atol=1e-9)


def test_timetable_switches_headway_with_period():
    line = small_line(3, headway_s=120.0)
    per = [Period(0.0, 600.0, 120.0, 1.0), Period(600.0, 2000.0, 300.0, 0.5)]
    tt = timetable(line, per)
    heads = np.diff(tt[:, 0])
    assert heads[0] == pytest.approx(120.0)
    assert heads[-1] == pytest.approx(300.0)
    # in the second period the dwell follows c = t_b p * 0.5 and headway 300 s
    dwell2 = 20.0 + 0.025 * 300.0
    assert tt[-1, 1] - tt[-1, 0] == pytest.approx(80.0 + dwell2)
    # and each step equals the blended TSK rule (eq. 9/10)
    out = tsk_step(line, per, np.array([tt[2, 0], tt[1, 1], tt[0, 2]]), np.zeros(3),
                   np.zeros(3), 3 * 120.0)
    assert out[1] == pytest.approx(tt[2, 1])
    assert out[2] == pytest.approx(tt[1, 2])


def test_exponential_disturbance_statistics_and_line_lookup():
    w = exponential_disturbance(np.random.default_rng(0), 2.0, (40000,))
    assert np.all(w >= 0.0)
    assert w.mean() == pytest.approx(2.0, rel=0.03)
    assert np.all(exponential_disturbance(np.random.default_rng(0), 0.0, (3,)) == 0.0)
    assert get_line("taipei_blue").n_stations == 23           # the scenario, as the ATS sees it
    assert get_line("blue_line_estimates").separation_min_s == 60.0
    assert get_line("small5").n_stations == 5
    with pytest.raises(ValueError):
        get_line("nowhere")


def test_blue_line_data_is_consistent():
    line = taipei_blue()
    assert line.station_codes[0] == "BL01" and line.station_codes[-1] == "BL23"
    assert line.distance_m.mean() == pytest.approx(1280.0)
    assert np.all(line.run_min_s < line.run_s) and np.all(line.run_s < line.run_max_s)
    # scheduled arrival leaves room for the minimum separation (no knock-on in steady state)
    gap = line.headway_s * (1 - line.c()) - line.dwell_fixed_s
    assert np.all(gap >= line.separation_min_s)
