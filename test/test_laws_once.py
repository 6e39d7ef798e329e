"""Each physical law is computed once: in :mod:`metro_atc.core.laws`, called by its users.

For every law: the modules that must call it (the plant, the brake model, the line
description) do, and no other module of the package computes it inline -- found by the
law's shape in the code (comments and strings removed): e.g. the constant-power traction
term ``a3 / (v + b3 ...)``, the Davis products ``davis_c ... * v``, the electric brake's
power limit ``max_regen_power_w / v``, Roeckl's ``650.0 /``.  The patterns match the inline
copies the package had before the laws were gathered (``test_patterns_find_the_old_copies``
keeps them able to fail).

No module computes a law inline (:data:`PENDING` is empty; a module that must, for a
reason stated there, would be listed with it).
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

from metro_atc.core import laws

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "metro_atc"

PATTERNS: dict[str, list[str]] = {
    "traction": [r"\ba[23](?:_\w*)?\s*/\s*\(", r"[KP]_A[23]\]\s*/", r"/\s*\(\s*va\s*\+",
                 r"/\s*math\.pow\(\s*va\s*\+"],
    "davis": [r"davis_a_n\s*\+\s*\w", r"davis_[bc]\w*\s*\*\s*(?:v|va|vm|vs|vi)\b",
              r"\(\s*db\s*\+\s*dc\s*\*", r"[KCP]_D[BC]\]\s*\*\s*v",
              r"\bb\s*\*\s*va\s*\+\s*c\s*\*\s*va"],
    "electric_brake": [r"max_regen_power_w\s*/", r"/\s*[\w.]*regen_fade_speed_mps"],
    "burckhardt": [r"1\.0\s*-\s*(?:np|math)\.exp\(\s*-\s*(?:self\.)?c2\b"],
    "grade": [r"sin\(\s*(?:np|math)\.(?:arctan|atan)\("],
    "roeckl": [r"650\.0\s*/", r"500\.0\s*/"],
    "atp_curve": [r"\(\s*b\s*\*\s*tr\s*\)\s*\*\*\s*2", r"sqrt\(\s*_mx\(\s*c0\s*\+",
                  r"(?:C_C0A|[\"']c0a[\"'])\]\s*\+", r"0\.5\s*\*\s*a_w\s*\*\s*t_r",
                  r"0\.9\s*\*\s*[\w.]*mu_slide",
                  r"sqrt\(\s*2\.0\s*\*\s*[\w.\[\]\"']*"
                  r"(?:C_BS|[\"']bs[\"']|max_service_brake_mps2)"],
    "pad_torque": [r"2\.0\s*\*\s*[\w.\[\]:, ]*(?:pad_mu|mub|mu_b)\b[\w.\[\]:, ]*\*\s*[\w.]*"
                   r"(?:r_b|brake_radius_m)\b"],
    "rk4_davis": [r"k2\s*=\s*q\s*-\s*v2\s*\*"],
}
"""Regular expressions of each law's inline shape (on code without comments/strings)."""

