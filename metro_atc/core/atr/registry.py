"""The ATS regulators: the one list of their names (ROS-free, imports nothing heavy).

Each entry maps a regulator name to its factory ``factory(name, inputs)`` (``inputs``: a
:class:`metro_atc.core.atr.regulators.RegulatorInputs`) and a one-line description.  The
launcher's ``--regulator`` choices, the ``ats_regulator`` node's ``regulator`` parameter
(descriptor and validation), :func:`metro_atc.core.atr.regulators.make_regulator`,
:func:`metro_atc.core.atr.dispatch.make_dispatcher`, the ``DepartureCommand.regulator``
codes of :mod:`metro_atc.nodes.conversions` (constant ``REGULATOR_<NAME>``) and the
weights store all take the names from here; ``test/test_name_registries.py`` checks the
``.msg`` constants against it.  Adding a regulator: one entry here, its class and factory,
and its ``REGULATOR_<NAME>`` constant in ``DepartureCommand.msg``.

Flags: ``trained`` -- a trained policy read from a weights file (``python -m metro_atc
train``; :mod:`metro_atc.core.atr.weights_store`); ``prebuilt`` -- the launcher builds it
once before the graph starts so that a regulator that cannot start stops the run early
(the energy-aware LQR is not: its energy table takes seconds, the ATS builds it anyway).
"""

from __future__ import annotations

from metro_atc.core.registry import Entry, Registry

_REG = "metro_atc.core.atr.regulators"

REGULATORS = Registry("regulator", [
    Entry("none", "timetable, no regulation", f"{_REG}:build_none"),
    Entry("lqr", "linear-quadratic regulator on the linear traffic model",
          f"{_REG}:build_lqr", frozenset({"prebuilt"})),
    Entry("dhp", "dual heuristic programming policy (trained weights)",
          f"{_REG}:build_trained", frozenset({"trained", "prebuilt"})),
    Entry("aoc", "adaptive optimal control policy (trained weights)",
          f"{_REG}:build_trained", frozenset({"trained", "prebuilt"})),
    Entry("elqr", "energy-aware LQR (running time traded for traction energy)",
          "metro_atc.core.atr.energy:build_elqr"),
])
"""Every ATS regulator, in the order of the ``DepartureCommand.REGULATOR_*`` codes."""

TRAINED = REGULATORS.with_flag("trained")
"""Regulators read from a weights file (``aoc``, ``dhp``)."""
