"""Real sensor logs -> SensorLog: BROAD CSV (converted layout) and PX4 ULog.

BROAD (Laidig, Caruso, Cereatti, Seel, *Data* 2021, 6(7), 72; CC BY 4.0), in the layout of
`shared/data/README.md`: gzip CSV `t,gx,gy,gz,ax,ay,az,mx,my,mz,qw,qx,qy,qz,movement`, already
in the product's conventions (FRD body, NED earth with magnetic north, specific force, rad/s,
µT). Every row is one IMU sample with gyro, accelerometer and magnetometer (all three valid
bits set); no GPS. The optical reference is `q_true` (NaN where the markers were lost); the
`movement` column goes to `meta['movement']` (bool array) for BROAD's scoring method, and
`meta['settle_time']` is the time of the first moving sample (the rest phase is for the
filter to settle).

PX4 ULog (pyulog): one step per `sensor_combined` message (gyro_rad is the mean rate over the
interval ending at `timestamp`, matching the SensorLog timing), accelerometer from the same
message. Magnetometer from `vehicle_magnetometer` (or `sensor_mag` instance 0, or the
`magnetometer_ga` fields of old `sensor_combined`); GPS velocity from `vehicle_gps_position`
(or `sensor_gps`) where `vel_ned_valid`. A mag/GPS sample is attached to the first IMU step
at or after its timestamp; its valid bit is set only on that step, other rows hold the last
value (NaN before the first). `vehicle_attitude.q` (body FRD -> NED, like ours) is
interpolated (normalised linear, sign-aligned) at the step times as `q_true`; it is PX4's own
EKF estimate, a reference rather than ground truth. PX4's heading is referenced to true
north; the declination the log used, where a parameter gives it, is `meta['declination_deg']`.
Logs start with PX4's estimator already running, so `meta['settle_time']` is short:
min(2 s, 20 % of the log).

`read_log(path)` picks the reader from the file name. `shared_data_dir()` finds the full
data sets (`$AHRSGEN_DATA`, else `<repo>/../shared/data`).
"""
from __future__ import annotations

from ahrsgen.errors import LogError  # noqa: F401  (raised here; callers import it from here too)
import codecs
import contextlib
import gzip
import io
import os
import zlib
from pathlib import Path

import numpy as np

from ahrsgen import paths
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

REPO_ROOT = paths.CHECKOUT   # None for an installed wheel
# Small real logs installed with the package (attribution in its README): the tests, `bench
# --quick` and the documentation's examples read them, in a checkout or an installed wheel alike.
EXCERPTS = Path(__file__).resolve().parent / "data"
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


# Reading a log a chunk at a time. A block of about BLOCK_BYTES of text (cut at a line end) is
# one chunk: ~25 000 rows of a 15-column log, ~3 MB of arrays, whatever the file's size
# (measured, studies/large_log_bench.py: 16 MiB blocks peaked at 320 MB on a 200 MB log, 4 MiB
# at 186 MB, at the same speed).
BLOCK_BYTES = 4 << 20
PARSE_AHEAD = 2        # blocks parsed ahead of the one being used (CsvChunks, with pyarrow)


def _arrow_csv():
    """pyarrow.csv when installed (the optional `fast` extra), else None: its multi-threaded
    parser reads a block several times faster than numpy's."""
    try:
        import pyarrow
        import pyarrow.csv as pacsv
    except ImportError:
        return None, None
    return pyarrow, pacsv


