"""Constants shared by the benchmark's modules."""
from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent.parent      # firmware_sim/
C_DIR = HERE / "c"
REPO = HERE.parent

PEER_NAMES = ("vqf", "fusion", "madgwick", "mahony")
ANGLES = ("roll", "pitch", "yaw")
BROAD_METRICS = ("total", "heading", "inclination")
