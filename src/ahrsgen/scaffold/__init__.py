"""`ahrsgen new NAME -o DIR`: write a filter folder that generates, compiles and validates as
it is, with short comments that teach the contract (docs/your_own_filter.md)."""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from ahrsgen.errors import ConfigError

HERE = Path(__file__).parent
# template file -> file written (test_<name>.py is named after the filter so pytest can tell
# several filters' tests apart)
FILES = {"defaults.toml.tmpl": "defaults.toml", "model.py.tmpl": "model.py", "reference.py.tmpl": "reference.py",
         "step.c.j2.tmpl": "step.c.j2", "test_filter.py.tmpl": "test_{name}.py"}


def write(name: str, out_dir: str | Path) -> Path:
    """Write out_dir/name/ (refused if it exists); every file appears at once or none does."""
    if not (name.isidentifier() and name.isascii() and name.lower() == name and not name.startswith("_")):
        raise ConfigError(f"filter name {name!r} must be a lower-case C identifier (letters, digits, _): "
                          f"it names the folder and prefixes the C API")
    from ahrsgen import filters
    known = filters.known(name)
    if known is not None:
        raise ConfigError(f"a filter named '{name}' exists already ({known.folder}, {known.origin}): "
                          f"two filters of one name cannot both be used; choose another name")
    out_dir = Path(out_dir)
    target = out_dir / name
    if target.exists():
        raise ConfigError(f"{target} already exists; choose another name or directory")
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=out_dir))
    try:
        for src, dst in FILES.items():
            text = (HERE / src).read_text().replace("__NAME__", name)
            (tmp / dst.format(name=name)).write_text(text)
        os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target
