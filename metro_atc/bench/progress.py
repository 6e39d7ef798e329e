"""Progress rows of the benches on stderr.

A bench reports how far it is (``done`` of ``total`` in its own unit: simulated seconds,
runs, lines), the rate and the ETA, at most once per ``period_s`` of wall time and once at
the end. Rows go to stderr, so ``--json`` keeps stdout one JSON object. Shown when stderr is
a terminal, or as the environment variable ``METRO_ATC_PROGRESS`` says (``always`` /
``never``).
"""

from __future__ import annotations

import math
import os
import sys
import time
from typing import Any, Iterable, Iterator, Optional, TypeVar

T = TypeVar("T")

PROGRESS_ENV = "METRO_ATC_PROGRESS"
"""``always``: progress rows even when stderr is not a terminal; ``never``: none."""


def progress_enabled(stream: Any = None) -> bool:
    """Whether progress rows are shown (:data:`PROGRESS_ENV`, else stderr is a terminal)."""
    mode = os.environ.get(PROGRESS_ENV, "auto").strip().lower()
    if mode == "always":
        return True
    if mode == "never":
        return False
    s = sys.stderr if stream is None else stream
    try:
        return bool(s.isatty())
    except (AttributeError, ValueError):
        return False


def eta_text(seconds: float) -> str:
    """``3 min 05 s`` (or ``?`` when unknown)."""
    if not math.isfinite(seconds) or seconds < 0.0:
        return "?"
    return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"


class Progress:
    """Rate-limited progress rows of one bench phase (module docstring).

    ``label`` names the bench and phase, ``total`` the work in ``unit`` (0: unknown).
    ``rate_name``: with simulated seconds as the unit, the rate is the real-time factor.
    """

    def __init__(self, label: str, total: float, unit: str = "runs", period_s: float = 2.0,
                 stream: Any = None, enabled: Optional[bool] = None,
                 rate_name: str = "") -> None:
        """Start the wall clock of the phase."""
        self.label, self.total, self.unit = label, float(total), unit
        self.period_s = float(period_s)
        self.stream = sys.stderr if stream is None else stream
        self.enabled = progress_enabled(self.stream) if enabled is None else bool(enabled)
        self.rate_name = rate_name
        self.t0 = time.monotonic()
        self._next = self.t0 + self.period_s
        self.rows = 0

    def row(self, done: float, note: str = "") -> str:
        """The progress text for ``done`` units (rate = done / wall time; ETA from it)."""
        wall = max(time.monotonic() - self.t0, 1e-9)
        rate = float(done) / wall
        left = (self.total - float(done)) / rate if rate > 0.0 and self.total > 0 else math.nan
        of = f" / {self.total:.0f}" if self.total > 0 else ""
        rate_txt = f"{rate:.1f}x real time" if self.rate_name == "rtf" else \
            f"{rate:.2f} {self.unit}/s"
        extra = f", {note}" if note else ""
        return (f"{self.label}: {float(done):.0f}{of} {self.unit}{extra}, {rate_txt}, "
                f"ETA {eta_text(left) if self.total > 0 else '?'}")

    def update(self, done: float, note: str = "", force: bool = False) -> bool:
        """Print a row if the period has passed (or ``force``); True if printed."""
        if not self.enabled:
            return False
        now = time.monotonic()
        if not force and now < self._next:
            return False
        self._next = now + self.period_s
        print(self.row(done, note), file=self.stream, flush=True)
        self.rows += 1
        return True


def progress_each(label: str, items: Iterable[T], unit: str = "items",
                  total: Optional[int] = None, period_s: float = 2.0, stream: Any = None,
                  enabled: Optional[bool] = None) -> Iterator[T]:
    """Yield ``items`` (lazily), printing progress rows (done / total, rate, ETA) as they go.

    ``total``: the number of items when ``items`` has no length (e.g. ``pool.map``).
    A row before the first item, then at most one per ``period_s``, and one when all are
    done; nothing when progress is disabled (:func:`progress_enabled`).
    """
    n = int(total) if total is not None else len(items)  # type: ignore[arg-type]
    prog = Progress(label, n, unit, period_s=period_s, stream=stream, enabled=enabled)
    prog.update(0, force=True)
    k = 0
    for k, x in enumerate(items):
        if k:
            prog.update(k)
        yield x
    prog.update(n, "done", force=True)
