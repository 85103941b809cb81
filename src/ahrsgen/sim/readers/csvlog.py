"""The CSV log format (docs/log-format.md), read whole (read_csv) and written (write_csv).

BROAD (Laidig, Caruso, Cereatti, Seel, *Data* 2021, 6(7), 72; CC BY 4.0), in the layout of
`shared/data/README.md`: gzip CSV `t,gx,gy,gz,ax,ay,az,mx,my,mz,qw,qx,qy,qz,movement`, already
in the product's conventions (FRD body, NED earth with magnetic north, specific force, rad/s,
µT). Every row is one IMU sample with gyro, accelerometer and magnetometer (all three valid
bits set); no GPS. The optical reference is `q_true` (NaN where the markers were lost); the
`movement` column goes to `meta['movement']` (bool array) for BROAD's scoring method, and
`meta['settle_time']` is the time of the first moving sample (the rest phase is for the
filter to settle).
"""
from __future__ import annotations

import contextlib
import gzip
import io
import os
import zlib
from pathlib import Path

import numpy as np

from ahrsgen.errors import LogError
from ahrsgen.sim.log import VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG, SensorLog

BROAD_COLUMNS = ["t", "gx", "gy", "gz", "ax", "ay", "az", "mx", "my", "mz",
                 "qw", "qx", "qy", "qz", "movement"]
BROAD_CITATION = ("D. Laidig, M. Caruso, A. Cereatti, T. Seel: BROAD - A Benchmark for Robust "
                  "Inertial Orientation Estimation. Data 2021, 6(7), 72 (CC BY 4.0)")

# The CSV log format (docs/log-format.md): a header names the columns, in any order.
CSV_REQUIRED = ("t", "gx", "gy", "gz", "ax", "ay", "az")
CSV_GROUPS = {                       # optional column groups: all of a group or none of it
    "mag": ("mx", "my", "mz"),
    "gps": ("gps_vn", "gps_ve", "gps_vd"),
    "reference": ("qw", "qx", "qy", "qz"),
    "movement": ("movement",),
}
REF_NORM_TOL = 0.1        # a reference quaternion whose norm is further than this from 1 is skipped


@contextlib.contextmanager
def _gzip_errors(path: Path):
    """Damaged gzip data read inside the block: one LogError naming the file."""
    try:
        yield
    except gzip.BadGzipFile:
        raise LogError(f"{path}: not a gzip file (the name ends in .gz)") from None
    except EOFError:
        raise LogError(f"{path}: truncated gzip file (it ends before the end-of-stream marker)") from None
    except zlib.error as e:
        raise LogError(f"{path}: damaged gzip data ({e})") from None


def _read_text(path: Path) -> str:
    """The whole file as text; gzip when the name ends in .gz. Damaged files are a LogError."""
    with _gzip_errors(path):
        if str(path).endswith(".gz"):
            with gzip.open(path, "rb") as f:
                raw = f.read()
        else:
            raw = path.read_bytes()
    try:
        return raw.decode("utf-8-sig")     # a byte-order mark (Excel's "CSV UTF-8") is not a column
    except UnicodeDecodeError as e:
        raise LogError(f"{path}: not a text file (byte {e.start} is not UTF-8)") from None


def _parse_rows(path: Path, lines: list[str], ncol: int, first_line: int = 2) -> np.ndarray:
    """Numbers of the data lines; an empty field is NaN. A bad field is a LogError naming its line
    (first_line: the line number of lines[0], counting non-empty lines as read_csv does)."""
    if not lines:
        return np.empty((0, ncol))
    try:       # fast path: numpy's parser (a file without empty fields or text)
        data = np.loadtxt(io.StringIO("\n".join(lines)), delimiter=",", dtype=float, ndmin=2)
        if data.shape[1] == ncol:
            return data
    except ValueError:
        pass       # find and name the bad field below (empty fields are NaN there)
    out = np.empty((len(lines), ncol))
    for i, ln in enumerate(lines):
        fields = ln.split(",")
        if len(fields) != ncol:
            raise LogError(f"{path}: line {i + first_line} has {len(fields)} fields, the header has {ncol}")
        for j, f in enumerate(fields):
            f = f.strip()
            if not f:
                out[i, j] = np.nan
                continue
            try:
                out[i, j] = float(f)
            except ValueError:
                raise LogError(f"{path}: line {i + first_line}, column {j + 1}: {f[:20]!r} is not a number") from None
    return out