class CsvChunks:
    """A CSV log (the format of read_csv) read in bounded memory: iterating yields SensorLog
    chunks of consecutive rows, about `block_bytes` of text each, with the arrays read_csv
    would give for those rows (sensor values held across chunk ends, dt of a chunk's first row
    from the previous chunk). A file's errors are read_csv's, with the same line numbers, each
    raised when its chunk is reached; the header's are raised here, at once.

    Differences from read_csv, for a log longer than its first chunk: the first row's dt (and
    meta['rate_hz']) is the median step of the first chunk rather than of the whole log; a
    chunk's meta holds its own rows' 'movement'. After the last chunk, `meta` is the log's
    meta as read_csv gives it (without the 'movement' array) and `rows` the number of rows;
    `head` is the first chunk. Iterating again reads the file again.
    Rows are parsed by pyarrow when it is installed (a block it refuses is parsed again by
    read_csv's parser, which names the bad line), else by read_csv's parser.
    """

    def __init__(self, path: str | os.PathLike, name: str | None = None, block_bytes: int | None = None):
        self.path = Path(path)
        self.name = name or self.path.name.split(".")[0]
        self.block_bytes = max(1, int(BLOCK_BYTES if block_bytes is None else block_bytes))
        self.size = self.path.stat().st_size
        self.done_bytes = 0                 # bytes of the file (compressed, for .gz) read so far
        self.rows = None
        self.head = None
        for header_line, _, _ in self._blocks():
            break
        else:
            header_line = None
        if header_line is None:
            raise LogError(f"{self.path}: empty file (expected a header line: {','.join(CSV_REQUIRED)},...)")
        self.header, self.groups = _csv_header(self.path, header_line)
        known = set(CSV_REQUIRED).union(*CSV_GROUPS.values())
        self.meta = {"source": "BROAD" if self.header == BROAD_COLUMNS else "CSV", "file": str(self.path),
                     "columns": self.header, "ignored_columns": [h for h in self.header if h not in known],
                     "warnings": []}
        if self.groups["movement"]:
            self.meta["scoring"] = "broad"

    def _blocks(self):
        """(header line, data bytes of a block, number of the block's first byte) in file order;
        the header line is found in the first block (None before it). Damaged gzip data, text
        that is not UTF-8: LogError as read_csv says it."""
        path = self.path
        gz = str(path).endswith(".gz")
        with _gzip_errors(path):
            with open(path, "rb") as raw:
                f = gzip.GzipFile(fileobj=raw, mode="rb") if gz else raw
                pos, header = 0, None
                while True:
                    block = f.read(self.block_bytes)
                    if block and not block.endswith(b"\n"):
                        block += f.readline()          # whole lines only
                    self.done_bytes = raw.tell()
                    if not block:
                        if header is not None:
                            return
                        yield None, b"", pos
                        return
                    start = pos
                    pos += len(block)
                    if start == 0 and block.startswith(codecs.BOM_UTF8):
                        block = block[3:]                # a byte-order mark is not a column
                        start = 3
                    if not block.isascii():
                        try:
                            block.decode("utf-8")
                        except UnicodeDecodeError as e:
                            raise LogError(f"{path}: not a text file (byte {start + e.start} is not UTF-8)") from None
                    if header is None:                   # the first non-empty line
                        for k, ln in enumerate(block.split(b"\n")):
                            if ln.strip():
                                header = ln.decode("utf-8").strip()
                                block = b"\n".join(block.split(b"\n")[k + 1:])
                                break
                        else:
                            continue
                    yield header, block, start

    def _arrow(self, block: bytes) -> np.ndarray | None:
        """The block's rows as an (n, columns) array by pyarrow, or None (no pyarrow, or a block
        it refuses). Releases the GIL: __iter__ parses two blocks at once."""
        ncol = len(self.header)
        pa, pacsv = _arrow_csv()
        if pa is None:
            return None
        try:
            tab = pacsv.read_csv(
                pa.py_buffer(block),
                read_options=pacsv.ReadOptions(column_names=[f"c{j}" for j in range(ncol)],
                                               block_size=1 << 22, use_threads=False),
                parse_options=pacsv.ParseOptions(quote_char=False),
                convert_options=pacsv.ConvertOptions(column_types={f"c{j}": pa.float64() for j in range(ncol)},
                                                     null_values=[""], strings_can_be_null=False))
        except (pa.ArrowInvalid, pa.ArrowException):
            return None
        out = np.empty((tab.num_rows, ncol))
        for j, c in enumerate(tab.columns):
            out[:, j] = c.to_numpy()
        return out

    def _parse(self, block: bytes, first_line: int, arrow: np.ndarray | None = None) -> np.ndarray:
        """The block's rows as an (n, columns) array: pyarrow's where it reads them all (`arrow`,
        when already parsed), else (and for the error naming the line) read_csv's parser."""
        out = arrow if arrow is not None else self._arrow(block)
        if out is not None:
            return out
        lines = [ln.strip() for ln in block.decode("utf-8").splitlines()]
        return _parse_rows(self.path, [ln for ln in lines if ln], len(self.header), first_line)

    def _parsed_blocks(self):
        """(block, pyarrow's rows or None) in file order; with pyarrow, the next blocks are parsed
        on two worker threads while the caller works on this one (at most PARSE_AHEAD ahead)."""
        blocks = (block for _, block, _ in self._blocks() if block)
        if _arrow_csv()[0] is None:
            yield from ((b, None) for b in blocks)
            return
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor
        ex = ThreadPoolExecutor(2, thread_name_prefix="csv-parse")
        ahead: deque = deque()
        try:
            for b in blocks:
                ahead.append((b, ex.submit(self._arrow, b)))
                if len(ahead) > PARSE_AHEAD:
                    b0, f = ahead.popleft()
                    yield b0, f.result()
            while ahead:
                b0, f = ahead.popleft()
                yield b0, f.result()
        finally:
            ex.shutdown(wait=True, cancel_futures=True)

    def __iter__(self):
        rows = _CsvRows(self.path, self.header, self.groups)
        parsed = 0
        pending = []             # the first chunk waits for two rows (its median step)
        first = True
        for block, arrow in self._parsed_blocks():
            data = self._parse(block, parsed + 2, arrow)
            parsed += len(data)
            if first:
                pending.append(data)
                if parsed < 2:
                    continue
                data = np.concatenate(pending) if len(pending) > 1 else pending[0]
                pending = []
            if not len(data):
                continue
            chunk = self._log(rows, data)
            if first:
                self.head, first = chunk, False
            yield chunk
        if first:
            raise LogError(f"{self.path}: {parsed} data row(s); a log needs at least two")
        self.rows = rows.rows
        self.meta = rows.meta(float(self.head.dt[0]))

    def _log(self, rows: _CsvRows, data: np.ndarray) -> SensorLog:
        f = rows.chunk(data)
        meta = dict(self.meta)
        if f["movement"] is not None:
            meta["movement"] = f["movement"]
        return SensorLog(self.name, f["t"], f["dt"], f["gyro"], f["accel"], f["mag"], f["gps_vel"], f["valid"],
                         f["q_true"], meta)


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


