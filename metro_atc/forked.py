"""Independent file-writing jobs run on several cores by forked workers (POSIX, ROS-free).

Used for the PNGs of a run (:func:`metro_atc.plots.write_outputs`): each figure is
rendered by its own call from data already in memory, so forked workers need no pickling
and no re-import; the files and their bytes are those of a run one after another.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Callable, Sequence

MAX_WORKERS = 4
"""Most worker processes (this one included)."""


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask; at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def run_jobs(jobs: Sequence[tuple[Path, Callable[[], None]]],
             workers: int | None = None) -> None:
    """Run ``jobs`` (each writes its file) on up to ``workers`` cores.

    ``workers`` default: the usable cores, at most :data:`MAX_WORKERS`.  The jobs are dealt
    round-robin to this process and ``workers - 1`` forked children; a child inherits the
    caller's data and imported modules (nothing is pickled or imported again), runs its
    share and leaves with ``os._exit`` (no atexit handlers, no ROS shutdown in it).  The
    jobs must be independent and touch nothing but their own file.  Where ``fork`` is
    missing, or a child fails, its share is run here (the child's error is on stderr): a
    job's exception then propagates as in a sequential run.
    """
    n = min(len(jobs), usable_cores() if workers is None else max(1, int(workers)),
            MAX_WORKERS)
    if n <= 1 or not hasattr(os, "fork"):
        for _, render in jobs:
            render()
        return
    shares = [list(jobs[k::n]) for k in range(n)]
    children: list[tuple[int, list[tuple[Path, Callable[[], None]]]]] = []
    for share in shares[1:]:
        sys.stdout.flush()
        sys.stderr.flush()
        try:
            pid = os.fork()
        except OSError:
            shares[0] += share
            continue
        if pid == 0:  # pragma: no cover - the child (its coverage is not collected)
            code = 0
            try:
                for _, render in share:
                    render()
            except BaseException:  # noqa: BLE001 - report, the parent renders it again
                import traceback
                traceback.print_exc()
                code = 1
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(code)
        children.append((pid, share))
    for _, render in shares[0]:
        render()
    for pid, share in children:
        _, status = os.waitpid(pid, 0)
        if os.waitstatus_to_exitcode(status) != 0:
            print(f"forked: the worker writing {[str(p.name) for p, _ in share]} failed "
                  f"(exit status {status}); writing them here", file=sys.stderr)
            for _, render in share:
                render()
