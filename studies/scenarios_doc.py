"""Writes docs/scenarios.md's overview table (`<!-- scenarios_doc.py: overview -->`) from the
simulator: each scenario's duration, rates and samples as `scenarios.make(name, seed=0, **opts)`
makes it. tests/sim/test_scenarios_doc.py makes every row again and compares.

    PYTHONPATH=src .venv/bin/python -m studies.scenarios_doc
"""
from __future__ import annotations

import sys

from studies.doc_blocks import ROOT, replace_block

WRITER = "scenarios_doc.py"

# (name, options, after): the rows of the table
ROWS = [
    ("fixedwing_gps", {}, "QCF paper"),
    ("fixedwing_gps", {"rate_hz": 100.0}, "QCF paper"),
    ("static_accel_disturbance", {}, "ADUKF paper"),
    ("static_mag_disturbance", {}, "ADUKF paper"),
    ("turntable", {}, "CPF paper"),
    ("multirotor", {}, "product"),
    ("multirotor", {"rate_hz": 400.0, "mag_rate": 100.0}, "product, sensors at their own rates"),
    ("multirotor", {"rate_hz": 400.0, "mag_rate": 100.0, "repeat_slow": True},
     "the same samples repeated: magnetometer bit set every step"),
    ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0}, "product: a 1 kHz IMU"),
    ("attached_magnet", {}, "product: a magnet fixed to the sensor"),
    ("handheld", {}, "product: one sensor"),
    ("handheld", {"calibration": True}, "product: its calibration log"),
    ("gyro_clip", {}, "product: recovery after gyro over-range"),
]


def opts_text(opts: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in opts.items())


def rate(x) -> str:
    return "none" if x is None else f"{x:g}"


def measure(name: str, opts: dict) -> dict[str, str]:
    """The row's figures as written: duration (s), IMU, magnetometer and GPS rates (Hz), steps."""
    from ahrsgen.sim import scenarios
    log = scenarios.make(name, seed=0, **opts)
    m = log.meta
    return {"duration s": f"{m['duration']:.1f}".removesuffix(".0"), "IMU Hz": rate(m["rate_hz"]), "mag Hz": rate(m["mag_rate_hz"]),
            "GPS Hz": rate(m["gps_rate_hz"]), "steps": f"{len(log):,}".replace(",", " ")}


def table() -> list[str]:
    cols = ("duration s", "IMU Hz", "mag Hz", "GPS Hz", "steps")
    lines = ["| name | options | after | " + " | ".join(cols) + " |", "|---|---|---|" + "---|" * len(cols)]
    for name, opts, after in ROWS:
        f = measure(name, opts)
        lines.append(f"| `{name}` | {opts_text(opts) or '-'} | {after} | " + " | ".join(f[c] for c in cols) + " |")
    return lines


def main() -> int:
    replace_block(ROOT / "docs" / "scenarios.md", WRITER, "overview", table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
