"""Where the product finds its own files and where it writes builds, installed or in a checkout.

The C templates ship inside the package (ahrsgen/codegen/templates/), and so do the C harness
files (ahrsgen/sim/c/, ahrsgen/sim/fuzz/, ahrsgen/target/). Everything is found beside the
imported modules, so a wheel installed anywhere works like the checkout.
"""
from __future__ import annotations

import os
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parent
# The repository root when the package runs from a checkout (editable install, pytest); None
# for an installed wheel.
CHECKOUT = PACKAGE_ROOT.parents[1] if (PACKAGE_ROOT.parents[1] / "pyproject.toml").exists() else None

# C harness files by the name callers use, and where they live in the package.
_HARNESS = {"c": PACKAGE_ROOT / "sim" / "c", "fuzz": PACKAGE_ROOT / "sim" / "fuzz",
            "data": PACKAGE_ROOT / "sim" / "data", "target": PACKAGE_ROOT / "target"}


def templates_dir() -> Path:
    """The folder of the C API templates (filter.h.j2, filter.c.j2)."""
    return PACKAGE_ROOT / "codegen" / "templates"


def harness_dir(name: str) -> Path:
    """C harness files (c, fuzz, target) and the real-log excerpts (data), shipped as package data."""
    return _HARNESS[name]


def build_dir(kind: str, env: str | None = None) -> Path:
    """Where compiled artefacts of one kind are cached: $env if set, build/<kind> in a checkout,
    else the user's cache ($XDG_CACHE_HOME/ahrsgen/<kind>), never inside site-packages."""
    if env and os.environ.get(env):
        return Path(os.environ[env])
    if CHECKOUT is not None:
        return CHECKOUT / "build" / kind
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "ahrsgen" / kind
