"""Logs of any size (issue 27): readers.CsvChunks gives read_csv's arrays a chunk at a time, and
`run` over a log read in chunks prints and writes what it does over the whole log.

Checked against the whole-file reader and the whole-log run, with tiny chunks (a few hundred
bytes of text) so every boundary case is crossed on the committed BROAD excerpt. Speed is the
benchmark's (studies/large_log_bench.py), not a test's.
"""
from __future__ import annotations

import codecs
import gzip
import io
import math

import numpy as np
import pytest

from ahrsgen.sim import host, readers
from ahrsgen.sim.log import VALID_MAG
from ahrsgen.sim.peers import rotate_heading
from ahrsgen import bench
from ahrsgen.bench import run as run_mod
from ahrsgen.bench.scoring import score

EXCERPT = readers.EXCERPTS / "broad_01_excerpt.csv.gz"
FIELDS = ("t", "dt", "gyro", "accel", "mag", "gps_vel", "valid", "q_true")


def _variant(tmp_path, name="v.csv", bom=True, movement=True, rows=None):
    """The excerpt rewritten: the magnetometer at a third of the rate (empty fields), a BOM."""
    log = readers.read_csv(EXCERPT)
    if rows:
        log = log.slice(0, rows)
        if movement:
            log.meta["movement"] = log.meta["movement"][:rows]
    log.valid[np.arange(len(log)) % 3 != 0] &= ~np.uint32(VALID_MAG)
    if not movement:
        log.meta.pop("movement")
    p = tmp_path / "plain.csv"
    readers.write_csv(log, p)
    data = (codecs.BOM_UTF8 if bom else b"") + p.read_bytes()
    out = tmp_path / name
    out.write_bytes(gzip.compress(data) if name.endswith(".gz") else data)
    return out


def _concat(chunks):
    return {f: np.concatenate([getattr(c, f) for c in chunks]) for f in FIELDS}


@pytest.mark.parametrize("name,block", [("v.csv", 300), ("v.csv.gz", 300), ("v.csv", 7000), ("v.csv", 1 << 30)])
def test_chunks_give_read_csv_arrays(tmp_path, name, block):
    p = _variant(tmp_path, name)
    whole = readers.read_csv(p)
    cs = readers.CsvChunks(p, block_bytes=block)
    chunks = list(cs)
    assert (len(chunks) > 1) == (block < 1 << 30)
    got = _concat(chunks)
    for f in FIELDS:
        a, b = got[f], getattr(whole, f)
        if f == "dt":          # the first row's dt: the median step of the first chunk
            assert a[0] == np.median(np.diff(chunks[0].t))
            a, b = a[1:], b[1:]
        assert np.array_equal(a, b, equal_nan=True), f
    assert np.array_equal(np.concatenate([c.meta["movement"] for c in chunks]), whole.meta["movement"])
    meta = {k: v for k, v in whole.meta.items() if k not in ("movement", "rate_hz")}
    assert {k: v for k, v in cs.meta.items() if k != "rate_hz"} == meta
    assert cs.rows == len(whole)
    assert not np.isfinite(whole.mag[1:3]).all() or np.array_equal(whole.mag[1], whole.mag[0])  # held values


def _lines(tmp_path):
    return _variant(tmp_path, bom=False, rows=120).read_text().splitlines()


@pytest.mark.parametrize("k", [1, 2, 3, 17, 18, 19, 60, 119, 120])
@pytest.mark.parametrize("fault", ["field", "count", "time", "time_nan"])
def test_errors_name_the_same_line_across_chunks(tmp_path, k, fault):
    lines = _lines(tmp_path)
    f = lines[k].split(",")
    if fault == "field":
        f[3] = "x1"
    elif fault == "count":
        f = f[:-1]
    elif fault == "time":
        f[0] = lines[k - 1].split(",")[0] if k > 1 else "1e9"
    else:
        f[0] = ""
    lines[k] = ",".join(f)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(readers.LogError) as whole:
        readers.read_csv(p)
    for block in (100, 700, 1 << 30):
        with pytest.raises(readers.LogError) as chunked:
            list(readers.CsvChunks(p, block_bytes=block))
        assert str(chunked.value) == str(whole.value)