def _hold(values: np.ndarray, arrived: np.ndarray, last: np.ndarray | None = None) -> np.ndarray:
    """Rows without a sample hold the last sample (NaN before the first), as the ULog reader does;
    `last` is the sample held before these rows (a previous chunk's), if any."""
    idx = np.where(arrived, np.arange(len(arrived)), -1)
    idx = np.maximum.accumulate(idx)
    out = np.full_like(values, np.nan)
    have = idx >= 0
    out[have] = values[idx[have]]
    if last is not None:
        out[~have] = last
    return out


def _csv_header(path: Path, line: str) -> tuple[list[str], dict]:
    """The header's column names and which optional groups it has; its errors are LogErrors."""
    header = [h.strip() for h in line.split(",")]
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise LogError(f"{path}: column(s) {', '.join(dup)} appear more than once in the header")
    missing = [c for c in CSV_REQUIRED if c not in header]
    if missing:
        raise LogError(f"{path}: missing column(s) {', '.join(missing)} (required: {', '.join(CSV_REQUIRED)}; "
                       f"header has: {', '.join(header)[:120]})")
    groups = {}
    for g, cols in CSV_GROUPS.items():
        have = [c for c in cols if c in header]
        if have and len(have) != len(cols):
            raise LogError(f"{path}: column(s) {', '.join(c for c in cols if c not in header)} missing "
                           f"beside {', '.join(have)} ({g} needs all of {', '.join(cols)})")
        groups[g] = bool(have)
    return header, groups


