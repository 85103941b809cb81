"""The package installed the way Python users install it: a wheel built from the checkout, put
into a fresh virtual environment outside the checkout, generates and validates filters there: a built-in, an example user filter and a scaffold.

The wheel is built from a clean copy of the checkout with pip (build isolation, setuptools from the index, as `pip install .`
would) and installed with pip into a venv without system site-packages. Its dependencies are
not downloaded and unpacked again (casadi alone is ~300 MB and 30 s): the distributions this
environment already has are linked into the new venv through a .pth file, and pip, run
without an index, must find every requirement the wheel declares among them. Nothing of the
checkout is importable there: the test asserts `ahrsgen` comes from the new venv.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow       # tests/README.md: left out of the quick run

REPO = Path(__file__).resolve().parents[1]
# Distributions linked into the fresh venv: the package's requirements, their requirements,
# and `ahrs` (the examples' independent reference).
DEPS = ["casadi", "numpy", "jinja2", "markupsafe", "ahrs", "docutils"]


def _link_distributions(names, dest: Path) -> None:
    """Link the top-level files and folders of installed distributions (their .dist-info too)."""
    dest.mkdir()
    for name in names:
        dist = metadata.distribution(name)
        top = {Path(str(f)).parts[0] for f in dist.files or [] if not str(f).startswith("..")}
        for entry in top:
            src = Path(str(dist.locate_file(entry)))
            if src.exists() and not (dest / entry).exists():
                (dest / entry).symlink_to(src)


def _clean_copy(dest: Path) -> Path:
    """The checkout's files as a fresh clone has them (tracked and new, nothing ignored): an
    in-tree build would also pack stale files left in build/ and *.egg-info by earlier builds."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=REPO, check=True,
                           capture_output=True, text=True).stdout.split("\0")
    for name in filter(None, files):
        src = REPO / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    return dest


def _run(cmd, cwd, env, timeout=300):
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} failed ({r.returncode}):\n{r.stdout}\n{r.stderr}"
    return r.stdout


def test_wheel_installs_and_works_outside_the_checkout(tmp_path):
    t0 = time.perf_counter()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AHRSGEN_BUILD", "AHRSGEN_BUILD_HARDEN",
                                                            "AHRSGEN_FILTER_PATH", "VIRTUAL_ENV")}
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    _run([*pip, "wheel", "-q", "--no-deps", "-w", str(tmp_path / "dist"),
          str(_clean_copy(tmp_path / "src"))], tmp_path, env)
    (wheel,) = (tmp_path / "dist").glob("ahrsgen-*.whl")
    t_wheel = time.perf_counter()

    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp_path, env)
    py = venv / "bin" / "python"
    site = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path, env).strip())
    _link_distributions(DEPS, tmp_path / "deps")
    (site / "deps.pth").write_text(str(tmp_path / "deps") + "\n")
    _run([*pip, "--python", str(py), "install", "-q", "--no-index", str(wheel)], tmp_path, env)
    t_install = time.perf_counter()

    where = _run([str(py), "-c", "import ahrsgen, ahrsgen.cli; print(ahrsgen.__file__); "
                  "print(ahrsgen.cli.__file__); print(ahrsgen.__version__)"], tmp_path, env).split()
    assert all(line.startswith(str(site)) for line in where[:2]), where
    assert where[2] == metadata.version("ahrsgen"), where       # the version is written once

    ahrsgen = str(venv / "bin" / "ahrsgen")
    # A built-in filter: the installed package generates exactly the committed output.
    out = _run([ahrsgen, "generate", "qcf", "-o", "out"], tmp_path, env)
    assert "qcf.c" in out
    for f in (REPO / "generated" / "qcf").iterdir():
        assert (tmp_path / "out" / f.name).read_text() == f.read_text(), f.name
    out = _run([ahrsgen, "validate", "qcf", "--scenario-opt", "duration=20"], tmp_path, env)
    assert out.rstrip().endswith("PASS"), out
    # An example user filter (a folder of the checkout, outside the installed package) and a
    # scaffold written by the installed `ahrsgen new`.
    out = _run([ahrsgen, "validate", str(REPO / "examples" / "madgwick"), "--precision", "double",
                "--scenario-opt", "duration=20"], tmp_path, env)
    assert out.rstrip().endswith("PASS"), out
    _run([ahrsgen, "new", "myfilt", "-o", "x"], tmp_path, env)
    out = _run([ahrsgen, "validate", "x/myfilt", "--scenario-opt", "duration=20"], tmp_path, env)
    assert out.rstrip().endswith("PASS"), out
    # Host builds go to the user's cache, never into site-packages.
    assert any((tmp_path / "cache" / "ahrsgen" / "host").iterdir())
    # The fuzz and soak harness files ship too: harden a filter that has no committed build here.
    out = _run([ahrsgen, "harden", "qcf", "--fuzz-seconds", "0", "--soak-steps", "20000", "--no-cppcheck",
                "--json", "h.json"], tmp_path, env)
    assert (tmp_path / "h.json").exists(), out
    # `run --help` names the example logs installed with the package, and they run as named there
    helptext = " ".join(_run([ahrsgen, "run", "--help"], tmp_path, env).split())
    example = str(site / "ahrsgen" / "sim" / "data" / "broad_01_excerpt.csv.gz")
    assert example in helptext, helptext
    out = _run([ahrsgen, "run", "mekf", "--log", example], tmp_path, env)
    assert "BROAD decomposition RMS: total" in out, out
    # The benchmark on its built-in data (the excerpts ship inside the package); the packages of
    # the `dev` extra that are missing here (vqf, imufusion, pyulog, matplotlib) are said, not fatal.
    _run([ahrsgen, "bench", "--quick", "--filters", "qcf", "--real-only", "-o", "b"], tmp_path, env)
    rep = json.loads((tmp_path / "b" / "bench.json").read_text())
    assert rep["broad"]["files"][0].startswith(str(site)), rep["broad"]["files"]
    assert set(rep["broad"]["trials"]["broad_01_excerpt"]) == {"qcf", "madgwick", "mahony"}
    assert rep["notes"][0].startswith("peers left out, their packages are not installed: vqf (vqf), fusion (imufusion)")
    t_end = time.perf_counter()
    print(f"\nwheel test: build {t_wheel - t0:.1f} s, venv + install {t_install - t_wheel:.1f} s, "
          f"commands {t_end - t_install:.1f} s, total {t_end - t0:.1f} s")
