"""The speed trackers' laws exist once: in :mod:`metro_atc.core.ato.tracker_laws`.

The Li n.d. fuzzy controller (memberships, the 15 rules of Table 1, the incremental form
with anti-windup and the absolute form) and the PI tracker (conditional integration, the
back-calculated integral) are compiled scalar functions there, called by the on-board
ATO's compiled step and by the vector classes ``FuzzyController`` / ``PIController``.
Checks: those modules reference them (AST); no other module of the package defines a
function of the same name; no other module writes a law inline, found by its shape in the
code (comments and strings removed): the rule singletons' products, a membership's clip or
its set-width division, the anti-windup bound ``-1 - u_ff``, the PI terms ``kp e`` and
``ki i``.  The patterns find the copies the package had before the laws were gathered
(:func:`test_patterns_find_the_old_copies`), so a second copy fails.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import numpy as np

from metro_atc.core.ato import tracker_laws
from metro_atc.core.ato.fuzzy import FuzzyController, FuzzyParams
from metro_atc.core.ato.pi import PIController, PIParams

PKG = Path(__file__).resolve().parents[1] / "metro_atc"
HOME = "core/ato/tracker_laws.py"
"""The one module that writes the trackers' laws."""

LAWS = ("clip01", "triangle", "rise", "fall", "e_sets", "d_sets", "flc", "fuzzy_inputs",
        "fuzzy_law", "pi_law", "tracker_state")
"""The laws' functions (each defined in :data:`HOME` only)."""

USERS = {
    "core/ato/control_kernel_step.py": {"fuzzy_inputs", "fuzzy_law", "pi_law",
                                        "tracker_state"},
    "core/ato/fuzzy.py": {"fuzzy_steps", "tracker_states", "flc_many", "memberships"},
    "core/ato/pi.py": {"pi_steps", "tracker_states"},
}
"""Module -> the functions of :data:`HOME` it must call."""

PATTERNS = {
    "rules": re.compile(r"[*@]\s*(?:RULE_MATRIX|R\d+)\b|(?:RULE_MATRIX|\bR\d+)\s*[*@]"),
    "membership": re.compile(r"\bclip01\s*\(|minimum\s*\(\s*up\s*,|\)\s*/\s*0\.5\s*(?:[,)]|$)"),
    "anti_windup": re.compile(r"-\s*1\.0\s*-\s*[\w.]*ff\b"),
    "pi": re.compile(r"\bkp\s*\*\s*[\w.]*\be\b|\bki\s*\*\s*[\w.]*\bi(?:_new)?\b"),
}
"""Inline shapes of the trackers' laws (on the code's tokens joined by single spaces)."""


def _code(path: Path) -> str:
    """The module's tokens without comments and strings, joined by single spaces."""
    toks = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    return " ".join(t.string for t in toks if t.type not in (tokenize.COMMENT, tokenize.STRING))


def _modules() -> list[tuple[str, Path]]:
    """(path relative to the package, path) of every module of the package."""
    return [(p.relative_to(PKG).as_posix(), p) for p in sorted(PKG.rglob("*.py"))]


def test_users_call_the_laws() -> None:
    """The compiled step and the vector classes reference the functions of the laws."""
    for rel, names in USERS.items():
        tree = ast.parse((PKG / rel).read_text())
        used: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module == tracker_laws.__name__:
                used.update(a.name for a in node.names)
        assert names <= used, (rel, names - used)
        calls = {n.func.id for n in ast.walk(tree)
                 if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
        assert names <= calls, (rel, names - calls)


def test_each_law_is_defined_once() -> None:
    """No module but :data:`HOME` defines a function named as one of the laws."""
    where: dict[str, list[str]] = {}
    for rel, path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name in LAWS:
                where.setdefault(node.name, []).append(rel)
    assert where == {name: [HOME] for name in LAWS}


def test_no_inline_tracker_law() -> None:
    """The laws' shapes appear in :data:`HOME` only."""
    found = {(rel, law) for rel, path in _modules() for law, pat in PATTERNS.items()
             if pat.search(_code(path))}
    assert found == {(HOME, law) for law in PATTERNS}


def test_patterns_find_the_old_copies() -> None:
    """The scan recognises the copies the package had before (it can fail)."""
    old = {  # the numpy classes and the compiled step's inline tracker
        "rules": "num = np . sum ( w * RULE_MATRIX , axis = ( - 2 , - 1 ) )",
        "membership": "return np . clip ( np . minimum ( up , down ) , 0.0 , 1.0 )",
        "anti_windup": "self . _u = np . clip ( self . _u + self . p . gain * y , - 1.0 - ff ,"
                       " 1.0 - ff )",
        "pi": "raw = c . kp * e + c . ki * i_new + u_ff",
    }
    for law, code in old.items():
        assert PATTERNS[law].search(code), law
    assert PATTERNS["membership"].search("e0 = clip01 ( ( e_n - 0.5 ) / 0.5 )")
    assert PATTERNS["rules"].search("num = num + w8 * R8")


def test_classes_compute_through_the_laws() -> None:
    """Known answers of the vector classes, as the scalar laws give them.

    At the centre of each e set with d zero only the Z row of Table 1 fires: the absolute
    form with gain 1 gives that singleton; the PI's first step is ``kp e + ki e dt``, and
    its integral freezes while the output saturates with the error.
    """
    fz = FuzzyController(FuzzyParams(e_scale_mps=1.0, d_scale_mps=1.0, gain=1.0,
                                     incremental=False))
    e = np.array([1.0, 0.5, 0.0, -0.5, -1.0])
    u = fz.step(e, np.zeros(5))
    np.testing.assert_array_equal(u, tracker_laws.RULE_MATRIX[1])
    assert [tracker_laws.flc(x, 0.0) for x in e] == list(u)
    p = PIController(PIParams(kp=0.5, ki=0.25))
    u = p.step(np.array([1.0, 10.0]), np.zeros(2), dt_s=0.2)
    assert u[0] == 0.5 * 1.0 + 0.25 * (1.0 * 0.2) and u[1] == 1.0
    assert p._i[1] == 0.0 and p._i[0] == 0.2
    assert tracker_laws.pi_law(0.0, 10.0, 0.2, 0.0, 0.5, 0.25) == (1.0, 0.0)
