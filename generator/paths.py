"""Where the product finds its own files and where it writes builds, installed or in a checkout.

The C templates live at the repository's top level (templates/) and ship inside the installed
package as `generator.templates` (setup.py maps the folder); the C harness files ship inside
`firmware_sim` (c/, fuzz/, target/). Everything is found from the imported packages, so a
wheel installed anywhere works like the checkout.
"""
from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parent
# The repository root when the package runs from a checkout (editable install, pytest); None
# for an installed wheel.
CHECKOUT = PACKAGE_ROOT.parent if (PACKAGE_ROOT.parent / "pyproject.toml").exists() else None


def templates_dir() -> Path:
    """The folder of the C API templates (filter.h.j2, filter.c.j2)."""
    if CHECKOUT is not None:
        return CHECKOUT / "templates"
    return Path(str(resources.files("generator").joinpath("templates")))


def harness_dir(name: str) -> Path:
    """firmware_sim/<name>: C harness files (c, fuzz, target), shipped as package data."""
    return Path(str(resources.files("firmware_sim"))) / name


def build_dir(kind: str, env: str | None = None) -> Path:
    """Where compiled artefacts of one kind are cached: $env if set, build/<kind> in a checkout,
    else the user's cache ($XDG_CACHE_HOME/ahrsgen/<kind>), never inside site-packages."""
    if env and os.environ.get(env):
        return Path(os.environ[env])
    if CHECKOUT is not None:
        return CHECKOUT / "build" / kind
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "ahrsgen" / kind
