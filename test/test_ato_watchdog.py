"""A lost ATO is a CBTC fault (issue 15 item 3): the watchdog and its effect on the plant."""

from __future__ import annotations

import numpy as np
import pytest

from metro_atc.core.ato_watchdog import STOP_EFFORT, AtoWatchdog
from metro_atc.core.plant.line import LineSim
from metro_atc.core.plant.scenario import load_scenario


def test_counts_lost_and_back() -> None:
    """Lost after exactly max_missed consecutive misses; back at the first command."""
    wd = AtoWatchdog(2, max_missed=3)
    act = np.array([True, True])
    eff = np.array([0.7, 0.2])
    got = np.array([False, True])
    kinds = []
    for k in range(5):
        out, ev = wd.apply(k, act, got, eff)
        kinds += [(e.kind, e.train, e.step) for e in ev]
        want = STOP_EFFORT if k >= 2 else 0.7
        assert out[0] == want and out[1] == 0.2
    assert kinds == [("lost", 0, 2)] and wd.losses == 1 and wd.stop_steps == 3
    out, ev = wd.apply(5, act, np.array([True, True]), eff)
    assert [(e.kind, e.missed) for e in ev] == [("back", 5)] and out[0] == 0.7
    # a miss shorter than the limit never stops the train
    for k in range(6, 8):
        out, ev = wd.apply(k, act, got, eff)
        assert out[0] == 0.7 and not ev
    # inactive trains are not counted
    out, ev = wd.apply(8, np.array([False, True]), got, eff)
    assert wd.missed[0] == 2 and not ev
    with pytest.raises(ValueError):
        AtoWatchdog(1, 0)


def test_dead_ato_at_full_traction_is_braked_to_a_stop() -> None:
    """The issue's case: an ATO dies while commanding full traction.

    Without the watchdog the plant keeps the last command (the train runs on at traction);
    with it the train is braked to a standstill within the stopping time of the service
    brake plus the detection delay, and stays there.
    """
    scn = load_scenario("mini")
    speeds = {}
    for use_wd in (False, True):
        sim = LineSim(scn, seed=0)
        wd = AtoWatchdog(sim.n, max_missed=4)
        last = np.zeros(sim.n)
        k_dead = None
        v_dead = 0.0
        for k in range(1200):
            act = np.asarray(sim.active_mask(), dtype=bool)
            st = sim.states()
            moving = bool(act[0]) and st["mode"][0] != 1  # out of the first dwell
            if k_dead is None and moving and st["v_mps"][0] > 12.0:
                k_dead, v_dead = k, float(st["v_mps"][0])
            alive = k_dead is None
            if alive:
                last = np.where(act, 1.0, 0.0)  # full traction for everyone
            got = act.copy()
            got[0] = alive
            eff = wd.apply(k, act, got, last)[0] if use_wd else last
            sim.step(eff)
            if k_dead is not None and k > k_dead + 200:
                break
        assert k_dead is not None
        speeds[use_wd] = (float(sim.states()["v_mps"][0]), v_dead)
    v_end_wd, v_dead = speeds[True]
    assert v_end_wd < 0.05, speeds
    assert speeds[False][0] > 1.0, speeds  # the contrast: without it the train runs on
