"""`ahrsgen new NAME -o DIR` writes a filter folder that generates, compiles and validates as
it is (the acceptance of issue 15: `ahrsgen new myfilt -o /tmp/x && ahrsgen validate /tmp/x/myfilt`),
and whose own pytest file passes."""
from __future__ import annotations

import pytest

import subprocess
import sys

from ahrsgen import cli


@pytest.mark.slow
def test_new_then_validate(tmp_path, capsys):
    assert cli.main(["new", "myfilt", "-o", str(tmp_path)]) == 0
    folder = tmp_path / "myfilt"
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        ["defaults.toml", "model.py", "reference.py", "step.c.j2", "test_myfilt.py"])
    capsys.readouterr()
    # the CLI's default validation (float, 10-minute fixed-wing flight), then double to 1e-9 rad
    assert cli.main(["validate", str(folder)]) == 0
    assert capsys.readouterr().out.rstrip().endswith("PASS")
    assert cli.main(["validate", str(folder), "--precision", "double", "--scenario", "turntable"]) == 0
    assert capsys.readouterr().out.rstrip().endswith("PASS")
    # the scaffold's own tests, run the way its user runs them
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(folder)],
                       cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0 and "3 passed" in r.stdout, r.stdout + r.stderr


def test_new_refuses_an_existing_folder_and_a_bad_name(tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    assert cli.main(["new", "taken", "-o", str(tmp_path)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert cli.main(["new", "qcf", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "a filter named 'qcf' exists already" in err and "built-in" in err
    for bad in ("My-filter", "2fast", "_hidden"):
        assert cli.main(["new", bad, "-o", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert "lower-case C identifier" in err and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]      # nothing half written