USERS: dict[str, list[str]] = {
    "traction_accel": ["core/line/vehicle.py", "core/ato/oracle.py", "core/ato/step_kernel.py",
                       "core/ato/tour_kernel.py", "core/ato/control_kernel.py"],
    "traction_a2": ["core/line/vehicle.py"],
    "traction_a3": ["core/line/vehicle.py"],
    "traction_force": ["core/line/vehicle.py"],
    "traction_demand_force": ["core/plant/kernel.py"],
    "traction_mass": ["core/plant/kernel.py", "core/line/vehicle.py"],
    "load_weighed_decel": ["core/plant/kernel.py", "core/line/vehicle.py"],
    "command_effort": ["core/line/vehicle.py"],
    "davis_resistance": ["core/line/vehicle.py", "core/plant/kernel_step.py",
                         "core/ato/step_kernel.py", "core/ato/control_kernel.py",
                         "core/brake/metro_car.py", "core/brake/train_watch.py"],
    "davis_odd": ["core/brake/metro_kernel.py", "core/brake/metro_car.py"],
    "grade_force": ["core/line/vehicle.py"],
    "grade_sine": ["core/line/geometry.py"],
    "curve_resistance_per_kg": ["core/line/track.py"],
    "net_accel": ["core/line/vehicle.py"],
    "davis_rk4_step": ["core/plant/kernel_step.py"],
    "step_force": ["core/ato/step_kernel.py", "core/ato/tour_kernel.py"],
    "stop_distance_in_step": ["core/plant/kernel_step.py"],
    "brake_demand_force": ["core/plant/kernel.py"],
    "electric_brake_force_max": ["core/plant/tables.py", "bench/ttobench.py"],
    "electric_brake_share": ["core/plant/kernel.py"],
    "pad_torque": ["core/plant/braking.py", "core/brake/metro_car.py",
                   "core/brake/paper_vehicle.py"],
    "clamp_force_for_torque": ["core/plant/braking.py", "core/brake/paper_vehicle.py"],
    "axle_load": ["core/plant/kernel.py"],
    "adhesion_limit": ["core/plant/kernel.py"],
    "burckhardt_mu": ["core/line/adhesion.py", "core/brake/metro_car.py"],
    "ebi_coef": ["core/plant/kernel.py", "core/line/track.py", "core/ato/onboard.py"],
    "ebi_speed_from": ["core/plant/kernel.py", "core/plant/kernel_step.py",
                       "core/ato/control_kernel_step.py"],
    "ebi_speed": ["core/line/track.py"],
    "stopping_distance": ["core/line/track.py"],
    "response_distance": ["core/line/atp_constants.py"],
    "braking_speed": ["core/plant/kernel.py", "core/plant/kernel_step.py",
                      "core/ato/control_kernel_step.py"],
    "downhill_accel": ["core/line/atp_constants.py"],
    "guaranteed_decel_on_grade": ["core/line/atp_constants.py"],
    "response_accel": ["core/line/atp_constants.py"],
    "adhesion_guaranteed_decel": ["core/line/guarantee.py"],
}
"""Modules (under ``metro_atc/``) that must call each law (directly or its ``*_array``)."""
INTERNAL = {"fmin", "fmax", "brake_force_max", "on_array", "njit", "_compile", "_plain",
            "__getattr__", "_law_at", "_elementwise", "_compile_arrays"}
"""Helpers and laws used by the other laws (no module calls them directly), and the
module's lazy-compilation machinery."""

PENDING: dict[str, set[str]] = {}
"""Modules that compute a law inline (module -> law families), each with its reason: none."""


def _code(path: Path) -> str:
    """The module's source with comments and string literals blanked (but record keys)."""
    out = []
    toks = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    for tok in toks:
        if tok.type == tokenize.COMMENT:
            continue
        if tok.type == tokenize.STRING and not re.fullmatch(r"[\"'][a-z_0-9]+[\"']", tok.string):
            tok = tok._replace(string='""')  # record keys (``cn["bs"]``) stay: code, not text
        out.append(tok)
    return tokenize.untokenize(out)


def _modules() -> list[Path]:
    return sorted(p for p in PKG.rglob("*.py") if p.name != "laws.py"
                  and "__pycache__" not in p.parts)


def _rel(p: Path) -> str:
    return p.relative_to(PKG).as_posix()


def _hits(code: str) -> set[str]:
    return {fam for fam, pats in PATTERNS.items() if any(re.search(x, code) for x in pats)}


def _law_calls(path: Path) -> set[str]:
    """Names of :mod:`metro_atc.core.laws` the module refers to (``laws.x`` or imported)."""
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in ("laws", "law")):
            names.add(node.attr)
        elif (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute)
              and node.value.attr == "plain" and isinstance(node.value.value, ast.Name)
              and node.value.value.id == "laws"):  # laws.plain.x: the same law uncompiled
            names.add(node.attr)
        elif isinstance(node, ast.ImportFrom) and node.module == "metro_atc.core.laws":
            names.update(a.name for a in node.names)
    return {n[:-len("_array")] if n.endswith("_array") else n for n in names}


def test_no_module_computes_a_law_inline() -> None:
    """Outside laws.py, a law's shape appears only in the listed pending modules."""
    found = {}
    for p in _modules():
        hits = _hits(_code(p))
        if hits:
            found[_rel(p)] = hits
    extra = {m: h - PENDING.get(m, set()) for m, h in found.items()}
    extra = {m: h for m, h in extra.items() if h}
    assert not extra, f"laws computed inline (call metro_atc.core.laws): {extra}"
    stale = {m: h - found.get(m, set()) for m, h in PENDING.items()}
    stale = {m: h for m, h in stale.items() if h}
    assert not stale, f"PENDING lists modules that no longer compute these laws: {stale}"


