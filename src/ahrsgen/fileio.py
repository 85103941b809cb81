"""Output files written whole or not at all, and output paths checked before any work is done.

Every file the CLI writes goes through `write_atomic`: the bytes go to a temporary file in the
same folder, which then replaces the target in one rename, so an error or an interrupt never
leaves half a file. `check_output_file` / `check_output_dir` refuse, with one line (ConfigError),
a path that cannot be written: before a long run rather than after it.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ahrsgen.errors import ConfigError


def _writable_dir(d: Path, what: str) -> None:
    if not d.exists():
        raise ConfigError(f"{what}: folder {d} does not exist")
    if not d.is_dir():
        raise ConfigError(f"{what}: {d} is not a folder")
    if not os.access(d, os.W_OK | os.X_OK):
        raise ConfigError(f"{what}: folder {d} is not writable")


def check_output_file(path: str | Path, what: str) -> Path:
    """A regular file we may create or replace: its folder exists and is writable, it is not a folder."""
    p = Path(path)
    if p.exists() and not p.is_file():
        raise ConfigError(f"{what}: {p} exists and is not a regular file")
    for parent in p.parents:          # a path under a file: 'x.txt/out.png'
        if parent.exists():
            if not parent.is_dir():
                raise ConfigError(f"{what}: {parent} is a file, not a folder")
            break
    _writable_dir(p.parent if str(p.parent) else Path("."), what)
    return p


def check_output_dir(path: str | Path, what: str) -> Path:
    """A folder we may create (with its parents) and write into."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ConfigError(f"{what}: {p} exists and is not a folder")
    anc = p
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise ConfigError(f"{what}: {anc} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise ConfigError(f"{what}: folder {anc} is not writable")
    return p


def write_atomic(path: str | Path, data: bytes) -> Path:
    p = Path(path)
    fd, tmp = tempfile.mkstemp(dir=p.parent if str(p.parent) else ".", prefix=f".{p.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_atomic(path, text.encode("utf-8"))