@pytest.mark.parametrize("text", ["", "\n\n", "t,gx,gy,gz,ax,ay,az\n", "t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,-9.8\n",
                                  "t,gx,gx,gz\n", "t,gx,gy,gz,ax,ay,az,mx\n", "t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,\xe9\n"])
def test_short_and_bad_files_same_error(tmp_path, text):
    p = tmp_path / "s.csv"
    p.write_bytes(text.encode("latin-1"))
    with pytest.raises(readers.LogError) as whole:
        readers.read_csv(p)
    with pytest.raises(readers.LogError) as chunked:
        list(readers.CsvChunks(p, block_bytes=30))
    assert str(chunked.value) == str(whole.value)


def _whole_with_dt0(p, cs):
    whole = readers.read_csv(p)
    whole.dt[0] = cs.head.dt[0] if cs.head is not None else whole.dt[0]
    return whole


@pytest.mark.parametrize("movement", [True, False])
def test_run_chunked_equals_whole(tmp_path, movement):
    """Score, status counts and the --csv file of a run read in chunks are the whole log's: the
    C filter's state is carried exactly; sums of chunks differ from one sum by rounding only."""
    p = _variant(tmp_path, movement=movement)
    cs = readers.CsvChunks(p, block_bytes=4000)
    list(cs)                                   # its first chunk's dt[0]
    whole = _whole_with_dt0(p, cs)
    out_c, out_w = io.StringIO(), io.StringIO()
    rc = bench.run_on_log("qcf", str(p), log=cs, csv=tmp_path / "c.csv", out=out_c)
    rw = bench.run_on_log("qcf", str(p), log=whole, csv=tmp_path / "w.csv", out=out_w)
    assert rc["res"] is None and rc["steps"] == rw["steps"] == len(whole)
    assert rc["score"]["n"] == rw["score"]["n"] and rc["score"]["nonfinite"] == rw["score"]["nonfinite"]
    for k, v in rw["score"].items():
        assert rc["score"][k] == pytest.approx(v, rel=1e-12, abs=1e-12), k
    assert (tmp_path / "c.csv").read_bytes() == (tmp_path / "w.csv").read_bytes()
    drop = lambda s: [ln for ln in s.splitlines() if not ln.startswith(("run qcf", "  wrote"))]  # noqa: E731
    assert drop(out_c.getvalue()) == drop(out_w.getvalue())


def test_heading_offset_scored_in_two_passes(tmp_path):
    """A filter without a heading source: the constant offset over every scored row, then the
    errors, as score(..., "none") over the whole log (a noisy estimate with a 37 deg offset)."""
    p = _variant(tmp_path, movement=False)
    whole = readers.read_csv(p)
    rng = np.random.default_rng(3)
    q_ref = np.where(np.isfinite(whole.q_true), whole.q_true, [1.0, 0, 0, 0])
    q_all = rotate_heading(q_ref, math.radians(37.0)) + rng.normal(0, 0.01, (len(whole), 4))
    q_all /= np.linalg.norm(q_all, axis=1, keepdims=True)
    cs = readers.CsvChunks(p, block_bytes=3000)

    def results():
        k = 0
        for c in cs:
            yield c, host.RunResult(q_all[k:k + len(c)], np.zeros((len(c), 3)), np.zeros(len(c), np.uint32))
            k += len(c)

    sc = run_mod._ChunkScore("none")
    for c, r in results():
        sc.add(c, r)
    sc.finish(cs.meta["settle_time"])
    assert sc.offset_pending is False
    for c, r in results():
        sc.add(c, r)
    sc.finish(cs.meta["settle_time"])
    want = score(q_all, whole, "none")
    got = sc.sums.result()
    assert got["n"] == want["n"]
    for k, v in want.items():
        assert got[k] == pytest.approx(v, rel=1e-10), k


