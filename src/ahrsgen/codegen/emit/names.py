"""Named literals while a kernel is emitted: a folded parameter with its expression (src/ahrsgen/codegen/folded.py)."""
from __future__ import annotations

import re


class _Marks:
    """Named literals while a kernel is emitted: each is a placeholder @<n>@ (no letters, so
    no identifier or temporary pattern matches it) that `plain` reads as the literal and
    `write` turns into `literal /* name */` in the finished lines."""
    _RE = re.compile(r"@(\d+)@")

    def __init__(self):
        self.items: list[tuple[str, str]] = []

    def add(self, lit: str, name: str) -> str:
        self.items.append((lit, name.replace("*/", "* /").replace("/*", "/ *")))
        return f"@{len(self.items) - 1}@"

    def name(self, text: str) -> str | None:
        m = self._RE.fullmatch(text)
        return self.items[int(m.group(1))][1] if m else None

    def plain(self, text: str) -> str:
        return self._RE.sub(lambda m: self.items[int(m.group(1))][0], text) if self.items else text

    def write(self, text: str) -> str:
        if not self.items:
            return text
        return self._RE.sub(lambda m: "{} /* {} */".format(*self.items[int(m.group(1))]), text)


def _reciprocal_name(name: str) -> str:
    return f"1/{name}" if name.isidentifier() else f"1/({name})"


def _reciprocal_name(name: str) -> str:
    return f"1/{name}" if name.isidentifier() else f"1/({name})"
