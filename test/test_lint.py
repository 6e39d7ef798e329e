"""Lint tests in the ROS style: flake8, pep257 docstrings, package.xml checks, mypy."""

from __future__ import annotations

import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PY_TARGETS = ["metro_atc", "test", "setup.py", "launch"]


def _run(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.mark.lint
def test_flake8() -> None:
    """flake8 (max line length 99, as ament_flake8) reports nothing."""
    r = _run([sys.executable, "-m", "flake8", *PY_TARGETS])
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.lint
def test_pep257() -> None:
    """Docstrings follow pep257 (ament_pep257 set; public API must be documented).

    D401/D403 (imperative mood, capitalised first word) are off: they misfire on message
    type names such as ``TrainState``.
    """
    r = _run([sys.executable, "-m", "pydocstyle", "--convention=pep257",
              "--add-ignore=D100,D104,D105,D107,D203,D212,D401,D403,D404", "metro_atc"])
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.lint
@pytest.mark.parametrize("path", ["package.xml", "msg_defs/package.xml"])
def test_package_xml(path: str) -> None:
    """package.xml is well-formed (xmllint if installed) and valid per REP 149 (catkin_pkg)."""
    f = ROOT / path
    ET.parse(f)  # well-formed
    if shutil.which("xmllint"):
        r = _run(["xmllint", "--noout", str(f)])
        assert r.returncode == 0, r.stderr
    from catkin_pkg.package import parse_package
    warnings: list[str] = []
    pkg = parse_package(str(f), warnings=warnings)
    assert pkg.package_format == 3
    assert not warnings, warnings
    assert pkg.licenses and pkg.maintainers and pkg.description


@pytest.mark.lint
def test_mypy() -> None:
    """mypy on metro_atc/ finds no type errors."""
    r = _run([sys.executable, "-m", "mypy", "--ignore-missing-imports", "--no-error-summary",
              "--cache-dir", str(ROOT / "build" / ".mypy_cache"), "metro_atc"])
    assert r.returncode == 0, r.stdout + r.stderr
