"""A CSV log of any size read a chunk at a time (CsvChunks), in bounded memory."""
from __future__ import annotations

import codecs
import gzip
import os
from pathlib import Path

import numpy as np

from ahrsgen.errors import LogError
from ahrsgen.sim.log import SensorLog
from ahrsgen.sim.readers.csvlog import (BROAD_COLUMNS, CSV_GROUPS, CSV_REQUIRED, _CsvRows, _csv_header,
                                        _gzip_errors, _parse_rows)

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
