"""The choice between the compiled ATO control step and its Python path (ROS-free).

Only the ATO control step keeps a switch (``METRO_ATC_ATO_KERNEL``: numba | python): its
Python path is not a twin but the path every case the kernel declines takes (a TSR in
force, a PI tracker, a hostile state), tested equal to the kernel where both apply.  The
plant, the brake observer and the planners always run compiled (``NUMBA_DISABLE_JIT=1``
runs the same source as Python, for debugging).
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
