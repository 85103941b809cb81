"""Real sensor logs -> SensorLog, one module per format:

- csvlog: the CSV format (docs/log-format.md; BROAD's trials are in it), read whole and written;
- chunks: the same format read a chunk at a time, for logs of any size (CsvChunks);
- ulog: PX4 ULog files;
- units: units recognised from the data (unit_warnings);
- files: where the logs are (the installed excerpts, the full data sets).

`read_log(path)` picks the reader from the file name. `shared_data_dir()` finds the full
data sets (`$AHRSGEN_DATA`, else `<repo>/../shared/data`).
"""
from __future__ import annotations

import os
from pathlib import Path

from ahrsgen.errors import LogError
from ahrsgen.sim.log import SensorLog
from ahrsgen.sim.readers import chunks
from ahrsgen.sim.readers.chunks import CsvChunks
from ahrsgen.sim.readers.csvlog import (BROAD_CITATION, BROAD_COLUMNS, CSV_GROUPS, CSV_REQUIRED, REF_NORM_TOL,
                                        read_broad, read_csv, write_csv)
from ahrsgen.sim.readers.files import DATA_ENV, EXCERPTS, REPO_ROOT, broad_trials, shared_data_dir
from ahrsgen.sim.readers.ulog import ULOG_MAGIC, read_ulog, ulog_truncation
from ahrsgen.sim.readers.units import gyro_scale, unit_warnings

__all__ = ["BROAD_CITATION", "BROAD_COLUMNS", "CSV_GROUPS", "CSV_REQUIRED", "CsvChunks", "chunks", "DATA_ENV",
           "EXCERPTS", "LogError", "REF_NORM_TOL", "REPO_ROOT", "SensorLog", "ULOG_MAGIC", "broad_trials",
           "gyro_scale", "read_broad", "read_csv", "read_log", "read_ulog", "shared_data_dir", "ulog_truncation",
           "unit_warnings", "write_csv"]


def read_log(path: str | os.PathLike, name: str | None = None) -> SensorLog:
    """Read a log by its file name: *.ulg -> PX4 ULog; *.csv / *.csv.gz -> the CSV format
    (docs/log-format.md; BROAD's files are in it). Problems are a LogError (one line)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"log file not found: {p}")
    if p.is_dir():
        raise LogError(f"{p}: is a folder, not a log file")
    lower = p.name.lower()
    if lower.endswith(".ulg"):
        return read_ulog(p, name)
    if lower.endswith((".csv", ".csv.gz")):
        return read_csv(p, name)
    raise LogError(f"{p}: unknown log format (expected a name ending in .ulg, .csv or .csv.gz)")
