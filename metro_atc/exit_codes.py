"""Process exit codes of ``python -m metro_atc run`` and of the node executables (ROS-free).

One table for the launcher, the ``line_simulator`` and the other nodes: 0 only when the
whole service ran and its outputs were written; every other end has its own code and one
line on stderr naming what did not happen and why.
"""

from __future__ import annotations

import enum
from typing import Any, Mapping


class Exit(enum.IntEnum):
    """What a run's (or a node process's) exit code means."""

    OK = 0
    """The whole service ran (every train completed its trips) and the outputs were written."""
    ERROR = 1
    """An unexpected error (a traceback on stderr)."""
    REFUSED = 2
    """Input refused before the graph started: an option, scenario, parameter, parameter
    file or regulator weights (one line naming it; nothing was run). A node process that
    exits with it is not restarted."""
    NODE_FAILED = 3
    """A node process failed beyond its respawn limit (one line naming it and its reason)."""
    OUTPUTS_NOT_WRITTEN = 4
    """The run ended but its outputs (``kpis.json``, ``events.csv``, plots, a bag) could not
    all be written (one line naming the file and the error)."""
    SERVICE_INCOMPLETE = 5
    """The scenario ended (its ``sim.duration_s``) before every train completed its trips:
    ``kpis.json`` has ``finished: false`` and ``incomplete_trains``."""
    CUT = 6
    """The run was cut where the user asked (``--duration`` / ``max_sim_time_s``) before
    the service completed: ``kpis.json`` has ``finished: false`` and ``cut_at_s``."""
    GRAPH_NOT_READY = 7
    """The simulator gave up waiting for the graph: some ATO/ATS/brake-diagnosis endpoint
    never appeared within ``startup_timeout_s`` (one line naming what was missing)."""
    TIMEOUT = 124
    """The wall-clock ``--timeout`` stopped the run (as coreutils ``timeout``)."""
    INTERRUPTED = 130
    """Stopped by Ctrl-C / SIGTERM (128 + SIGINT)."""


NORMAL_END = frozenset({Exit.OK, Exit.SERVICE_INCOMPLETE, Exit.CUT})
"""Simulator exit codes of a run that reached its end (its outputs written): the launcher
does not restart it, it reports the run's own outcome."""
NO_RESPAWN = frozenset({Exit.REFUSED, Exit.OUTPUTS_NOT_WRITTEN, Exit.GRAPH_NOT_READY})
"""Node exit codes that a restart cannot mend: the launcher ends the run with the code."""


def outcome(kpis: Mapping[str, Any]) -> tuple[Exit, str]:
    """The exit code of a run that reached its end, from its ``kpis.json``, and why.

    :data:`Exit.OK` only for ``finished: true``; a run cut by ``--duration`` is
    :data:`Exit.CUT`, any other unfinished one :data:`Exit.SERVICE_INCOMPLETE` (the line
    is the KPIs' ``end``: how many trains did not complete and why).
    """
    if kpis.get("finished") is True:
        return Exit.OK, str(kpis.get("end") or "service completed")
    end = str(kpis.get("end") or "the service did not complete (no 'finished' in the KPIs)")
    if kpis.get("cut_at_s") is not None:
        return Exit.CUT, end
    return Exit.SERVICE_INCOMPLETE, end
