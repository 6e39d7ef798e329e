"""One source for each list of names: regulators, planners, trackers (ROS-free).

The registries (:mod:`metro_atc.core.atr.registry`, :mod:`metro_atc.core.ato.registry`)
are the only lists; the ``DepartureCommand.msg`` constants must name exactly the
registered regulators, in the registry's order, so a regulator added to either side alone
fails here.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from metro_atc.core.ato.registry import PLANNERS, TRACKERS
from metro_atc.core.atr.registry import REGULATORS, TRAINED
from metro_atc.core.registry import Entry, Registry

MSG = Path(__file__).resolve().parents[1] / "msg_defs" / "msg" / "DepartureCommand.msg"


def msg_regulator_constants(text: str) -> dict[str, int]:
    """``REGULATOR_<NAME> = code`` constants of a .msg text, name lowercased -> code."""
    return {m.group(1).lower(): int(m.group(2))
            for m in re.finditer(r"^\s*uint8\s+REGULATOR_([A-Z0-9_]+)\s*=\s*(\d+)", text,
                                 re.MULTILINE)}


def test_msg_constants_match_the_regulator_registry() -> None:
    """Every REGULATOR_* constant is a registered regulator and vice versa, codes in order."""
    consts = msg_regulator_constants(MSG.read_text())
    assert set(consts) == set(REGULATORS.names), (
        f".msg only: {sorted(set(consts) - set(REGULATORS))}; registry only: "
        f"{sorted(set(REGULATORS) - set(consts))}")
    assert [consts[n] for n in REGULATORS] == list(range(len(REGULATORS)))


def test_msg_check_fails_when_either_side_gains_a_name() -> None:
    """The comparison above can fail: a constant or an entry of its own is seen."""
    text = MSG.read_text()
    extra = text + "\nuint8 REGULATOR_MPC = 5\n"
    assert set(msg_regulator_constants(extra)) != set(REGULATORS.names)
    grown = Registry("regulator", [*REGULATORS.values(),
                                   Entry("mpc", "model predictive control", "math:sqrt")])
    assert set(msg_regulator_constants(text)) != set(grown.names)


def test_launcher_choices_and_conversion_codes_come_from_the_registry() -> None:
    """``run --regulator`` choices; trained ones; the train command's methods."""
    from metro_atc import launcher
    from metro_atc.core.atr import weights_store

    parser = launcher._parser()
    action = next(a for a in parser._actions if a.dest == "regulator")
    assert tuple(action.choices) == REGULATORS.names
    assert set(TRAINED) == {"aoc", "dhp"}
    assert weights_store.KINDS == TRAINED


@pytest.mark.parametrize("registry", [REGULATORS, PLANNERS, TRACKERS], ids=lambda r: r.kind)
def test_every_entry_has_a_description_and_an_importable_factory(registry: Registry) -> None:
    """The factories resolve (a moved function fails here, not at a run's start)."""
    assert len(registry) >= 2
    for name, e in registry.items():
        assert e.name == name and e.description
        assert callable(e.load()), name
    assert all(f"{n}: " in registry.help() for n in registry)


def test_unknown_names_are_refused_in_one_line() -> None:
    """An unknown name: ValueError naming the kind and the choices."""
    with pytest.raises(ValueError, match=r"unknown planner 'nope'; choose one of mmas, dp"):
        PLANNERS.check("nope")
    with pytest.raises(ValueError, match="unknown regulator"):
        REGULATORS.check("x")
    assert "pi" in TRACKERS and "nope" not in TRACKERS and TRACKERS.names == ("fuzzy", "pi")


def test_registry_refuses_duplicates_and_malformed_entries() -> None:
    """Two entries of one name, an upper-case name, a factory without ``:``."""
    with pytest.raises(ValueError, match="twice"):
        Registry("x", [Entry("a", "d", "m:f"), Entry("a", "d", "m:g")])
    with pytest.raises(ValueError):
        Entry("A", "d", "m:f")
    with pytest.raises(ValueError):
        Entry("a", "d", "m.f")


def test_the_trackers_and_planners_are_what_the_core_builds() -> None:
    """AtoCore builds the registered tracker class; plan_profile accepts every planner."""
    from metro_atc.core.ato.controller import TRACKERS as CORE_TRACKERS
    from metro_atc.core.ato.fuzzy import FuzzyController
    from metro_atc.core.ato.pi import PIController
    from metro_atc.core.ato.planner import PLANNERS as CORE_PLANNERS

    assert CORE_TRACKERS == TRACKERS.names and CORE_PLANNERS == PLANNERS.names
    assert TRACKERS["fuzzy"].load() is FuzzyController
    assert TRACKERS["pi"].load() is PIController


def test_elqr_needs_its_scenario() -> None:
    """make_regulator builds every regulator by name; elqr without a scenario is refused."""
    from metro_atc.core.atr.lines import atr_line_for
    from metro_atc.core.atr.regulators import LqrRegulator, NoneRegulator, make_regulator
    from metro_atc.core.line.scenario import load_scenario

    line = atr_line_for(load_scenario("mini"))
    assert isinstance(make_regulator("none", line), NoneRegulator)
    assert isinstance(make_regulator("lqr", line), LqrRegulator)
    with pytest.raises(ValueError, match="needs the scenario"):
        make_regulator("elqr", line)
