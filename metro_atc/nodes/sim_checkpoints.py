"""The line_simulator's resume store: periodic checkpoints and the departure journal.

Every ``checkpoint_period_s`` of simulated time the simulator's full state (the plant with
its event log and RNG states, and the node's own counters: the caller's ``state``) is
captured and written to ``<folder>/line_simulator.npz`` by a thread, atomically
(:meth:`Checkpoints.save`).  Every departure command the simulator applies is appended,
with its step, to ``line_simulator_departures.jsonl`` *before* it is applied
(:meth:`Checkpoints.journal`).  A process that finds a checkpoint resumes from it
(:meth:`Checkpoints.open`) and re-applies the journaled departure commands of the steps
after it at their steps (:meth:`Checkpoints.take_replay`).  Steps are lockstep step
indices; times are simulated seconds.
"""

from __future__ import annotations

import json
import math
import os
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Mapping

import numpy as np

from metro_atc.core.checkpoint import CheckpointError, capture, read, restore, save_tree
from metro_atc.core.journal import read_entries
from metro_atc.core.plant.snapshot import static_parts
from metro_atc.nodes.common import NodeConfigError

CHECKPOINT_FILE = "line_simulator.npz"
"""The simulator's checkpoint in ``checkpoint_dir`` (replaced atomically)."""
STARTED_MARKER = "line_simulator.started"
"""Written in ``checkpoint_dir`` at the first start: a process that finds it is a respawn."""
DEPARTURE_JOURNAL = "line_simulator_departures.jsonl"
"""Departure commands applied, one JSON line each (step, train, station, values)."""


def journal_key(e: Mapping[str, Any]) -> tuple[Any, ...]:
    """Return a journal line's command: (train, station, departure, run, dwell, regulator).

    Departure time, running time and dwell limit in seconds; the regulator as its code.
    """
    return (int(e["i"]), int(e["st"]), float(e["dep"]), float(e["run"]), float(e["dwell"]),
            int(e["reg"]))


def nan_key(key: tuple[Any, ...]) -> tuple[Any, ...]:
    """A hashable key where NaN equals NaN (NaN marks an unset value)."""
    return tuple("nan" if isinstance(x, float) and math.isnan(x) else x for x in key)


def read_journal(path: Path) -> list[dict[str, Any]]:
    """The departure journal's entries (a torn or foreign line ends it)."""
    return read_entries(path, lambda e, _: bool((journal_key(e), int(e["k"]))))


