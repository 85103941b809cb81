"""Under CI=true a check that needs a tool .ci/setup installs fails instead of skipping
(tests/conftest.py). Checked by running pytest on small test files with our conftest."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent

PROBE_TESTS = '''
import pytest
from conftest import needs, require

@needs("no-such-tool-ahrsgen")
def test_marker():
    pass

def test_imperative():
    require("no-such-tool-ahrsgen")

def test_importorskip():
    pytest.importorskip("ahrs")          # shadowed below by a module whose import fails

def test_data_absent():
    pytest.skip("BROAD subset not found (../shared/data/broad)")

@needs("sh")
def test_present():
    pass
'''


def _run(tmp_path: Path, ci: str | None) -> str:
    shutil.copy(HERE / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "test_probe.py").write_text(PROBE_TESTS)
    (tmp_path / "test_probe_module.py").write_text(
        "import pytest\npytest.importorskip('ahrs')\n\ndef test_in_skipped_module():\n    pass\n")
    (tmp_path / "ahrs.py").write_text("raise ModuleNotFoundError(\"No module named 'ahrs'\")\n")
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    if ci is not None:
        env["CI"] = ci
    r = subprocess.run([sys.executable, "-m", "pytest", "-v", "-p", "no:cacheprovider", "--continue-on-collection-errors", "--rootdir",
                        str(tmp_path), str(tmp_path)], capture_output=True, text=True, cwd=tmp_path, env=env)
    return r.stdout


@pytest.mark.parametrize("ci", [None, "true"])
def test_tool_skips_fail_under_ci(tmp_path, ci):
    out = _run(tmp_path, ci)
    lines = out.splitlines()

    def outcome(name):
        return next(ln.split()[1] for ln in lines if ln.startswith(f"test_probe.py::{name} "))

    tool_tests = ("test_marker", "test_imperative", "test_importorskip")
    if ci:
        # a skipif marker acts in setup, so pytest reports that test as an ERROR: red either way
        assert all(outcome(t) in ("FAILED", "ERROR") for t in tool_tests), out
        assert "CI=true and this check did not run" in out, out
    else:
        assert [outcome(t) for t in tool_tests] == ["SKIPPED"] * 3, out
    assert outcome("test_data_absent") == "SKIPPED", out
    # a module skipped at import: an error (collection) under CI, a skip otherwise
    assert ("ERROR test_probe_module.py" in out) == bool(ci), out      # absent data may skip, even in CI
    assert outcome("test_present") == "PASSED", out
