"""Constants shared by the benchmark's modules."""
from __future__ import annotations

from ahrsgen import paths

C_DIR = paths.harness_dir("c")
REPO = paths.CHECKOUT

PEER_NAMES = ("vqf", "fusion", "madgwick", "mahony")
ANGLES = ("roll", "pitch", "yaw")
BROAD_METRICS = ("total", "heading", "inclination")