class _CsvRows:
    """Rows of one CSV log turned into SensorLog arrays a chunk at a time: what one chunk hands
    the next (the last time, the held sensor values) and the counts the log's meta needs
    (samples per sensor, reference rows left out) are kept here, so read_csv (one chunk) and
    CsvChunks (many) build the same arrays."""

    def __init__(self, path: Path, header: list[str], groups: dict):
        self.path, self.header, self.groups = path, header, groups
        self.col = {c: i for i, c in enumerate(header)}
        self.rows = 0                    # data rows so far
        self.t_first = self.t_last = None
        self.last = {}                   # sensor -> last sample (held into the next chunk)
        self.samples = {"gyro": 0, "accel": 0, "mag": 0, "gps": 0}
        self.ref_off = 0                 # reference rows whose norm is far from 1
        self.ref_finite = False          # some reference row is left to score
        self.first_moving = None         # time of the first row with movement = 1

    def chunk(self, data: np.ndarray, dt0: float | None = None) -> dict:
        """SensorLog fields of the next data rows (an (n, columns) array); dt0 is the first row's
        dt when these are the log's first rows (else the step from the previous chunk's last t)."""
        path, col, groups = self.path, self.col, self.groups
        first = self.rows + 2            # line number of data[0] (non-empty lines, header = 1)

        def block(cols):
            return data[:, [col[c] for c in cols]]

        t = data[:, col["t"]]
        if not np.all(np.isfinite(t)):
            raise LogError(f"{path}: line {int(np.flatnonzero(~np.isfinite(t))[0]) + first}: time t is empty or not finite")
        tt = t if self.t_last is None else np.concatenate(([self.t_last], t))
        back = np.flatnonzero(np.diff(tt) <= 0)
        if len(back):
            k = int(back[0]) + (first + 1 if self.t_last is None else first)
            raise LogError(f"{path}: line {k}: time t = {float(tt[back[0] + 1])!r} does not increase "
                           f"(previous {float(tt[back[0]])!r})")
        n = len(t)
        dt = np.diff(tt, prepend=np.nan)[-n:] if n else np.empty(0)
        if self.t_last is None and n:
            dt[0] = float(np.median(dt[1:])) if dt0 is None else dt0
        valid = np.zeros(n, dtype=np.uint32)
        arrays = {}
        for key, cols, bit in (("gyro", CSV_REQUIRED[1:4], VALID_GYRO), ("accel", CSV_REQUIRED[4:7], VALID_ACCEL),
                               ("mag", CSV_GROUPS["mag"], VALID_MAG), ("gps", CSV_GROUPS["gps"], VALID_GPS)):
            if key in ("mag", "gps") and not groups[key]:
                arrays[key] = np.full((n, 3), np.nan)
                continue
            v = block(cols)
            arrived = np.all(np.isfinite(v), axis=1)
            valid[arrived] |= np.uint32(bit)
            arrays[key] = _hold(v, arrived, self.last.get(key))
            if n:
                self.last[key] = arrays[key][-1].copy()
            self.samples[key] += int(arrived.sum())
        q_true = None
        if groups["reference"]:
            q_true = block(CSV_GROUPS["reference"])
            q_true[~np.all(np.isfinite(q_true), axis=1)] = np.nan
            # a row whose norm is far from 1 (zeros, a scaled or garbled quaternion) is no attitude:
            # left out of the score like a non-finite row, and counted
            norm = np.linalg.norm(q_true, axis=1)
            off = np.isfinite(norm) & (np.abs(norm - 1.0) > REF_NORM_TOL)
            if off.any():
                q_true[off] = np.nan
                self.ref_off += int(off.sum())
            self.ref_finite = self.ref_finite or bool(np.isfinite(q_true).any())
        movement = None
        if groups["movement"]:
            mv = data[:, col["movement"]]
            movement = np.isfinite(mv) & (mv > 0.5)
            moving = np.flatnonzero(movement)
            if self.first_moving is None and len(moving):
                self.first_moving = float(t[moving[0]])
        if n:
            self.t_first = float(t[0]) if self.t_first is None else self.t_first
            self.t_last = float(t[-1])
        self.rows += n
        return {"t": t, "dt": dt, "gyro": arrays["gyro"], "accel": arrays["accel"], "mag": arrays["mag"],
                "gps_vel": arrays["gps"], "valid": valid, "q_true": q_true, "movement": movement}

    def meta(self, dt0: float) -> dict:
        """The log's meta once every row is read (as read_csv has always given it)."""
        path, header, groups = self.path, self.header, self.groups
        known = set(CSV_REQUIRED).union(*CSV_GROUPS.values())
        duration = max(float(self.t_last - self.t_first), 1e-9)
        ref_warnings = []
        if self.ref_off:
            ref_warnings.append(f"{path.name}: {self.ref_off} reference row(s) with a quaternion norm "
                                f"outside 1 +- {REF_NORM_TOL:g} (e.g. all zeros) left out of the score")
            if not self.ref_finite:
                ref_warnings[-1] += ": no reference row is left, nothing to score"
        broad = header == BROAD_COLUMNS
        stem = path.name.split(".")[0]
        meta = {
            "source": "BROAD" if broad else "CSV",
            "description": (f"BROAD trial {stem} (optical motion capture reference)" if broad
                            else f"CSV log {path.name} ({duration:.1f} s)"),
            "file": str(path),
            "rate_hz": 1.0 / dt0,
            "columns": header,
            "ignored_columns": [h for h in header if h not in known],
            "warnings": ref_warnings,
        }
        meta.update({f"{k}_rate_hz": float(v / duration) for k, v in self.samples.items()
                     if k != "gyro" and (k not in ("mag", "gps") or groups[k])})
        if broad:
            meta.update({"citation": BROAD_CITATION, "mag_unit": "uT", "heading_reference": "magnetic north",
                         "reference": "optical motion capture (NaN where markers were lost)"})
        elif groups["reference"] and self.ref_finite:
            meta["reference"] = "the log's qw, qx, qy, qz columns"
        if groups["movement"]:
            meta["settle_time"] = float(self.first_moving - self.t_first) if self.first_moving is not None else 0.0
            meta["scoring"] = "broad"
        else:
            meta["settle_time"] = min(10.0, 0.2 * duration)
        return meta