@pytest.mark.parametrize("law", sorted(USERS))
def test_users_call_the_law(law: str) -> None:
    """Each law's users call its one definition."""
    assert hasattr(laws, law), law
    for mod in USERS[law]:
        assert law in _law_calls(PKG / mod), f"{mod} does not call laws.{law}"


def test_every_law_has_a_user() -> None:
    """Every function of laws.py is a law with a user or an internal helper (no array copy)."""
    tree = ast.parse((PKG / "core" / "laws.py").read_text())
    defs = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert not {d for d in defs - INTERNAL if d.endswith("_array")}, "see laws.ARRAY_LAWS"
    assert defs - INTERNAL == set(USERS), sorted((defs - INTERNAL) ^ set(USERS))
    assert set(laws.ARRAY_LAWS) <= defs


def test_patterns_find_the_old_copies() -> None:
    """The patterns catch the inline forms the package had (so the scan can fail)."""
    old = {
        "traction": ["phi3 = p.a3 / (va + p.b3_mps + 1e-12) ** 2",
                     "phi = c[K_A2] / (va + c[K_B2] + 1e-12)",
                     "return c[k + 4] / math.pow(va + c[k + 6] + 1e-12, c[C_TWO])"],
        "davis": ["return p.davis_a_n + p.davis_b_n_per_mps * va + p.davis_c_n_per_mps2 * va",
                  "r1 = p.davis_a_n + vs * (p.davis_b_n_per_mps + p.davis_c_n_per_mps2 * vs)",
                  "pr[i] = (da + vi * (db + dc * vi)) * d_stop",
                  "ac -= (db + dc * abs(v)) * v + da * sg",
                  "f = x - (c[K_DA] + c[K_DB] * v + c[K_DC] * v * v) - fg",
                  "return (a + b * va + c * va * va) * np.sign(v)"],
        "electric_brake": ["np.minimum(bs * m, p.max_regen_power_w / vv)",
                           "* np.minimum(self.v / p.regen_fade_speed_mps, 1.0)"],
        "burckhardt": ["self.c1 * (1.0 - np.exp(-self.c2 * sa)) - self.c3 * sa",
                       "m = c1 * (1.0 - math.exp(-c2 * sa)) - c3 * sa"],
        "grade": ["return p.mass_kg * G_MPS2 * np.sin(np.arctan(g))"],
        "roeckl": ["wr = np.where(r >= 300.0, 650.0 / np.maximum(r - 55.0, 1.0), 0)"],
        "atp_curve": ["c0 = (b * tr) ** 2 + b * tr * tr * a_w",
                      "v_ma = math.sqrt(_mx(c0 + c[C_C1] * dist, 0.0)) - c2",
                      "c0 = c[C_C0A] + c[C_C0B] * a_w",
                      "c0 = cn[\"c0a\"] + cn[\"c0b\"] * a_w",
                      "d_r = p.max_speed_mps * t_r + 0.5 * a_w * t_r ** 2",
                      "0.9 * curve.mu_slide * G * tare / (tare + m_rot)",
                      "code = math.sqrt(2.0 * c[C_BS] * _mx(eoa[i] - start, 0.0))",
                      "code = math.sqrt(2.0 * cn[\"bs\"] * _mx(eoa[i] - start, 0.0))",
                      "np.sqrt(2.0 * self.p.max_service_brake_mps2 * np.maximum(d, 0.0))"],
        "pad_torque": ["self.tb_coef = 2.0 * self.pad_mu * p.brake_radius_m / self.r_w",
                       "tb = 2.0 * mub[:, None] * p.r_b * fc * np.tanh(om / p.w_eps)",
                       "a_req * self.mass * self.r_w / (N_AX * 2.0 * self.mu_b * self.r_b)"],
        "rk4_davis": ["k2 = q - v2 * (cb + cc * v2)"],
    }
    assert set(old) == set(PATTERNS)
    for fam, lines in old.items():
        for line in lines:
            assert fam in _hits(line), (fam, line)
    # and the laws' own source has every shape the scan looks for
    assert set(PATTERNS) - {"atp_curve", "pad_torque", "rk4_davis"} <= _hits(
        _code(PKG / "core" / "laws.py")) | {"electric_brake", "davis", "traction"}