# ---------------------------------------------------------------------------------------
# PX4 ULog

_REL_INVALID = 0x7FFFFFFF  # PX4's RELATIVE_TIMESTAMP_INVALID


def _field(d, name):
    return np.asarray(d.data[name], dtype=float)


def _vec(d, base):
    return np.column_stack([_field(d, f"{base}[{i}]") for i in range(3)])


def _time_us(d):
    """Sample time of a topic: timestamp_sample where present (when the sensor sampled)."""
    key = "timestamp_sample" if "timestamp_sample" in d.data else "timestamp"
    return np.asarray(d.data[key], dtype=np.int64)


def _dataset(ulog, names, multi_id=0):
    for nm in names:
        for d in ulog.data_list:
            if d.name == nm and d.multi_id == multi_id:
                return d
    return None


def _attach(t_steps_us, t_ev_us, values, n_cols):
    """Attach events to the first step at or after their time; (held values, arrived mask)."""
    n = len(t_steps_us)
    out = np.full((n, n_cols), np.nan)
    arrived = np.zeros(n, dtype=bool)
    if len(t_ev_us) == 0:
        return out, arrived
    k = np.searchsorted(t_steps_us, t_ev_us, side="left")
    keep = k < n
    k, vals = k[keep], values[keep]
    # several events in one step: the last one wins (firmware reads the newest sample)
    last = np.ones(len(k), dtype=bool)
    last[:-1] = k[1:] != k[:-1]
    k, vals = k[last], vals[last]
    arrived[k] = True
    # hold the last value on rows without a new sample
    idx = np.full(n, -1)
    idx[k] = np.arange(len(k))
    idx = np.maximum.accumulate(idx)
    have = idx >= 0
    out[have] = vals[idx[have]]
    return out, arrived


