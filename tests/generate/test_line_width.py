"""Generated lines stay within 100 columns (DESIGN.md): every line of the source and the header
of every filter's float and double, default and runtime builds, and of each preset (the kernels
as the printer writes them, the templates' own step code, the fastmath helpers, the input
checks and tables)."""
from __future__ import annotations

import pytest

from conftest import kernel_builds, rendered

WIDTH = 100


def _long(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if len(ln) > WIDTH]


def _check(gen) -> None:
    for name, text in gen.files.items():
        if name.endswith((".c", ".h")):
            assert _long(text) == [], name


@pytest.mark.parametrize("name,precision,runtime", kernel_builds())
def test_every_generated_line_within_100_columns(name, precision, runtime):
    gen = rendered(name, precision, runtime)
    _check(gen)
    # the kernels as printed are in the source (the width holds for them, not a copy)
    source = gen.files[gen.manifest["files"]["source"]]
    for k in gen.kernels:
        assert source.find(k.source()) >= 0, f"{k.name} not in the source as printed"


def _presets():
    from ahrsgen import filters
    return [(n, p) for n in filters.names() for p in filters.load(n).presets()]


@pytest.mark.parametrize("name,preset", _presets())
def test_presets_within_100_columns(name, preset):
    from ahrsgen.generate import config, render
    _check(render.render(config.resolve(name, preset=preset)))
