"""Expensive fixture work started at session start, in background threads.

Most of the suite's wall time on two cores is single-threaded unit tests (one core busy)
and graph runs that wait on DDS discovery, lockstep round trips and child processes. A
*job* is the expensive, self-contained part of a fixture (graph runs with their probes, a
lint subprocess): it is registered under the name of the fixture that returns its result
(:func:`job`), and ``conftest`` starts the jobs the selected tests need right after
collection, on ``LANES`` background lanes, in the order their first consumer runs. The
fixture then only collects the result (:func:`result`): it waits if the job is still
running, starts it at once if no lane has reached it yet, and re-raises what the job
raised (a failed run fails its tests exactly as before).

A job gets its own temporary directory and allocates its own DDS domains
(``harness.DomainAllocator``); it must clean up everything it starts before it returns
(a ``finally``), and it must not print (the output would land in whatever test runs at
that moment): what it wants printed goes into its result and the fixture prints it.

``METRO_ATC_TEST_LANES`` sets the number of lanes (default 1: with the main thread, two
busy cores; 0 runs every job in its fixture, when the consumer asks, as before).
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any, Callable

JobFn = Callable[[Path], Any]

_REGISTRY: dict[str, JobFn] = {}
LANES = int(os.environ.get("METRO_ATC_TEST_LANES", "1"))
"""Background lanes (threads running jobs one after another)."""


def job(name: str) -> Callable[[JobFn], JobFn]:
    """Register ``fn(tmp_dir) -> result`` as the job behind fixture ``name``."""
    def deco(fn: JobFn) -> JobFn:
        _REGISTRY[name] = fn
        return fn
    return deco


def registered() -> set[str]:
    """Names of the registered jobs (= the fixtures they feed)."""
    return set(_REGISTRY)


class Job:
    """One run of a registered job function, in its own thread."""

    def __init__(self, name: str, tmp: Path) -> None:
        """Prepare (not start) the job ``name`` writing under ``tmp``."""
        self.name, self.tmp = name, tmp
        self.fn = _REGISTRY[name]
        self.lock = threading.Lock()
        self.thread: threading.Thread | None = None
        self.value: Any = None
        self.error: BaseException | None = None
        self.t_start = self.t_end = 0.0
        self.started_by = ""

    def start(self, by: str) -> bool:
        """Start the job's thread unless it was started; True if this call started it."""
        with self.lock:
            if self.thread is not None:
                return False
            self.started_by = by
            self.thread = threading.Thread(target=self._run, name=f"job-{self.name}",
                                           daemon=True)
            self.thread.start()
            return True

    def _run(self) -> None:
        self.t_start = time.monotonic()
        try:
            self.value = self.fn(self.tmp)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the consumer
            self.error = exc
        finally:
            self.t_end = time.monotonic()

    def join(self) -> None:
        """Wait for the job's end (it must have been started)."""
        assert self.thread is not None
        self.thread.join()

    def result(self) -> Any:
        """The job's value (starting it now if no lane has); re-raises its exception."""
        self.start("consumer")
        self.join()
        if self.error is not None:
            raise self.error
        return self.value

    def summary(self) -> str:
        """One line: name, who started it, wall time."""
        if self.thread is None:
            return f"{self.name}: not started"
        return (f"{self.name}: started by {self.started_by}, "
                f"{self.t_end - self.t_start:.1f} s wall")


class Scheduler:
    """Runs jobs on ``lanes`` background threads, each taking the next unstarted job."""

    def __init__(self, jobs: list[Job], lanes: int = LANES) -> None:
        """Jobs in the order their first consumers run."""
        self.jobs = {j.name: j for j in jobs}
        self._order = list(jobs)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.lanes = [threading.Thread(target=self._lane, name=f"lane-{k}", daemon=True)
                      for k in range(max(lanes, 0))]
        for t in self.lanes:
            t.start()

    def _next(self) -> Job | None:
        with self._lock:
            while self._order and not self._stop.is_set():
                j = self._order.pop(0)
                if j.start("lane"):
                    return j
            return None

    def _lane(self) -> None:
        while (j := self._next()) is not None:
            j.join()

    def result(self, name: str) -> Any:
        """The result of job ``name`` (see :meth:`Job.result`)."""
        return self.jobs[name].result()

    def close(self) -> list[str]:
        """Start no more jobs; wait for the running ones (they clean up); their summaries."""
        self._stop.set()
        for j in self.jobs.values():
            if j.thread is not None:
                j.join()
        return [j.summary() for j in self.jobs.values()]
