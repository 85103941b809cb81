"""Names of derived literals: the reciprocal of a folded parameter (src/ahrsgen/codegen/folded.py)."""
from __future__ import annotations


def _reciprocal_name(name: str) -> str:
    return f"1/{name}" if name.isidentifier() else f"1/({name})"
