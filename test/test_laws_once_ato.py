"""The ATO kernels and planners take the train's laws from :mod:`metro_atc.core.laws`.

Two checks over the source of ``metro_atc/core/ato``: the kernels and planners reference
the laws' functions (by AST: ``laws.<name>`` or ``from metro_atc.core.laws import <name>``),
and no module there writes a law inline (the Davis sum ``A + B v ...``, the constant-power
traction branch ``a3 / (...)``, the gravity constant), comments and strings left out.  The
list of inline expressions that remain (:data:`ALLOWED`, with the reason) is empty and must
match exactly, so a new copy fails.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import numpy as np
import pytest

from metro_atc.core import laws
from metro_atc.core.ato import control_kernel

ATO_DIR = Path(__file__).resolve().parents[1] / "metro_atc" / "core" / "ato"

USES = {
    "step_kernel.py": {"traction_accel", "davis_resistance", "step_force"},
    "tour_kernel.py": {"traction_accel", "davis_resistance", "step_force"},
    "control_kernel.py": {"davis_resistance", "traction_accel"},
    "control_kernel_step.py": {"braking_speed", "ebi_speed_from", "guaranteed_decel_on_grade"},
    "onboard.py": {"ebi_coef"},
    "oracle.py": {"traction_accel_array", "on_array"},
    "planner.py": {"G_MPS2"},
    "sections.py": {"G_MPS2"},
}
"""Module -> the laws it must take from :mod:`metro_atc.core.laws`."""

PATTERNS = {
    "davis": re.compile(r"(davis_a\w*|\[\s*\w*_DA\s*\]|\bda\b)\s*\+\s*[\w.\[\] ]*?"
                        r"(davis_b\w*|\[\s*\w*_DB\s*\]|\bdb\b)\s*\*"),
    "traction": re.compile(r"(\ba3\w*|\[\s*\w*_A3\s*\])\s*/\s*(\(|cpow|math\s*\.\s*pow|q\b)"),
    "gravity": re.compile(r"9\s*\.\s*80665"),
    "atp_curve": re.compile(r"\(\s*b\s*\*\s*tr\s*\)\s*\*\*\s*2"
                            r"|sqrt\s*\(\s*2\.0\s*\*\s*b\s*\*|\bq\s*=\s*c0\s*\+"),
}
"""Inline forms of the laws (on the code's tokens joined by single spaces)."""

ALLOWED: dict[tuple[str, str], int] = {}
"""(module, law) -> inline occurrences that remain (with the reason)."""


def _code(path: Path) -> str:
    """The module's tokens without comments and strings, joined by single spaces."""
    toks = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    return " ".join(t.string for t in toks if t.type not in (tokenize.COMMENT, tokenize.STRING))


def _laws_used(path: Path) -> set[str]:
    """Names of :mod:`metro_atc.core.laws` a module references."""
    tree = ast.parse(path.read_text())
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "metro_atc.core.laws":
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id == "laws":
            out.add(node.attr)
    return out


@pytest.mark.parametrize("name", sorted(USES))
def test_kernels_and_planners_use_the_laws(name: str) -> None:
    """Each listed module references its laws, and they exist in :mod:`.laws`."""
    used = _laws_used(ATO_DIR / name)
    assert USES[name] <= used, (name, USES[name] - used)
    for law in used:
        assert hasattr(laws, law), (name, law)


def test_no_inline_law_in_core_ato() -> None:
    """No module of core/ato writes a law inline beyond the listed remainder."""
    found: dict[tuple[str, str], int] = {}
    for path in sorted(ATO_DIR.glob("*.py")):
        code = _code(path)
        for law, pat in PATTERNS.items():
            n = len(pat.findall(code))
            if n:
                found[(path.name, law)] = n
    assert found == ALLOWED


def test_patterns_find_the_old_forms() -> None:
    """The scan recognises the expressions the kernels wrote before (it can fail)."""
    old = ("f = delta * ( c [ K_MASS ] * phi ) - ( c [ K_DA ] + c [ K_DB ] * v + c [ K_DC ] "
           "* v * v ) - fg",
           "phi = p [ P_A3 ] / ( va + p [ P_B3 ] + 1e-12 ) ** 2",
           "return c [ k + 4 ] / math . pow ( va , 2.0 )",
           "G = 9 . 80665",
           "cc = math . sqrt ( 2.0 * b * ( 0.0 if 0.0 > d else d ) )",
           "q = c0 + c . two_b * ( d - c . t_sbi * v )")
    hits = [any(p.search(s) for p in PATTERNS.values()) for s in old]
    assert hits == [True, True, False, True, True, True]
    # ``c[k + 4]``: the offset form of the old control kernel is caught by the slot check


def test_control_kernel_has_named_records() -> None:
    """No numbered slots (``C_*``, ``S_*``, ``P_*``, ``K_*``, ``M_*``), no ``c[C_TWO]``."""
    from metro_atc.core.ato import step_kernel, tour_kernel
    for mod in (control_kernel, step_kernel, tour_kernel):
        assert not [n for n in vars(mod) if re.match(r"[CSPKM]_[A-Z]", n)], mod.__name__
    for name in ("control_kernel.py", "control_kernel_step.py", "control_kernel_pack.py"):
        code = _code(ATO_DIR / name)
        assert not re.search(r"\b[cC]\s*\[\s*(C_|k\b)", code), name
        assert not re.search(r"\bst\s*\[\s*S_", code), name
        assert not re.search(r"\bp\s*\[\s*P_", code), name
    assert control_kernel.CONSTANTS.names == control_kernel.CONSTANT_FIELDS
    assert control_kernel.STATE.names == control_kernel.STATE_FIELDS
    assert control_kernel.PLAN.names == control_kernel.PLAN_FIELDS
    assert set(np.dtype(control_kernel.STATE).fields) >= set(control_kernel.CORE_STATE_FIELDS)


def test_cpow_is_cpython_pow() -> None:
    """The kernel's ``cpow`` gives CPython's ``x ** 2`` and ``x ** 3`` bit for bit."""
    from metro_atc.core.ato.step_kernel import jit

    @jit
    def sq_cube(x):  # type: ignore[no-untyped-def]
        return control_kernel.cpow(x, 2.0), control_kernel.cpow(x, 3.0)

    rng = np.random.default_rng(7)
    xs = np.concatenate([rng.uniform(0.0, 60.0, 20000), rng.uniform(-1e3, 1e3, 5000)])
    bad = [x for x in xs.tolist() if sq_cube(x) != (x ** 2, x ** 3)]
    assert not bad
    # products differ from the C pow on some of these values (what cpow is for)
    assert any(x * x != x ** 2 for x in xs.tolist())
