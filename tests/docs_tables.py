"""Reading a figure table of the docs back, so a test can re-measure every row of it.

A table is found by the sentence that introduces it; its rows are `| label | number | number |`.
"""
from __future__ import annotations

from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def min_max_rows(doc: str, intro: str) -> dict[str, tuple[float, float]]:
    """docs/<doc>'s table after the text `intro`: label -> (min, max)."""
    text = (DOCS / doc).read_text()
    text = text[text.index(intro):]
    rows = {}
    for ln in text.splitlines():
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[1].replace(".", "").isdigit():
            rows[cells[0]] = (float(cells[1]), float(cells[2]))
        elif rows and not ln.startswith("|"):
            break
    return rows