class Checkpoints:
    """Checkpoints and the departure journal in ``folder`` ('' : none, every call a no-op).

    ``identity``: what a checkpoint must have been made for (scenario content, seed,
    parameters); ``period_s``: simulated time between checkpoints [s] (0: none);
    ``control_period_s``: the lockstep step [s]; ``logger``: the node's logger;
    ``warn(key, text)``: a rate-limited warning.
    """

    def __init__(self, folder: str, identity: str, period_s: float, control_period_s: float,
                 logger: Any, warn: Callable[[str, str], None]) -> None:
        """Nothing opened yet (:meth:`open`)."""
        self.folder = Path(folder) if folder else None
        self.identity = identity
        period = float(period_s) / float(control_period_s)
        self.every = max(int(round(period)), 1) if period > 0 else 0
        """Steps between checkpoints (0: none)."""
        self.replay: list[dict[str, Any]] = []
        """Journaled departure commands still to re-apply after a resume (in order)."""
        self.journaled: set[tuple[Any, ...]] = set()
        """Departure commands of the journal (a late copy from the ATS is not re-applied)."""
        self.resumed_from = -1
        """The step of the checkpoint resumed from (-1: a fresh start)."""
        self.first_start = True
        """No earlier process of this run (see :data:`STARTED_MARKER`)."""
        self._log = logger
        self._warn = warn
        self._journal: Any = None
        self._writer: threading.Thread | None = None
        """The thread writing the last checkpoint (:meth:`save`)."""
        self._failed: str | None = None
        """Why the last checkpoint write failed (reported by :meth:`wait`)."""

    def open(self, line: Any, state: Mapping[str, Any]) -> SimpleNamespace | None:
        """Resume from the folder's checkpoint if there is one; open the departure journal.

        ``line``: the plant (restored in place); ``state``: the node's checkpointed values
        by name (their current ones: the restore's templates).  Returns the restored values
        (``.k``: the step; one attribute per name of ``state``), or None without a
        checkpoint. Raises :class:`NodeConfigError` for a checkpoint that cannot be resumed.
        """
        folder = self.folder
        if folder is None:
            return None
        folder.mkdir(parents=True, exist_ok=True)
        marker = folder / STARTED_MARKER
        self.first_start = not marker.exists()
        marker.touch()
        ck = folder / CHECKPOINT_FILE
        journal = folder / DEPARTURE_JOURNAL
        holder = None
        if ck.is_file():
            try:
                head, arrays = read(ck, identity=self.identity)
                holder = SimpleNamespace(line=line, **state)
                restore(holder, head["tree"], arrays, static_parts(line))
            except (CheckpointError, KeyError, TypeError, ValueError, IndexError) as exc:
                raise NodeConfigError(f"cannot resume from {ck}: {str(exc)[:200]}") from None
            self.resumed_from = int(holder.k)
            self._log.warning(
                f"resuming from the checkpoint of step {holder.k} (t={line.t:.2f} s) in "
                f"{folder}")
        for tmp in folder.glob(f".{CHECKPOINT_FILE}.*.tmp"):
            tmp.unlink(missing_ok=True)  # a checkpoint being written when the node died
        entries = read_journal(journal)
        if entries:
            # resumed, or restarted before the first checkpoint (then from step 0): the
            # departure commands since are re-applied at their steps, not taken again
            self.journaled = {nan_key(journal_key(e)) for e in entries}
            self.replay = [e for e in entries if int(e["k"]) >= max(self.resumed_from, 0)]
        # rewrite the journal with the entries kept (a torn last line is dropped)
        tmp = journal.with_name(journal.name + ".tmp")
        tmp.write_text("".join(json.dumps(e) + "\n" for e in entries))
        os.replace(tmp, journal)
        self._journal = open(journal, "a", encoding="utf-8")
        return holder

    def is_journaled(self, key: tuple[Any, ...]) -> bool:
        """The departure command ``key`` (:func:`journal_key`'s fields) is in the journal."""
        return nan_key(key) in self.journaled

    def journal(self, k: int, key: tuple[Any, ...]) -> None:
        """Append a departure command about to be applied at step ``k`` to the journal."""
        if self._journal is None:
            return
        i, st, dep, run, dwell, reg = key
        self._journal.write(json.dumps({"k": int(k), "i": int(i), "st": int(st),
                                        "dep": dep, "run": run, "dwell": dwell,
                                        "reg": int(reg)}) + "\n")
        self._journal.flush()  # in the OS: survives a SIGKILL of this process

    def replay_due(self, k: int) -> bool:
        """Journaled departure commands are to be re-applied at step ``k``."""
        return bool(self.replay) and int(self.replay[0]["k"]) <= k

    def take_replay(self, k: int) -> list[dict[str, Any]]:
        """The journaled departure commands of the steps up to ``k`` not re-applied yet."""
        out = []
        while self.replay and int(self.replay[0]["k"]) <= k:
            out.append(self.replay.pop(0))
        return out

    def due(self, k: int) -> bool:
        """A checkpoint is written at step ``k``."""
        return bool(self.folder is not None and self.every) and k != 0 \
            and k % self.every == 0 and k != self.resumed_from

    def save(self, k: int, t: float, line: Any, state: Mapping[str, Any]) -> None:
        """Write the checkpoint of step ``k`` at time ``t`` [s] (atomically) if one is due.

        The state (``line`` and ``state`` as for :meth:`open`) is captured here (copies:
        :func:`metro_atc.core.checkpoint.capture`); the file is written by a thread while the
        lockstep goes on (~60 % of a checkpoint's time: JSON, ``np.savez``, fsync), one file
        at a time.  Until it is renamed into place the previous checkpoint stands: a kill in
        between resumes from that one (the departure journal holds every command since), as
        a kill before this step would.
        """
        if not self.due(k):
            return
        holder = SimpleNamespace(line=line, **state)
        try:
            tree, arrays = capture(holder, static_parts(line))
        except CheckpointError as exc:
            self._warn("checkpoint", f"checkpoint of step {k} not written: {exc}")
            return
        self.wait()
        assert self.folder is not None
        writer = threading.Thread(
            target=self._write, name="checkpoint", daemon=False,
            args=(self.folder / CHECKPOINT_FILE, tree, arrays, int(k), float(t)))
        self._writer = writer
        writer.start()

    def _write(self, path: Path, tree: Any, arrays: list[np.ndarray], step: int,
               t: float) -> None:
        """Write a captured checkpoint (the writer thread); a failure is kept for :meth:`wait`."""
        try:
            save_tree(path, tree, arrays, identity=self.identity, step=step, t=t)
        except Exception as exc:  # noqa: BLE001 - reported by wait, never raised
            self._failed = f"checkpoint of step {step} not written: {exc}"

    def wait(self) -> None:
        """Wait until the checkpoint being written (if any) is in place; log a failure."""
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.join()
        failed, self._failed = self._failed, None
        if failed:
            self._warn("checkpoint", failed)
