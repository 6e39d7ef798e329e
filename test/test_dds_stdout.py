"""stdout stays clean for ``--json`` when the current directory was deleted.

Fast DDS looks for ``DEFAULT_FASTRTPS_PROFILES.xml`` in the current directory; in a deleted
one it logs ``[XMLPARSER Error] getcwd failed`` (or ``realpath failed``) ``...
loadDefaultXMLFile`` on stdout. ``dds_defaults`` skips that look-up when there is no such
file; the single-process graph also points fd 1 at stderr while its nodes exist.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")

NODE = ("import rclpy\nfrom rclpy.node import Node\nrclpy.init()\nn = Node('dds_stdout_probe')\n"
        "n.destroy_node()\nrclpy.shutdown()\n")


def _run_in_deleted_dir(tmp_path: Path, code: str, env: dict[str, str]) -> str:
    """Run ``code`` in a fresh Python whose current directory is deleted; return stdout."""
    gone = tmp_path / "gone"
    gone.mkdir()
    script = ("import os\nos.chdir(%r)\nos.rmdir(%r)\n" % (str(gone), str(gone))) + code
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                         text=True, timeout=60, check=True)
    return out.stdout


def _env() -> dict[str, str]:
    env = dict(os.environ, ROS_DOMAIN_ID="84")
    env.pop("SKIP_DEFAULT_XML_FILE", None)
    return env


def test_deleted_cwd_prints_the_fast_dds_error_without_the_default(tmp_path: Path) -> None:
    """The cause, shown: without dds_defaults, Fast DDS writes its error on stdout."""
    out = _run_in_deleted_dir(tmp_path, NODE, _env())
    assert "loadDefaultXMLFile" in out


def test_dds_defaults_keep_stdout_clean_in_a_deleted_cwd(tmp_path: Path) -> None:
    """With the project's defaults applied first, nothing reaches stdout."""
    code = "from metro_atc.dds import dds_defaults\ndds_defaults()\n" + NODE
    assert _run_in_deleted_dir(tmp_path, code, _env()) == ""


def test_default_xml_file_in_cwd_is_still_loaded(tmp_path: Path, monkeypatch) -> None:
    """A DEFAULT_FASTRTPS_PROFILES.xml in the current directory is not skipped."""
    from metro_atc.dds import dds_defaults

    monkeypatch.delenv("SKIP_DEFAULT_XML_FILE", raising=False)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<dds/>")
    dds_defaults()
    assert "SKIP_DEFAULT_XML_FILE" not in os.environ
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").unlink()
    dds_defaults()
    assert os.environ.get("SKIP_DEFAULT_XML_FILE") == "1"


def test_stdout_on_stderr_moves_c_level_writes(tmp_path: Path) -> None:
    """fd 1 writes inside the block land on stderr; stdout works again after it."""
    code = ("import os, sys\nfrom metro_atc.nodes.graph import stdout_on_stderr\n"
            "with stdout_on_stderr():\n    os.write(1, b'inside\\n')\n    print('py')\n"
            "print('after')\n")
    out = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True,
                         text=True, timeout=60, check=True)
    assert out.stdout == "after\n"
    assert "inside" in out.stderr and "py" in out.stderr
