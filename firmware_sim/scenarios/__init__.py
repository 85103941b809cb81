"""Simulated scenarios with ground truth, one module per scenario.

Each module `firmware_sim/scenarios/<name>.py` defines

    DESCRIPTION: str                      # one line for `ahrsgen list` / reports
    def make(seed: int = 0, **options) -> SensorLog

and is deterministic for a given seed and options. `names()` finds them; `make(name, seed,
**options)` builds one.
"""
from __future__ import annotations

import importlib
import pkgutil

from firmware_sim.log import SensorLog


def names() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def module(name: str):
    if name not in names():
        raise KeyError(f"unknown scenario {name!r} (known: {', '.join(names()) or 'none'})")
    return importlib.import_module(f"{__name__}.{name}")


def make(name: str, seed: int = 0, **options) -> SensorLog:
    return module(name).make(seed=seed, **options)