def read_csv(path: str | os.PathLike, name: str | None = None) -> SensorLog:
    """A CSV log (.csv or .csv.gz), header-driven; the format is docs/log-format.md.

    Required columns t, gx, gy, gz, ax, ay, az; optional groups mx, my, mz (magnetometer),
    gps_vn, gps_ve, gps_vd (GPS velocity, NED m/s), qw, qx, qy, qz (reference attitude),
    movement (1 = score this row, BROAD's method). A row is one step; a sensor whose fields are
    empty or NaN in a row delivered no sample there (its valid bit is clear), so every sensor
    has its own rate. Other columns are ignored (listed in meta['ignored_columns']).
    The whole file is read at once; CsvChunks reads a log of any size a chunk at a time.
    """
    path = Path(path)
    text = _read_text(path)
    lines = [ln.strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines:
        raise LogError(f"{path}: empty file (expected a header line: {','.join(CSV_REQUIRED)},...)")
    header, groups = _csv_header(path, lines[0])
    data = _parse_rows(path, lines[1:], len(header))
    if len(data) < 2:
        raise LogError(f"{path}: {len(data)} data row(s); a log needs at least two")
    rows = _CsvRows(path, header, groups)
    f = rows.chunk(data)
    meta = rows.meta(float(f["dt"][0]))
    if f["movement"] is not None:
        meta["movement"] = f["movement"]
    stem = path.name.split(".")[0]
    return SensorLog(name or stem, f["t"], f["dt"], f["gyro"], f["accel"], f["mag"], f["gps_vel"], f["valid"],
                     f["q_true"] if rows.ref_finite else None, meta)


def write_csv(log: SensorLog, path: str | os.PathLike) -> Path:
    """Write a SensorLog in the CSV format read_csv reads: a sensor without a sample in a row
    (valid bit clear) has empty fields there; the reference where the log has one, and the
    movement column where meta['movement'] exists. Gzip when the name ends in .gz; atomic."""
    from ahrsgen.fileio import write_atomic
    cols = list(CSV_REQUIRED) + list(CSV_GROUPS["mag"]) + list(CSV_GROUPS["gps"])
    blocks = [(VALID_GYRO, log.gyro), (VALID_ACCEL, log.accel), (VALID_MAG, log.mag), (VALID_GPS, log.gps_vel)]
    has_ref = log.q_true is not None
    mv = log.meta.get("movement")
    if has_ref:
        cols += list(CSV_GROUPS["reference"])
    if mv is not None:
        cols += ["movement"]
    lines = [",".join(cols)]
    for k in range(len(log)):
        v = int(log.valid[k])
        parts = [repr(float(log.t[k]))]
        for bit, arr in blocks:
            parts.extend(repr(float(x)) for x in arr[k]) if v & bit else parts.extend(("", "", ""))
        if has_ref:
            q = log.q_true[k]
            parts.extend(repr(float(x)) for x in q) if np.all(np.isfinite(q)) else parts.extend(("",) * 4)
        if mv is not None:
            parts.append("1" if mv[k] else "0")
        lines.append(",".join(parts))
    data = ("\n".join(lines) + "\n").encode()
    if str(path).endswith(".gz"):
        data = gzip.compress(data, mtime=0)
    return write_atomic(path, data)


def read_broad(path: str | os.PathLike, name: str | None = None) -> SensorLog:
    """One BROAD trial (the CSV format with BROAD's 15 columns; see read_csv)."""
    return read_csv(path, name)
