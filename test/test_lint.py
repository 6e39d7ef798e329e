"""Lint tests in the ROS style: flake8, pep257 docstrings, package.xml checks, mypy."""

from __future__ import annotations

import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from background import job

ROOT = Path(__file__).resolve().parent.parent
PY_TARGETS = ["metro_atc", "test", "setup.py", "launch"]
FLAKE8 = [sys.executable, "-m", "flake8", *PY_TARGETS]
PEP257 = [sys.executable, "-m", "pydocstyle", "--convention=pep257",
          "--add-ignore=D100,D104,D105,D107,D203,D212,D401,D403,D404", "metro_atc"]
MYPY = [sys.executable, "-m", "mypy", "--ignore-missing-imports", "--no-error-summary",
        "--cache-dir", str(ROOT / "build" / ".mypy_cache"), "metro_atc"]
"""The linters' command lines; each runs as a background job started with the session
(``background``: mypy alone is ~40 s of one core on a fresh clone) and its test asserts
on the result."""


def _run(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)


job("flake8_result")(lambda tmp: _run(FLAKE8))
job("pep257_result")(lambda tmp: _run(PEP257))
job("mypy_result")(lambda tmp: _run(MYPY))


@pytest.fixture
def flake8_result(background_jobs: Any) -> subprocess.CompletedProcess[str]:
    """flake8 on the Python targets (background job)."""
    return background_jobs.result("flake8_result")


@pytest.fixture
def pep257_result(background_jobs: Any) -> subprocess.CompletedProcess[str]:
    """pydocstyle on the package (background job)."""
    return background_jobs.result("pep257_result")


@pytest.fixture
def mypy_result(background_jobs: Any) -> subprocess.CompletedProcess[str]:
    """mypy on the package (background job)."""
    return background_jobs.result("mypy_result")


@pytest.mark.lint
def test_flake8(flake8_result: subprocess.CompletedProcess[str]) -> None:
    """flake8 (max line length 99, as ament_flake8) reports nothing."""
    r = flake8_result
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.lint
def test_pep257(pep257_result: subprocess.CompletedProcess[str]) -> None:
    """Docstrings follow pep257 (ament_pep257 set; public API must be documented).

    D401/D403 (imperative mood, capitalised first word) are off: they misfire on message
    type names such as ``TrainState``.
    """
    r = pep257_result
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
def test_mypy(mypy_result: subprocess.CompletedProcess[str]) -> None:
    """mypy on metro_atc/ finds no type errors."""
    r = mypy_result
    assert r.returncode == 0, r.stdout + r.stderr
