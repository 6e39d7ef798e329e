"""Node processes stop when the launcher that started them is gone (no orphaned graphs).

``python -m metro_atc run`` starts every node in its own session (so that it can stop the
process group) and sets :data:`PARENT_PID_ENV` to its own process id. If the launcher is
killed (SIGKILL, OOM killer: no chance to stop its children), the node processes are
re-parented; :func:`watch_parent` notices it and stops the process as SIGTERM would.
ROS-free (used by :mod:`metro_atc.nodes.common` before rclpy starts).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from typing import Mapping

PARENT_PID_ENV = "METRO_ATC_PARENT_PID"
"""Environment variable set by ``python -m metro_atc run`` to its own process id: a node
process whose parent is no longer that process (the launcher was killed, even with SIGKILL)
stops itself (:func:`watch_parent`)."""
PARENT_POLL_S = 0.5
"""Period [s] of the parent check of :func:`watch_parent`."""
ORPHAN_GRACE_S = 20.0
"""Time [s] an orphaned node process gets to stop cleanly after its SIGTERM before it exits
hard (exit code 3)."""


def parent_gone(expected_pid: int) -> bool:
    """True when this process's parent is not ``expected_pid`` any more (re-parented)."""
    return os.getppid() != expected_pid


def _watch_parent_loop(expected_pid: int) -> None:
    while not parent_gone(expected_pid):
        time.sleep(PARENT_POLL_S)
    print(f"{os.path.basename(sys.argv[0]) if sys.argv else 'node'}: launcher (pid "
          f"{expected_pid}) gone, stopping", file=sys.stderr, flush=True)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(ORPHAN_GRACE_S)
    os._exit(3)


def watch_parent(env: Mapping[str, str] | None = None) -> bool:
    """Stop this process when the launcher that started it dies; return True if watching.

    Only when :data:`PARENT_PID_ENV` names a process id (set by the launcher; a node started
    by hand or by ``ros2 launch`` is not watched). A daemon thread polls the parent every
    :data:`PARENT_POLL_S`; once the process is re-parented it sends itself SIGTERM (the
    loops end and the nodes close as on a normal stop; before the handler is installed the
    default action ends the process) and exits hard after :data:`ORPHAN_GRACE_S`.
    """
    raw = (os.environ if env is None else env).get(PARENT_PID_ENV, "")
    try:
        pid = int(raw)
    except ValueError:
        return False
    if pid <= 1:
        return False
    threading.Thread(target=_watch_parent_loop, args=(pid,), name="parent_watch",
                     daemon=True).start()
    return True
