"""The ATO planners and trackers: the one list of each (ROS-free, imports nothing heavy).

Planners (:func:`metro_atc.core.ato.planner.plan_profile`): each entry's factory is
``plan(run, name, target_s, fast, cache, params, t0) -> Profile``
(:mod:`metro_atc.core.ato.planner`).  Trackers (:class:`metro_atc.core.ato.controller.AtoCore`):
each entry's factory is the tracker class, called without arguments (default gains).
The ``ato_controller`` node's ``planner`` / ``tracker`` parameters (descriptor and
validation), :class:`~metro_atc.core.ato.controller.AtoCore` and the benches take the names
from here.  Adding a planner or a tracker: one entry here plus its function or class.
"""

from __future__ import annotations

from metro_atc.core.registry import Entry, Registry

_PL = "metro_atc.core.ato.planner"

PLANNERS = Registry("planner", [
    Entry("mmas", "MAX-MIN ant system over section modes and speed codes",
          f"{_PL}:plan_mmas"),
    Entry("dp", "dynamic-programming minimum-energy reference", f"{_PL}:plan_dp"),
    Entry("fotp", "flat-out train profile (no coasting, fastest run)", f"{_PL}:plan_fotp"),
    Entry("fctp", "fixed-point coasting train profile", f"{_PL}:plan_coasting"),
    Entry("ectp", "coasting point searched for the target running time",
          f"{_PL}:plan_coasting"),
    Entry("actp_tc", "adaptive-critic train profile: traction effort and coasting point",
          f"{_PL}:plan_coasting"),
    Entry("actp_c", "adaptive-critic train profile: coasting point only",
          f"{_PL}:plan_coasting"),
])
"""Every speed-profile planner of the ATO."""

TRACKERS = Registry("tracker", [
    Entry("fuzzy", "fuzzy speed controller", "metro_atc.core.ato.fuzzy:FuzzyController"),
    Entry("pi", "proportional-integral speed controller", "metro_atc.core.ato.pi:PIController"),
])
"""Every speed tracker of the ATO."""
