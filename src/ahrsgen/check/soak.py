"""The soak: src/ahrsgen/sim/c/soak.c steps the float build millions of times over synthesised
varied motion with occasional glitches and reports the invariants as JSON."""
from __future__ import annotations

import json
import math
import os
import subprocess
from pathlib import Path

from ahrsgen.check.layout import C_DIR, HardenError, invariant_plan, load_manifest
from ahrsgen.check.tools import _build

SOAK_FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-fno-math-errno", "-Wall", "-Wextra"]


def build_soak(gen_dir: str | Path) -> Path:
    cc = os.environ.get("CC", "cc")
    return _build("soak", Path(gen_dir), cc, SOAK_FLAGS, C_DIR / "soak.c")


def site_field(params: dict) -> tuple[float, float]:
    """(declination, inclination) in rad that the filter's baked parameters assume (inclination
    60 deg when the filter does not fix one), so the soak's magnetic field matches its site."""
    decl = float(params.get("declination", 0.0))
    incl = math.radians(float(params.get("inclination_deg", 60.0)))
    return decl, incl


def run_soak(gen_dir: str | Path, steps: int = 10_000_000, seed: int = 1, glitch_rate: float = 1e-3,
             varied: bool = True, gyro_bias_scale: float = 1.0) -> dict:
    """Soak one filter (float or double build as generated); see src/ahrsgen/sim/c/soak.c."""
    gen_dir = Path(gen_dir)
    exe = build_soak(gen_dir)
    decl, incl = site_field(load_manifest(gen_dir)["params"])
    r = subprocess.run([str(exe), str(int(steps)), str(int(seed)), repr(float(glitch_rate)), "1" if varied else "0",
                        repr(decl), repr(incl), repr(float(gyro_bias_scale))],
                       capture_output=True, text=True)
    if r.returncode not in (0, 1) or not r.stdout.strip():
        raise HardenError(f"soak of {gen_dir} failed (exit {r.returncode}):\n{r.stderr}")
    out = json.loads(r.stdout)
    out["invariants"] = invariant_plan(load_manifest(gen_dir))
    return out
