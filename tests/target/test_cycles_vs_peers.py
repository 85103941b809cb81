"""studies/cycles_vs_peers.py without the network: a tampered sdist in --sources is refused in one
line with exit 2 before anything is built (the benchmark itself is not a test; it downloads the
sdists and runs for about a minute)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from conftest import REPO



def test_tampered_sdist_is_refused_in_one_line(tmp_path):
    (tmp_path / "imufusion-1.3.3.tar.gz").write_bytes(b"not the sdist")
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    p = subprocess.run([sys.executable, str(REPO / "studies" / "cycles_vs_peers.py"), "--sources", str(tmp_path),
                        "-o", str(tmp_path / "out.json")], capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "sha256" in lines[0] and "imufusion-1.3.3.tar.gz" in lines[0], p.stderr
    assert not (tmp_path / "out.json").exists()