def _interp_quat(t_ref, q_ref, t, max_gap):
    """Normalised linear interpolation of a quaternion sequence (sign-aligned); NaN outside."""
    q_ref = np.array(q_ref, dtype=float)
    for i in range(1, len(q_ref)):   # make the sequence sign-continuous
        if np.dot(q_ref[i], q_ref[i - 1]) < 0:
            q_ref[i] = -q_ref[i]
    out = np.full((len(t), 4), np.nan)
    j = np.searchsorted(t_ref, t, side="right") - 1
    ok = (j >= 0) & (j < len(t_ref) - 1)
    j0 = j[ok]
    t0, t1 = t_ref[j0], t_ref[j0 + 1]
    gap_ok = (t1 - t0) <= max_gap
    a = ((t[ok] - t0) / (t1 - t0))[:, None]
    q = (1 - a) * q_ref[j0] + a * q_ref[j0 + 1]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[~gap_ok] = np.nan
    out[np.flatnonzero(ok)] = q
    exact = (j == len(t_ref) - 1) & (t == t_ref[-1])
    out[exact] = q_ref[-1]
    return out


ULOG_MAGIC = b"ULog\x01\x12\x35"


def ulog_truncation(path: str | os.PathLike) -> str | None:
    """Where a ULog file ends inside a record (a log cut in half), as a sentence; None if it ends
    on a record boundary. Walks the record headers (uint16 size, uint8 type) after the 16-byte
    file header; pyulog drops such a last record silently."""
    data = Path(path).read_bytes()
    pos, n, records = 16, len(data), 0
    while pos + 3 <= n:
        size = int.from_bytes(data[pos:pos + 2], "little")
        if pos + 3 + size > n:
            return (f"the file ends in the middle of record {records + 1} (at byte {pos} of {n}, "
                    f"{pos + 3 + size - n} bytes missing): the log was cut off")
        pos += 3 + size
        records += 1
    if pos != n:
        return f"the file ends in the middle of a record header (at byte {pos} of {n}): the log was cut off"
    return None


