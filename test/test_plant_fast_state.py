"""Persistent row blocks of the compiled step (:mod:`metro_atc.core.plant.fast_state`).

The blocks must always hold the components' current values (the kernel reads them) and the
kernel's in-place writes must always reach the components, whatever the components do with
their arrays (edit in place, rebind, deep copy, pickle).
"""

from __future__ import annotations

import copy
import pickle
from operator import attrgetter
from typing import Any

import numpy as np
import pytest

from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.fast_state import Blocks
from metro_atc.core.plant.line import LineSim
from metro_atc.core.plant.snapshot import capture_line, restore_line


class _Part:
    def __init__(self, n: int, k: float) -> None:
        self.own = np.full(n, k)
        self.own2 = np.arange(n) + k
        self.cp = np.full(n, 10.0 * k)
        self.cp2 = np.full(n, 20.0 * k)
        self.derived = np.full(n, 30.0 * k)


def _blocks() -> Blocks:
    rows = ((0, "own", True), (1, "own", True), (0, "cp", False), (1, "cp2", False),
            (0, "derived", None), (0, "own2", True), (1, "own2", True), (1, "cp", False),
            (0, "cp2", False))
    return Blocks((((4,), float, 1, rows),), 2)


def _check(parts: tuple[_Part, _Part], blk: np.ndarray) -> None:
    a, b = parts
    for r, arr in enumerate((a.own, b.own, a.cp, b.cp2, a.derived, a.own2, b.own2, b.cp,
                             a.cp2)):
        np.testing.assert_array_equal(blk[r], arr, err_msg=f"row {r}")


def test_blocks_follow_the_components() -> None:
    """In-place edits, rebinding, derived rows; kernel writes reach the components."""
    parts = (_Part(4, 1.0), _Part(4, 2.0))
    bl = _blocks()
    (blk,) = bl.sync(parts)
    _check(parts, blk)
    a, b = parts
    assert a.own.base is blk and b.own2.base is blk  # owned attributes are row views
    assert a.cp.base is None  # copied ones are not
    blk[0, 1] = 5.0  # the kernel writes an owned row in place
    assert a.own[1] == 5.0
    a.own[2] = 7.0  # the component edits in place
    assert bl.sync(parts)[0][0, 2] == 7.0
    b.own = np.array([9.0, 8.0, 7.0, 6.0])  # the component rebinds an owned array
    (blk,) = bl.sync(parts)
    _check(parts, blk)
    assert b.own.base is blk
    a.cp2[0] = -1.0  # a copied array edited in place, then another one rebound
    a.cp = a.cp * 3.0
    a.derived = a.derived + 1.0
    (blk,) = bl.sync(parts)
    _check(parts, blk)
    assert bl.sync(parts)[0] is blk  # nothing changed: the same block, no copy


def test_blocks_resync_only_the_component_that_rebound() -> None:
    """A rebinding re-packs its own component; the others keep their rows and views."""
    parts = (_Part(4, 1.0), _Part(4, 2.0))
    bl = _blocks()
    (blk,) = bl.sync(parts)
    a, b = parts
    a_own, a_own2 = a.own, a.own2
    blk[2, 0] = -5.0  # stale copy of a.cp: only a rebinding of ``a`` re-packs it
    b.cp = b.cp + 1.0  # component b rebinds a copied array, b edits an owned one in place
    b.own2[3] = 42.0
    (blk,) = bl.sync(parts)
    assert blk[2, 0] == -5.0  # a's copied rows were not copied again
    assert a.own is a_own and a.own2 is a_own2  # nor its owned rows rebound
    np.testing.assert_array_equal(blk[7], b.cp)
    assert blk[6, 3] == 42.0
    a.cp2 = a.cp2 * 2.0  # now a rebinds: all its copied rows again
    (blk,) = bl.sync(parts)
    _check(parts, blk)


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_blocks_copied_with_their_components(how: str) -> None:
    """A copy of (components, blocks) is independent and re-syncs in full."""
    parts = (_Part(4, 1.0), _Part(4, 2.0))
    bl = _blocks()
    bl.sync(parts)
    pair: Any = (parts, bl)
    parts2, bl2 = copy.deepcopy(pair) if how == "deepcopy" else pickle.loads(pickle.dumps(pair))
    (blk2,) = bl2.sync(parts2)
    _check(parts2, blk2)
    assert parts2[0].own.base is blk2
    blk2[0, 0] = 123.0
    assert parts2[0].own[0] == 123.0 and parts[0].own[0] == 1.0
    (blk,) = bl.sync(parts)
    _check(parts, blk)


def test_restored_compiled_plant_continues_like_the_original() -> None:
    """A compiled-kernel plant restored mid-run (fresh blocks) steps like the original."""
    scn = load_scenario("taipei_blue")
    a = LineSim(scn, seed=3)
    for _ in range(1200):
        a.step(simple_driver(a))
    b = LineSim(scn, seed=3)
    tree, arrays = capture_line(a)
    restore_line(b, tree, {f"a{i}": x for i, x in enumerate(arrays)})
    for k in range(400):
        ra, rb = a.step(simple_driver(a)), b.step(simple_driver(b))
        sa, sb = ra.sensor_arrays, rb.sensor_arrays
        assert (sa is None) == (sb is None)
        if sa is not None and sb is not None:
            np.testing.assert_array_equal(sa.omega, sb.omega)
        for name in ("fleet.x", "fleet.v", "atp.eb", "atp.sb", "energy.e_trac",
                     "energy.e_stop_corr", "atp.interventions", "fleet.status", "fleet.stop_x",
                     "atp.speed_code", "energy.n_in_service"):
            np.testing.assert_array_equal(attrgetter(name)(a), attrgetter(name)(b),
                                          err_msg=f"step {k}: {name}")
    assert a.energy.e_trac.sum() > 0.0
    assert b.energy.e_trac.base is b.stepper.state.blocks[0]  # re-packed, not a's memory
