"""Reading a figure table of the docs back, so a test can re-measure every row of it.

A table is found by the sentence that introduces it (the first table after that text). Cells
hold numbers with a space as thousands separator ("18 356"), several in one cell separated by
" / ". A stated figure is compared with its measurement within a relative tolerance plus half a
unit of the last digit the doc writes (the doc rounds; tolerance 0 means equal as written).
"""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def table(doc: str, intro: str) -> list[dict[str, str]]:
    """The table after the text `intro` in `doc` (a path from the repository's root, e.g.
    "README.md" or "docs/target.md"): one dict a row, header cell -> cell. Cells split at the
    unescaped bars, as Markdown does ("mean\\|e\\|" is one cell)."""
    text = (ROOT / doc).read_text()
    lines = text[text.index(intro):].splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("|"))
    rows = []
    for ln in lines[start:]:
        if not ln.startswith("|"):
            break
        rows.append([c.strip() for c in re.split(r"(?<!\\)\|", ln.strip()[1:-1])])
    header, body = rows[0], rows[2:]          # rows[1] is the |---| line
    return [dict(zip(header, r)) for r in body]


def numbers(cell: str) -> list[str]:
    """The figures of a cell as written: "5 872 / 5 170" -> ["5872", "5170"]."""
    return [re.sub(r"[\s\u202f]", "", part) for part in cell.split(" / ")]


def outside(stated: str, measured: float, tolerance: float) -> bool:
    """Is `measured` further from the written figure `stated` than `tolerance` (relative) plus
    half a unit of its last written digit? In exponent notation the unit is the mantissa's last
    digit times the power of ten ("2.2e-6": half of 1e-7)."""
    mantissa, _, exponent = stated.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    value = float(stated)
    unit = 10.0 ** (int(exponent or 0) - decimals)
    return abs(measured - value) > tolerance * abs(value) + 0.5 * unit


def min_max_rows(doc: str, intro: str) -> dict[str, tuple[float, float]]:
    """docs/<doc>'s table of `| label | min | max |` after the text `intro`: label -> (min, max)."""
    out = {}
    for row in table(f"docs/{doc}", intro):
        label, lo, hi = row.values()
        out[label] = (float(lo), float(hi))
    return out
