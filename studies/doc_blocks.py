"""Writing generated tables into the docs: a block stands between a line
`<!-- NAME: BLOCK -->` and a line `<!-- end NAME -->`, and only what is between is replaced.
The tests read the tables back (tests/docs_tables.py) and re-measure every figure."""
from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def replace_block(path: Path, writer: str, block: str, lines: list[str]) -> None:
    """Put `lines` between `<!-- writer: block -->` and the next `<!-- end writer -->` of `path`."""
    begin, end = f"<!-- {writer}: {block} -->", f"<!-- end {writer} -->"
    text = path.read_text()
    pattern = re.compile(re.escape(begin) + r"\n.*?" + re.escape(end), re.S)
    if not pattern.search(text):
        sys.exit(f"{path}: no block {begin} ... {end}")
    path.write_text(pattern.sub(lambda _m: "\n".join([begin, *lines, end]), text, count=1))
