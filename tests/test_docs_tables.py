"""The house's reader of doc figures (tests/docs_tables.py): a figure as written is compared with
its measurement within half a unit of its last written digit, so it must get that unit right,
in exponent notation too, or a stale figure passes."""
from __future__ import annotations

import pytest

from docs_tables import outside


@pytest.mark.parametrize("stated, inside, beyond", [
    ("2.09", 2.0949, 2.0951),
    ("18", 18.49, 18.51),
    ("2.2e-6", 2.249e-6, 2.251e-6),
    ("9.7e-10", 9.749e-10, 9.751e-10),
    ("3e-5", 3.49e-5, 3.51e-5),
    ("1.5E+3", 1549.0, 1551.0),
])
def test_half_a_unit_of_the_last_written_digit(stated, inside, beyond):
    assert not outside(stated, inside, 0.0)
    assert outside(stated, beyond, 0.0)


def test_relative_tolerance_adds_to_the_rounding():
    assert not outside("100", 104.9, 0.045)     # 4.5 + 0.5
    assert outside("100", 105.1, 0.045)
