"""Finished plans shared by the ATO processes of one run, as files.

A plan is a pure function of the line, the train, the run, the planner, its parameters and
the target running time: the ATO processes of a run (each hosting a few trains) would
otherwise plan the same run for the same target once per process, each time holding up the
lockstep (an ECTP plan costs 0.3-0.8 CPU seconds on the Blue line). With a store, the first
process to plan a run writes it, the others read it.

Files are ``.npz`` archives read with ``allow_pickle=False`` (no code runs on load); a file
that cannot be read or does not hold a complete profile is ignored (the plan is computed
again). Written atomically (temporary file, then rename): a reader sees a whole file or
none. The key is a SHA-256 of the plan's memo key (planner, run, target, parameters) plus a
``context`` string naming the line and the train (the caller's), so one store can never
hand a plan of another line or train.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Optional

import numpy as np

from metro_atc.core.ato.planner import Profile

_ARRAYS = ("section_bounds_m", "modes", "codes_mps", "s_grid", "v_profile")
_FLOATS = ("x_start_m", "x_stop_m", "target_running_time_s", "coast_point_m",
           "running_time_s", "energy_j", "compute_s")
_STRINGS = ("planner", "message")


class PlanStore:
    """A directory of finished plans (module docstring)."""

    def __init__(self, directory: "str | Path", context: str = "") -> None:
        """Use (and create) ``directory``; ``context`` names the line and the train."""
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.context = str(context)
        self.hits = 0
        self.writes = 0

    def path(self, memo: Any) -> Path:
        """File of a memo key."""
        h = hashlib.sha256(f"{self.context}|{memo!r}".encode("utf-8")).hexdigest()[:32]
        return self.dir / f"plan_{h}.npz"

    def get(self, memo: Any) -> Optional[Profile]:
        """The stored plan of ``memo``, or None (absent, unreadable or incomplete)."""
        p = self.path(memo)
        try:
            with np.load(p, allow_pickle=False) as z:
                prof = Profile(
                    planner=str(z["planner"]), message=str(z["message"]),
                    feasible=bool(z["feasible"]),
                    **{k: float(z[k]) for k in _FLOATS if k != "compute_s"},
                    section_bounds_m=np.asarray(z["section_bounds_m"], dtype=np.float64),
                    modes=np.asarray(z["modes"], dtype=np.int64),
                    codes_mps=np.asarray(z["codes_mps"], dtype=np.float64),
                    s_grid=np.asarray(z["s_grid"], dtype=np.float64),
                    v_profile=np.asarray(z["v_profile"], dtype=np.float64),
                    compute_s=float(z["compute_s"]))
        except (OSError, KeyError, ValueError, TypeError, EOFError, zipfile.BadZipFile):
            return None
        if prof.s_grid.shape != prof.v_profile.shape or \
                prof.section_bounds_m.size != prof.modes.size + 1 or \
                not math.isfinite(prof.running_time_s):
            return None
        self.hits += 1
        return prof

    def put(self, memo: Any, prof: Profile) -> None:
        """Store a plan (atomically; a failure to write is ignored: the store is a cache)."""
        fields: dict[str, Any] = {k: np.asarray(getattr(prof, k)) for k in _ARRAYS}
        fields.update({k: np.float64(getattr(prof, k)) for k in _FLOATS})
        fields.update({k: np.str_(str(getattr(prof, k))) for k in _STRINGS})
        fields["feasible"] = np.bool_(prof.feasible)
        try:
            fd, tmp = tempfile.mkstemp(dir=self.dir, prefix=".plan_", suffix=".npz")
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, **fields)
            os.replace(tmp, self.path(memo))
            self.writes += 1
        except OSError:
            try:
                os.unlink(tmp)
            except (OSError, UnboundLocalError):
                pass
