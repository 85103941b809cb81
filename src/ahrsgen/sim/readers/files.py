"""Where the real logs are: the excerpts installed with the package and the full data sets
(`$AHRSGEN_DATA`, else `<repo>/../shared/data`)."""
from __future__ import annotations

import os
from pathlib import Path

from ahrsgen import paths

REPO_ROOT = paths.CHECKOUT   # None for an installed wheel
# Small real logs installed with the package (attribution in its README): the tests, `bench
# --quick` and the documentation's examples read them, in a checkout or an installed wheel alike.
EXCERPTS = Path(__file__).resolve().parent.parent / "data"
DATA_ENV = "AHRSGEN_DATA"


def shared_data_dir(option: str | os.PathLike | None = None) -> Path | None:
    """Directory holding broad/ and px4/: the option, else $AHRSGEN_DATA, else <repo>/../shared/data.

    Returns None when none of them exists (callers say so and skip real-data parts).
    """
    for cand in (option, os.environ.get(DATA_ENV), (REPO_ROOT.parent / "shared" / "data") if REPO_ROOT else None):
        if cand and Path(cand).is_dir():
            return Path(cand)
    return None


def broad_trials(data_dir: str | os.PathLike | None = None) -> list[Path]:
    """Sorted BROAD trial files (*.csv.gz / *.csv) under <data_dir>/broad (empty if absent)."""
    d = shared_data_dir(data_dir)
    if d is None or not (d / "broad").is_dir():
        return []
    return sorted(p for p in (d / "broad").iterdir() if p.name.endswith((".csv.gz", ".csv")))
