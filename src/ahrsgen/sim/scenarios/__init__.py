"""Simulated scenarios with ground truth, one module per scenario.

Each module `src/ahrsgen/sim/scenarios/<name>.py` defines

    DESCRIPTION: str                      # one line for `ahrsgen list` / reports
    MAX_DURATION_S: float                 # only without a `duration` option: the longest log it makes
    def make(seed: int = 0, **options) -> SensorLog

and is deterministic for a given seed and options. `names()` finds them; `make(name, seed,
**options)` builds one.
"""
from __future__ import annotations

import importlib
import pkgutil

from ahrsgen.sim.log import SensorLog


def names() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def module(name: str):
    if name not in names():
        raise KeyError(f"unknown scenario {name!r} (known: {', '.join(names()) or 'none'})")
    return importlib.import_module(f"{__name__}.{name}")


def make(name: str, seed: int = 0, **options) -> SensorLog:
    return module(name).make(seed=seed, **options)


# Options that are rates or lengths of time: a number > 0. Every other number is >= 0 (gps_rate
# 0: no GPS receiver).
_POSITIVE = ("rate_hz", "duration", "mag_rate")
# A simulated flight is held in memory, about 100 bytes per IMU step (truth and sensors): 10
# million steps (a 1 kHz IMU for 2.8 hours) is about 1 GB. An IMU below 5 Hz is not one an
# attitude filter runs on (and leaves the truth too coarse to score).
MAX_STEPS = 10_000_000
MIN_RATE_HZ = 5.0


def options(name: str) -> dict:
    """The keyword options of a scenario's make() with their defaults (seed excluded)."""
    import inspect
    sig = inspect.signature(module(name).make)
    return {p.name: p.default for p in sig.parameters.values()
            if p.name != "seed" and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)}


def parse_options(name: str | None, items: list[str]) -> dict:
    """'--scenario-opt NAME=VALUE' strings -> make() keywords, checked against the scenario's
    options (all scenarios' when name is None) and their defaults' types. A bad one is a
    ConfigError naming it and what is allowed."""
    import math
    from ahrsgen.errors import ConfigError
    if name is None:
        known = {}
        for n in names():
            known.update(options(n))
    else:
        known = options(name)
    out = {}
    for item in items:
        key, eq, text = item.partition("=")
        key, text = key.strip(), text.strip()
        where = f"--scenario-opt {item!r}"
        if not eq or not key:
            raise ConfigError(f"{where}: expected NAME=VALUE")
        if key not in known:
            raise ConfigError(f"{where}: unknown option {key!r} for scenario {name or '(any)'}; "
                              f"known: {', '.join(sorted(known))}")
        default = known[key]
        if isinstance(default, bool):
            low = text.lower()
            if low not in ("true", "false", "1", "0", "yes", "no"):
                raise ConfigError(f"{where}: expected true or false")
            out[key] = low in ("true", "1", "yes")
            continue
        if isinstance(default, (tuple, list)) or key == "gyro_bias_deg_s":
            n_expected = len(default) if isinstance(default, (tuple, list)) else 3
            try:
                vals = tuple(float(x) for x in text.split(","))
            except ValueError:
                vals = ()
            if len(vals) != n_expected or not all(math.isfinite(v) for v in vals):
                raise ConfigError(f"{where}: expected {n_expected} comma-separated numbers")
            out[key] = vals
            continue
        if key == "dropout" or not (isinstance(default, (int, float)) or default is None):
            raise ConfigError(f"{where}: option {key!r} cannot be set from the command line")
        try:
            v = float(text)
        except ValueError:
            raise ConfigError(f"{where}: {text!r} is not a number") from None
        if not math.isfinite(v) or v < 0 or (key in _POSITIVE and v == 0):
            raise ConfigError(f"{where}: {key} must be a finite number {'> 0' if key in _POSITIVE else '>= 0'}")
        out[key] = v
    rate, duration = out.get("rate_hz", known.get("rate_hz")), out.get("duration", known.get("duration"))
    if duration is None and name is not None:      # a scenario whose length follows from its motion
        duration = getattr(module(name), "MAX_DURATION_S", None)
    if "rate_hz" in out and rate < MIN_RATE_HZ:
        raise ConfigError(f"--scenario-opt rate_hz={rate:g}: the IMU rate must be at least {MIN_RATE_HZ:g} Hz")
    if isinstance(rate, (int, float)) and isinstance(duration, (int, float)) and rate * duration > MAX_STEPS:
        raise ConfigError(f"--scenario-opt: {rate:g} Hz for {duration:g} s is {rate * duration:.3g} IMU steps; at most "
                          f"{MAX_STEPS:.0e} (about 1 GB of memory): shorten duration or lower rate_hz")
    return out
