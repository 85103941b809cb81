"""Generated lines stay within 100 columns (DESIGN.md) where the printer writes them: every
line of every emitted kernel (its parts, its Args/Outputs comment, prototype and statements)
and every line of the header, in every filter's float and double, default and runtime builds.
(The filters' hand-written step partials, the fastmath helpers and the input checks of
filter.c.j2 are not yet held to it.)"""
from __future__ import annotations

import pytest

from conftest import kernel_builds, rendered

WIDTH = 100


def _long(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if len(ln) > WIDTH]


@pytest.mark.parametrize("name,precision,runtime", kernel_builds())
def test_kernel_and_header_lines_within_100_columns(name, precision, runtime):
    gen = rendered(name, precision, runtime)
    man = gen.manifest
    source, header = gen.files[man["files"]["source"]], gen.files[man["files"]["header"]]
    assert _long(header) == []
    for k in gen.kernels:
        at = source.find(k.source())
        assert at >= 0, f"{k.name} not in the source as printed"
        span = source[source.rfind("\n", 0, at) + 1:at + len(k.source())]
        assert _long(span) == [], k.name
