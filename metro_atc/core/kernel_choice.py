"""The choice between a compiled (numba) kernel and its reference path (ROS-free).

The plant step (``METRO_ATC_PLANT_KERNEL``: numba | numpy), the ATO planners' strategy
simulation (``METRO_ATC_PLAN_KERNEL``: numba | numpy) and the ATO control step
(``METRO_ATC_ATO_KERNEL``: numba | python) each keep a reference path that the compiled one
is tested equal to; this module resolves a request to one of the two the same way for all.
"""

from __future__ import annotations

import functools
import importlib.util
import os
from typing import Optional


@functools.lru_cache(maxsize=1)
def numba_available() -> bool:
    """True when numba can be imported (else every kernel runs its reference path)."""
    return importlib.util.find_spec("numba") is not None


def resolve_kernel(name: Optional[str], env_var: str, reference: str, what: str) -> str:
    """``numba`` or ``reference`` for a request (the argument, else ``$env_var``, else auto).

    ``auto``: numba when installed, else the reference. An unknown name raises ValueError,
    ``numba`` without numba RuntimeError (``what`` names the kernel in both messages).
    """
    choices = ("auto", "numba", reference)
    req = (name or os.environ.get(env_var, "") or "auto").strip().lower()
    if req not in choices:
        raise ValueError(f"{what} must be one of {choices}, got {req!r}")
    if req == reference:
        return reference
    if not numba_available():
        if req == "numba":
            raise RuntimeError(f"{what} 'numba' requested but numba is not installed")
        return reference
    return "numba"