def test_plot_rows_decimate_with_status_kept():
    log = readers.read_csv(EXCERPT)
    pr = run_mod._PlotRows(limit=500)
    status = np.zeros(len(log), np.uint32)
    status[1001] = 4
    for a in range(0, len(log), 700):
        part = log.slice(a, a + 700)
        pr.add(part, part.q_true, status[a:a + 700])
    plog, q, st = pr.log(log.name, log.meta)
    assert 250 <= len(plog) <= 500 and np.all(np.diff(plog.t) > 0)
    assert np.count_nonzero(st) == 1        # the one flagged step stays visible


def test_plot_marks_faults_apart_from_information():
    """The plot's marks: a step with any fault bit is a fault (whatever else it sets), a step with
    only information bits (AT_REST) is information, a zero status is unmarked; and the run's
    tally counts the same fault steps a chunk at a time as over the whole run."""
    from ahrsgen import status as st
    # a filter's own bits: AT_REST information, a second one a fault
    fault = st.fault_mask([("AT_REST", "at rest", st.INFO), ("NUMERIC", "numeric trouble")])
    at_rest, numeric = st.FILTER_BASE, st.FILTER_BASE << 1
    s = np.array([0, at_rest, numeric, at_rest | st.ACCEL_NONFINITE, st.DT_INVALID, 0, at_rest], np.uint32)
    assert fault & st.ACCEL_NONFINITE and fault & numeric and not fault & at_rest
    bad, info = run_mod.status_marks(s, fault)
    assert bad.tolist() == [2, 3, 4] and info.tolist() == [1, 6]
    tally = run_mod.StatusTally(fault_mask=fault)
    tally.add(s[:3])
    tally.add(s[3:])
    assert tally.count(fault) == len(bad) and tally.count(0) - tally.count(fault) == len(info)


def test_cli_run_reads_a_large_log_in_chunks(tmp_path, monkeypatch, capsys):
    """`ahrsgen run` streams a CSV larger than one block: same score lines as the whole read."""
    from ahrsgen.cli import main
    p = _variant(tmp_path)
    monkeypatch.setattr(readers.chunks, "BLOCK_BYTES", 20000)
    assert main(["run", "qcf", "--log", str(p), "--plot", str(tmp_path / "p.png")]) == 0
    chunked = capsys.readouterr().out
    assert "read in chunks" in chunked and (tmp_path / "p.png").stat().st_size > 1000
    monkeypatch.setattr(readers.chunks, "BLOCK_BYTES", 1 << 30)
    assert main(["run", "qcf", "--log", str(p)]) == 0
    whole = capsys.readouterr().out
    tail = lambda s: s[s.index("error vs"):s.index("wrote") if "wrote" in s else None]  # noqa: E731
    assert tail(chunked).strip() == tail(whole).strip()


def test_without_pyarrow_same_arrays(tmp_path, monkeypatch):
    """A plain install (no pyarrow): every block goes through read_csv's numpy parser."""
    p = _variant(tmp_path, movement=False)
    with_arrow = _concat(list(readers.CsvChunks(p, block_bytes=5000)))
    monkeypatch.setattr(readers.chunks, "_arrow_csv", lambda: (None, None))
    without = _concat(list(readers.CsvChunks(p, block_bytes=5000)))
    for f in FIELDS:
        assert np.array_equal(with_arrow[f], without[f], equal_nan=True), f


def test_cli_a_bad_line_in_a_later_chunk_is_one_line(tmp_path, monkeypatch, capsys):
    """The chunks are read ahead in a thread (run._prefetched): a bad field far into the file
    still ends `run` with read_csv's one line naming that line, exit 2, and no --csv file."""
    from ahrsgen.cli import main
    lines = _lines(tmp_path)
    k = len(lines) - 5
    f = lines[k].split(",")
    f[3] = "x1"
    lines[k] = ",".join(f)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(readers.LogError) as whole:
        readers.read_csv(p)
    monkeypatch.setattr(readers.chunks, "BLOCK_BYTES", 2000)
    out = tmp_path / "o.csv"
    assert main(["run", "qcf", "--log", str(p), "--csv", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(whole.value) in err[0] and f"line {k + 1}" in err[0], err
    assert not out.exists()