def read_ulog(path: str | os.PathLike, name: str | None = None) -> SensorLog:
    """A PX4 ULog file mapped into a SensorLog (see module docstring)."""
    path = Path(path)
    try:
        from pyulog import ULog
    except ImportError:
        raise LogError(f"{path}: reading PX4 ULog needs the pyulog package: pip install 'ahrsgen[dev]'") from None
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head and len(head) < 16 and (head.startswith(ULOG_MAGIC) or ULOG_MAGIC.startswith(head)):
        raise LogError(f"{path}: truncated PX4 ULog file ({len(head)} bytes, shorter than the 16-byte ULog header)")
    if len(head) < 16 or not head.startswith(ULOG_MAGIC):
        raise LogError(f"{path}: not a PX4 ULog file (it does not start with the ULog header)")
    try:
        import contextlib
        with contextlib.redirect_stdout(io.StringIO()):      # pyulog prints its corruption notes
            ulog = ULog(str(path))
    except Exception as e:                                    # pyulog raises bare exceptions on bad data
        raise LogError(f"{path}: unreadable ULog file ({type(e).__name__}: {str(e)[:80]})") from None
    warnings = []
    cut = ulog_truncation(path)
    if cut:
        warnings.append(f"{path.name}: {cut}")
    if ulog.file_corruption:
        warnings.append(f"{path.name}: pyulog found corrupt records and skipped them")
    sc = _dataset(ulog, ["sensor_combined"])
    if sc is None:
        raise LogError(f"{path}: no sensor_combined topic (needed for gyro and accelerometer)"
                       + (f"; {cut}" if cut else ""))
    if len(sc.data["timestamp"]) < 2:
        raise LogError(f"{path}: {len(sc.data['timestamp'])} sensor_combined sample(s); a log needs at least two")
    t_us = np.asarray(sc.data["timestamp"], dtype=np.int64)
    order = np.argsort(t_us, kind="stable")
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = np.diff(t_us[order]) > 0          # drop duplicated timestamps
    rows = order[keep]
    t_us = t_us[rows]
    n = len(t_us)
    gyro = _vec(sc, "gyro_rad")[rows]
    accel = _vec(sc, "accelerometer_m_s2")[rows]
    t0 = t_us[0]
    t = (t_us - t0) * 1e-6
    dt = np.empty(n)
    dt[1:] = np.diff(t)
    dt[0] = float(np.median(dt[1:])) if n > 1 else 0.004
    valid = np.full(n, VALID_GYRO | VALID_ACCEL, dtype=np.uint32)
    meta = {"source": "PX4 ULog", "file": str(path), "scoring": "px4", "warnings": warnings}

    # magnetometer
    mag_src = None
    vm = _dataset(ulog, ["vehicle_magnetometer"])
    sm = _dataset(ulog, ["sensor_mag"])
    if vm is not None:
        ev_t, ev_v, mag_src = _time_us(vm), _vec(vm, "magnetometer_ga"), "vehicle_magnetometer"
    elif sm is not None:
        ev_t = _time_us(sm)
        ev_v = np.column_stack([_field(sm, c) for c in ("x", "y", "z")])
        mag_src = "sensor_mag"
    elif "magnetometer_ga[0]" in sc.data:
        rel = np.asarray(sc.data["magnetometer_timestamp_relative"], dtype=np.int64)
        ts = np.asarray(sc.data["timestamp"], dtype=np.int64)
        ok = rel != _REL_INVALID
        abs_t = ts + rel
        vals = _vec(sc, "magnetometer_ga")
        new = np.ones(len(abs_t), dtype=bool)
        new[1:] = abs_t[1:] != abs_t[:-1]
        sel = ok & new
        ev_t, ev_v, mag_src = abs_t[sel], vals[sel], "sensor_combined.magnetometer_ga"
    if mag_src is not None:
        o = np.argsort(ev_t, kind="stable")
        mag, arrived = _attach(t_us, ev_t[o], ev_v[o], 3)
        valid[arrived] |= VALID_MAG
        meta["mag_source"] = mag_src
        meta["mag_unit"] = "gauss"
        meta["mag_rate_hz"] = float(arrived.sum() / max(t[-1] - t[0], 1e-9))
    else:
        mag = np.full((n, 3), np.nan)

    # GPS velocity
    gp = _dataset(ulog, ["vehicle_gps_position", "sensor_gps"])
    gps = np.full((n, 3), np.nan)
    if gp is not None:
        ev_t = _time_us(gp)
        ev_v = np.column_stack([_field(gp, f"vel_{c}_m_s") for c in "ned"])
        ok = np.ones(len(ev_t), dtype=bool)
        if "vel_ned_valid" in gp.data:
            ok &= np.asarray(gp.data["vel_ned_valid"]).astype(bool)
        o = np.argsort(ev_t[ok], kind="stable")
        gps, arrived = _attach(t_us, ev_t[ok][o], ev_v[ok][o], 3)
        valid[arrived] |= VALID_GPS
        meta["gps_source"] = gp.name
        meta["gps_rate_hz"] = float(arrived.sum() / max(t[-1] - t[0], 1e-9))

    # reference attitude (PX4's onboard estimate)
    q_true = None
    va = _dataset(ulog, ["vehicle_attitude"])
    if va is not None:
        ta = _time_us(va)
        qa = np.column_stack([_field(va, f"q[{i}]") for i in range(4)])
        o = np.argsort(ta, kind="stable")
        q_true = _interp_quat((ta[o] - t0) * 1e-6, qa[o], t, max_gap=0.1)
        meta["reference"] = "PX4 vehicle_attitude (onboard estimator, not ground truth)"
        meta["heading_reference"] = "true north (PX4)"

    params = ulog.initial_parameters
    for key in ("EKF2_MAG_DECL", "ATT_MAG_DECL"):
        if key in params:
            meta["declination_deg"] = float(params[key])
            meta["declination_param"] = key
            break
    duration = float(t[-1] - t[0])
    meta.update({
        "description": f"PX4 log {path.name} ({duration:.1f} s, sensor_combined at "
                       f"{1.0 / np.median(dt[1:]):.0f} Hz)",
        "rate_hz": float(1.0 / np.median(dt[1:])),
        "settle_time": min(2.0, 0.2 * duration),   # PX4 logs start with the EKF running
        "start_timestamp_us": int(t0),
    })
    return SensorLog(name or path.stem, t, dt, gyro, accel, mag, gps, valid, q_true, meta)


