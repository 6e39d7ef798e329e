"""The scenario-to-ATO wiring, written once (ROS-free).

:func:`ato_wiring` derives from a scenario and the ATO's settings everything each train's
:class:`~metro_atc.core.ato.onboard.OnboardAto` is built from: rolling stock, track, stop
points, planner and tracker, control period, planning limits inside the ATP envelope,
temporary speed restrictions as the ATO knows them, the ATP model and the planner's
parameters.  The ``ato_controller`` node and the ROS-free closed loop
(:func:`metro_atc.core.closed_loop.run_closed_loop`, what ``bench lines`` measures) both
build their ATOs with :meth:`AtoWiring.onboard`, so the bench measures what the graph runs
(``test/test_ato_wiring.py`` compares the two).
"""

from __future__ import annotations

import dataclasses
import hashlib
import pickle
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

import numpy as np

from metro_atc.core.ato.envelope import OperatingLimits
from metro_atc.core.ato.mmas import MmasParams
from metro_atc.core.ato.onboard import (AtpModel, OnboardAto, TsrZone, atp_model_for,
                                        envelope_limits, tsr_zones)
from metro_atc.core.ato.registry import PLANNERS, TRACKERS
from metro_atc.core.bridge import Timetable, timetable_for, track_for, train_for
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.vehicle import Track, TrainParams


@dataclass(frozen=True)
class MmasSettings:
    """The MMAS planner's settings the node exposes as parameters (defaults: the planner's).

    n_ants: ants per iteration; n_iterations: iterations; n_sections: sections per run.
    """

    n_ants: int = MmasParams.n_ants
    n_iterations: int = MmasParams.n_iterations
    n_sections: int = 50


def planner_params(planner: str, mmas: Optional[MmasSettings] = None) -> dict[str, Any]:
    """Extra parameters of ``planner`` for :func:`metro_atc.core.ato.planner.plan_profile`.

    ``mmas``: the MMAS settings (default :class:`MmasSettings`); other planners take none.
    """
    if PLANNERS.check(planner) != "mmas":
        return {}
    return dataclasses.asdict(mmas if mmas is not None else MmasSettings())


@dataclass(frozen=True)
class AtoWiring:
    """What every train's OnboardAto of a scenario is built from (module docstring).

    stations_m: stop-point chainages [m]; control_period_s [s]; params: the planner's
    extra parameters (:func:`planner_params`).
    """

    train: TrainParams
    track: Track
    stations_m: np.ndarray
    planner: str
    tracker: str
    control_period_s: float
    limits: OperatingLimits
    tsrs: tuple[TsrZone, ...]
    atp: AtpModel
    params: Mapping[str, Any] = field(default_factory=dict)

    def onboard(self, shared: Optional[dict[str, Any]] = None) -> OnboardAto:
        """A fresh OnboardAto of one train (``shared``: the cache of the trains of a process)."""
        return OnboardAto(self.train, self.track, self.stations_m, planner=self.planner,
                          tracker=self.tracker, control_period_s=self.control_period_s,
                          limits=self.limits, shared=shared, tsrs=self.tsrs,
                          atp=self.atp, **dict(self.params))

    def summary(self) -> dict[str, Any]:
        """Every part as a plain value or the SHA-256 of its pickle (equal iff bit-equal)."""
        def digest(obj: Any) -> str:
            return hashlib.sha256(pickle.dumps(obj, protocol=5)).hexdigest()

        return {"planner": self.planner, "tracker": self.tracker,
                "control_period_s": self.control_period_s, "params": dict(self.params),
                "train": digest(self.train), "track": digest(self.track),
                "stations_m": digest(np.asarray(self.stations_m, dtype=float)),
                "limits": digest(self.limits), "tsrs": digest(self.tsrs),
                "atp": digest(self.atp)}


def ato_wiring(scn: Scenario, planner: str = "ectp", tracker: str = "fuzzy",
               mmas: Optional[MmasSettings] = None, tt: Optional[Timetable] = None,
               atp: Optional[AtpModel] = None) -> AtoWiring:
    """The ATO wiring of ``scn`` (module docstring); ValueError for an unknown name.

    ``tt``: the scenario's timetable when the caller has it (else built); ``atp``: an ATP
    model already derived from ``scn`` (the trains of a node process share one; else
    derived here).
    """
    PLANNERS.check(planner)
    TRACKERS.check(tracker)
    train = train_for(scn)
    tt = tt if tt is not None else timetable_for(scn)
    return AtoWiring(
        train=train, track=track_for(scn), stations_m=tt.station_positions_m,
        planner=planner, tracker=tracker, control_period_s=float(scn.sim.control_period_s),
        limits=envelope_limits(scn, train), tsrs=tuple(tsr_zones(scn)),
        atp=atp if atp is not None else atp_model_for(scn, train),
        params=planner_params(planner, mmas))
