"""Plain-float versions of the numpy primitives the per-train ATO calls every step.

The ATO of one train evaluates its reference, envelope and grade tables at one position a
few dozen times per control step; numpy spends more time wrapping a 0-d array than
computing.  These functions give the *same IEEE double* as the numpy call they name for a
single float (graph speed; proven against numpy on many inputs in
``test/test_scalar_math.py``).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import Sequence


def interp1(x: float, xp: Sequence[float], fp: Sequence[float]) -> float:
    """``float(np.interp(x, xp, fp))`` for one float x (xp increasing, len >= 2).

    numpy's algorithm (``arr_interp``): ``fp[0]`` left of ``xp[0]``, ``fp[-1]`` at and right
    of ``xp[-1]``, ``fp[j]`` on a knot, else ``slope (x - xp[j]) + fp[j]`` with the same NaN
    fall-backs; NaN in, NaN out.
    """
    if x != x:
        return x
    n = len(xp)
    j = bisect_right(xp, x) - 1
    if j < 0:
        return fp[0]
    if j >= n - 1:
        return fp[n - 1]
    x0 = xp[j]
    if x0 == x:
        return fp[j]
    y0, y1 = fp[j], fp[j + 1]
    slope = (y1 - y0) / (xp[j + 1] - x0)
    out = slope * (x - x0) + y0
    if out != out:
        out = slope * (x - xp[j + 1]) + y1
        if out != out and y0 == y1:
            out = y0
    return out


def clip1(x: float, lo: float, hi: float) -> float:
    """``float(np.clip(x, lo, hi))`` for one float (NaN stays NaN)."""
    if x < lo:
        x = lo
    if x > hi:
        x = hi
    return x


def maximum1(a: float, b: float) -> float:
    """``float(np.maximum(a, b))``: NaN propagates, ``a`` on a tie."""
    if a != a:
        return a
    return a if a >= b else b


def minimum1(a: float, b: float) -> float:
    """``float(np.minimum(a, b))``: NaN propagates, ``a`` on a tie."""
    if a != a:
        return a
    return a if a <= b else b


def sqrt_or_nan(x: float) -> float:
    """``float(np.sqrt(x))`` for one float: NaN below zero (no exception)."""
    return math.sqrt(x) if x >= 0.0 else math.nan