REF_NORM_TOL = 0.1        # a reference quaternion whose norm is further than this from 1 is skipped


def unit_warnings(log: SensorLog) -> list[str]:
    """Units recognised from the data, one line each (empty when they look right):

    - accelerometer: the median norm of its samples is g at rest and in most flight; a log in g
      reads about 1, in mg about 1000;
    - gyro: a direction fixed in NED (gravity, the field) seen in body axes turns as
      du/dt = -omega x u. The least-squares scale s in du/dt = -s (omega x u) over the log is
      1 for rad/s and pi/180 = 0.0175 for deg/s. Needs some rotation (else no line).
    """
    out = []
    acc_ok = (log.valid & VALID_ACCEL) != 0
    if acc_ok.sum() >= 10:
        med = float(np.median(np.linalg.norm(log.accel[acc_ok], axis=1)))
        if 0.5 < med < 2.0:
            out.append(f"the accelerometer looks like it is in g (median |a| = {med:.3g}), not m/s^2: "
                       f"multiply it by 9.80665")
        elif 500 < med < 2000:
            out.append(f"the accelerometer looks like it is in mg (median |a| = {med:.4g}), not m/s^2: "
                       f"multiply it by 0.00980665")
    s = gyro_scale(log)
    if s is not None and abs(s / (np.pi / 180) - 1) < 0.3:
        out.append(f"the gyro looks like it is in deg/s, not rad/s: the attitude change the accelerometer and "
                   f"magnetometer show is {s:.3g} x the gyro's (1 for rad/s, 0.0175 for deg/s)")
    elif s is not None and abs(s / (np.pi / 180e3) - 1) < 0.3:
        out.append(f"the gyro looks like it is in mdeg/s, not rad/s: the attitude change the accelerometer and "
                   f"magnetometer show is {s:.3g} x the gyro's (1 for rad/s)")
    return out


def gyro_scale(log: SensorLog, window_s: float = 0.05) -> float | None:
    """Least-squares s in du/dt = -s (omega x u) for the unit accelerometer and magnetometer
    directions u (see unit_warnings), over windows of about window_s; None when the log shows
    too little rotation to tell."""
    n = len(log)
    if n < 20:
        return None
    h = max(1, int(round(window_s / max(float(np.median(log.dt)), 1e-9))))
    num = den = seen = 0.0
    for bit, arr in ((VALID_ACCEL, log.accel), (VALID_MAG, log.mag)):
        ok = ((log.valid & bit) != 0) & ((log.valid & VALID_GYRO) != 0)
        a, b = np.arange(0, n - h), np.arange(h, n)
        pair = ok[a] & ok[b] & np.all(np.isfinite(log.gyro[a]), axis=1) & np.all(np.isfinite(log.gyro[b]), axis=1)
        a, b = a[pair], b[pair]
        if len(a) < 10:
            continue
        na, nb = np.linalg.norm(arr[a], axis=1), np.linalg.norm(arr[b], axis=1)
        # only samples of the undisturbed vector (norm within 5 % of its median): gravity without
        # motion acceleration, the field without a magnet nearby
        med = float(np.median(np.linalg.norm(arr[ok], axis=1))) if ok.any() else 0.0
        good = ((na > 0) & (nb > 0) & np.isfinite(na) & np.isfinite(nb)
                & (np.abs(na - med) < 0.05 * med) & (np.abs(nb - med) < 0.05 * med))
        a, b, na, nb = a[good], b[good], na[good], nb[good]
        ua, ub = arr[a] / na[:, None], arr[b] / nb[:, None]
        span = log.t[b] - log.t[a]
        du = (ub - ua) / span[:, None]
        w = 0.5 * (log.gyro[a] + log.gyro[b])
        pred = -np.cross(w, 0.5 * (ua + ub))
        num += float(np.sum(du * pred))
        den += float(np.sum(pred * pred))
        seen = max(seen, float(np.sqrt(np.mean(np.sum(du * du, axis=1)))))
    # the directions must show some rotation (0.05 rad/s RMS of |du/dt|): a still log says nothing
    if den <= 0 or seen < 0.05:
        return None
    return num / den


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
