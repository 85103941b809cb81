"""Bad configs, logs and paths through the CLI: one line on stderr, exit 2, no traceback, nothing
written half-way (issue 11). Every case runs `ahrsgen` in-process through cli.main; an uncaught
exception (what a user sees as a traceback) fails the test. Compiling is forbidden in every case
(host.build raises), so a refused path or option is refused before the run, not after it.
"""
from __future__ import annotations

import gzip
import shutil
import sys
from pathlib import Path

import pytest

from conftest import cli_run as _run, REPO

from ahrsgen.sim import readers
from ahrsgen import cli
from ahrsgen.sim.readers import EXCERPTS

DATA = EXCERPTS
ULOG = DATA / "px4_small_excerpt.ulg"
BROAD = DATA / "broad_01_excerpt.csv.gz"
HEADER = "t,gx,gy,gz,ax,ay,az\n"
ROW = "0.01,0,0,0,0,0,-9.81\n"


def _file(tmp, name, content):
    p = tmp / name
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(content)
    return str(p)


def _truncated_gz(tmp):
    data = gzip.compress((HEADER + ROW * 2000).encode())
    return _file(tmp, "cut.csv.gz", data[: len(data) // 2])


# (id, argv builder (tmp -> argv, outputs that must not exist afterwards), text expected in the error)
CASES = [
    # -o of generate
    ("o-is-a-file", lambda t: (["generate", "qcf", "-o", _file(t, "f.txt", "x")], []), "not a folder"),
    ("o-under-a-file", lambda t: (["generate", "qcf", "-o", _file(t, "f.txt", "x") + "/sub"], []), "is a file"),
    ("o-dev-null", lambda t: (["generate", "qcf", "-o", "/dev/null"], []), "not a folder"),
    ("o-read-only", lambda t: (["generate", "qcf", "-o", "/proc/ahrsgen-out"], ["/proc/ahrsgen-out"]),
     "/proc"),
    # --json of target: refused before anything is built
    ("target-negative-count-steps", lambda t: (["target", "qcf", "--count-steps", "-3"], []), "whole number >= 0"),
    ("target-nan-tolerance", lambda t: (["target", "qcf", "--tolerance", "nan"], []), "finite number >= 0"),
    ("target-json-is-dir", lambda t: (["target", "qcf", "--json", str(t)], []), "is a folder"),
    ("target-json-under-file", lambda t: (["target", "qcf", "--json", _file(t, "f.txt", "x") + "/t.json"], []),
     "not a folder"),
    # --log of run
    ("log-empty-csv", lambda t: (["run", "qcf", "--log", _file(t, "e.csv", "")], []), "empty file"),
    ("log-header-only", lambda t: (["run", "qcf", "--log", _file(t, "h.csv", HEADER)], []), "0 data row"),
    ("log-missing-columns", lambda t: (["run", "qcf", "--log", _file(t, "m.csv", "t,gx,gy,gz\n0,0,0,0\n")], []),
     "missing column(s) ax, ay, az"),
    ("log-text-in-number", lambda t: (["run", "qcf", "--log", _file(t, "x.csv", HEADER + ROW + "0.02,0,abc,0,0,0,-9.81\n")],
                                      []), "line 3, column 3: 'abc' is not a number"),
    ("log-time-backwards", lambda t: (["run", "qcf", "--log", _file(t, "b.csv", HEADER + ROW + "0.005,0,0,0,0,0,-9.81\n")],
                                      []), "line 3: time t = 0.005 does not increase (previous 0.01)"),
    ("bench-data-missing", lambda t: (["bench", "--real-only", "--data", str(t / "nope"), "-o", str(t / "b")],
                                      [str(t / "b")]), "--data"),
    ("bench-data-is-file", lambda t: (["bench", "--real-only", "--data", _file(t, "d.txt", "x"), "-o", str(t / "b")],
                                      [str(t / "b")]), "is not a folder"),
    ("bench-seeds-zero", lambda t: (["bench", "--quick", "--seeds", "0", "-o", str(t / "b")], [str(t / "b")]),
     "--seeds: expected a whole number >= 1"),
    ("bench-jobs-zero", lambda t: (["bench", "--quick", "-j", "0", "-o", str(t / "b")], [str(t / "b")]),
     "expected a whole number >= 1, got '0'"),
    ("tune-budget-zero", lambda t: (["tune", "qcf", "--scenario", "turntable", "--params", "kp", "--budget", "0",
                                     "-o", str(t / "t.toml")], [str(t / "t.toml")]), "--budget"),
    ("target-cflags-opt", lambda t: (["target", "qcf", "--cflags=-O3 -g"], []), "--opt"),
    ("target-cflags-quote", lambda t: (["target", "qcf", "--cflags=-DX='a"], []), "No closing quotation"),
    ("log-truncated-gz", lambda t: (["run", "qcf", "--log", _truncated_gz(t)], []), "truncated gzip"),
    ("log-not-gzip", lambda t: (["run", "qcf", "--log", _file(t, "n.csv.gz", HEADER + ROW)], []), "not a gzip file"),
    ("log-not-ulog", lambda t: (["run", "qcf", "--log", _file(t, "n.ulg", "hello, not a ULog\n" * 10)], []),
     "not a PX4 ULog file"),
    ("log-100-byte-ulog", lambda t: (["run", "qcf", "--log", _file(t, "s.ulg", ULOG.read_bytes()[:100])], []), "ulg"),
    ("log-unknown-extension", lambda t: (["run", "qcf", "--log", _file(t, "a.txt", HEADER + ROW)], []),
     "unknown log format"),
    ("log-directory", lambda t: (["run", "qcf", "--log", str(t)], []), "is a folder"),
    ("log-missing", lambda t: (["run", "qcf", "--log", str(t / "nope.csv")], []), "does not exist"),
    # outputs of run: checked before the run
    ("plot-no-dir", lambda t: (["run", "qcf", "--log", str(BROAD), "--plot", str(t / "nodir" / "x.png")],
                               [str(t / "nodir")]), "does not exist"),
    ("csv-is-dir", lambda t: (["run", "qcf", "--log", str(BROAD), "--csv", str(t)], []), "not a regular file"),
    ("plot-bad-format", lambda t: (["run", "qcf", "--log", str(BROAD), "--plot", str(t / "x.xyz")],
                                   [str(t / "x.xyz")]), ".png"),
    # config files and options
    ("toml-not-utf8", lambda t: (["generate", "qcf", "--config", _file(t, "c.toml", b"prefix = \"\xff\xfe\"\n"),
                                  "-o", str(t / "out")], [str(t / "out")]), "not UTF-8"),
    ("config-without-filter", lambda t: (["generate", "--config", _file(t, "c.toml", "prefix = \"att\"\n"),
                                          "-o", str(t / "out")], [str(t / "out")]), "no 'filter"),
    ("no-filter-no-config", lambda t: (["generate", "-o", str(t / "out")], [str(t / "out")]), "name a filter"),
    ("prefix-math", lambda t: (["generate", "qcf", "--prefix", "math", "-o", str(t / "o")], [str(t / "o")]),
     "shadows the standard header <math.h>"),
    ("prefix-stdint", lambda t: (["generate", "qcf", "--prefix", "stdint", "-o", str(t / "o")], [str(t / "o")]),
     "<stdint.h>"),
    ("prefix-keyword", lambda t: (["generate", "qcf", "--prefix", "int", "-o", str(t / "o")], [str(t / "o")]),
     "C keyword"),
    ("prefix-empty", lambda t: (["generate", "qcf", "--prefix", "", "-o", str(t / "o")], [str(t / "o")]),
     "prefix is empty"),
    ("prefix-too-long", lambda t: (["generate", "qcf", "--prefix", "a" * 300, "-o", str(t / "o")], [str(t / "o")]),
     "300 characters long"),
    ("ulog-10-bytes", lambda t: (["run", "qcf", "--log", _file(t, "x.ulg", b"ULog\x01\x12\x35\x01\x00\x00")], []),
     "truncated PX4 ULog"),
    ("scenario-rate-huge", lambda t: (["validate", "qcf", "--scenario-opt", "rate_hz=1e9"], []), "IMU steps; at most"),
    ("scenario-duration-huge", lambda t: (["validate", "qcf", "--scenario-opt", "duration=1e6"], []), "IMU steps"),
    ("scenario-rate-huge-no-duration", lambda t: (["validate", "mekf", "--scenario", "gyro_clip", "--scenario-opt",
                                                   "rate_hz=1e6"], []), "IMU steps; at most"),
    ("scenario-flip-late", lambda t: (["validate", "mekf", "--scenario", "gyro_clip", "--scenario-opt",
                                       "flip_time=1e6"], []), "at most 600"),
    ("scenario-rate-half-hz", lambda t: (["validate", "qcf", "--scenario-opt", "rate_hz=0.5"], []), "at least 5 Hz"),
    ("validate-seed-negative", lambda t: (["validate", "qcf", "--seed", "-1"], []), "--seed"),
    ("validate-tolerance-negative", lambda t: (["validate", "qcf", "--tolerance", "-1"], []), "--tolerance"),
    ("scenario-opt-text", lambda t: (["validate", "qcf", "--scenario-opt", "duration=abc"], []), "'abc' is not a number"),
    ("scenario-opt-zero", lambda t: (["validate", "qcf", "--scenario-opt", "duration=0"], []), "duration must be"),
    ("scenario-opt-unknown", lambda t: (["validate", "qcf", "--scenario-opt", "bogus=1"], []), "unknown option 'bogus'"),
    ("scenario-opt-too-short", lambda t: (["validate", "qcf", "--scenario-opt", "duration=0.001"], []),
     "too short"),
    ("harden-soak-negative", lambda t: (["harden", "qcf", "--soak-steps", "-5"], []), "--soak-steps"),
    ("unknown-option", lambda t: (["generate", "qcf", "--bogus", "-o", str(t / "o")], [str(t / "o")]),
     "unrecognized arguments"),
]





@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_exit_2(case, tmp_path, capsys, no_build):
    _, build, expect = case
    argv, outputs = build(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    rc, out, err = _run(argv, capsys)
    assert rc == 2, (rc, out, err)
    assert err.count("\n") == 1 and err.startswith("ahrsgen"), err
    assert "Traceback" not in err + out
    assert expect in err, err
    for p in outputs:
        assert not Path(p).exists(), p
    # nothing new in the work folder (no partial or temporary file)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("module,argv_of", [
    ("matplotlib", lambda t: ["run", "qcf", "--log", str(BROAD), "--plot", str(t / "x.png")]),
    ("pyulog", lambda t: ["run", "qcf", "--log", str(ULOG)]),
])
def test_missing_extra_is_named(module, argv_of, tmp_path, capsys, monkeypatch, no_build):
    """Without the optional package: one line naming what to install, before any work."""
    for m in list(sys.modules):
        if m == module or m.startswith(module + "."):
            monkeypatch.delitem(sys.modules, m)
    monkeypatch.setitem(sys.modules, module, None)        # import raises ImportError
    rc, out, err = _run(argv_of(tmp_path), capsys)
    assert rc == 2 and err.count("\n") == 1 and "ahrsgen[dev]" in err, err
    assert not (tmp_path / "x.png").exists()


def test_two_filters_do_not_share_a_folder(tmp_path, capsys):
    """A second filter into the same folder would overwrite manifest.json: refused, first kept whole."""
    d = tmp_path / "out"
    assert _run(["generate", "qcf", "--prefix", "att", "-o", str(d)], capsys)[0] == 0
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    rc, out, err = _run(["generate", "qcf", "--prefix", "att2", "-o", str(d)], capsys)
    assert rc == 2 and err.count("\n") == 1 and "already holds the generated filter 'att'" in err, err
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before
    # the same prefix again regenerates in place
    assert _run(["generate", "qcf", "--prefix", "att", "-o", str(d)], capsys)[0] == 0


def test_generate_takes_the_filter_from_the_config(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text('filter = "qcf"\nprefix = "att"\n[params]\nkp = 0.5\n')
    rc, out, err = _run(["generate", "--config", str(cfg), "-o", str(tmp_path / "o")], capsys)
    assert rc == 0, err
    assert "kp = 0.5" not in err and (tmp_path / "o" / "att.h").exists()
    assert "0.5f" in (tmp_path / "o" / "att.c").read_text()


def test_target_opt_as_written_in_the_readme():
    """'--opt -O2' (README, --help) parses; so do '--opt=-Os' and repeats."""
    cli._load_extra_commands()
    p = cli.build_parser()
    a = p.parse_args(cli._join_dash_values(["target", "qcf", "--opt", "-O2", "--opt=-Os"]))
    assert a.opt == ["-O2", "-Os"]


def test_truncated_ulog_warns(tmp_path):
    """A ULog cut in the middle of a record is read up to the cut, with a warning saying so."""
    data = ULOG.read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: len(data) * 2 // 3 + 7])
    assert readers.ulog_truncation(ULOG) is None
    log = readers.read_log(cut)
    assert any("cut off" in w for w in log.meta["warnings"]), log.meta["warnings"]
    assert len(log) < len(readers.read_log(ULOG))
    shutil.copy(ULOG, tmp_path / "whole.ulg")
    assert readers.read_log(tmp_path / "whole.ulg").meta["warnings"] == []


def test_run_says_why_most_steps_were_refused(tmp_path, capsys):
    """A log whose time column is in nanoseconds runs (every step refused: dt too large): `run`
    fails and says what probably went wrong in one line on stderr; a good log gets no hint."""
    rows = "".join(f"{k * 4_000_000},0.01,0,0,0,0,-9.81\n" for k in range(1, 60))
    rc, out, err = _run(["run", "qcf", "--log", _file(tmp_path, "ns.csv", HEADER + rows)], capsys)
    assert rc == 1, out              # a filter that never ran is a failure (issue 27), said on stderr
    assert "refused: 59" in out and "most steps were refused for dt above dt_max" in err
    assert "median dt is 4e+06 s: is its time column t in seconds (not ms or us)?" in err
    rows = "".join(f"{k * 0.004},0.01,0,0,0,0,-9.81\n" for k in range(1, 60))
    rc, out, _ = _run(["run", "qcf", "--log", _file(tmp_path, "s.csv", HEADER + rows)], capsys)
    assert rc == 0 and "hint:" not in out, out


def test_version(capsys):
    from importlib import metadata
    rc, out, err = _run(["--version"], capsys)
    assert rc == 0 and out.strip() == f"ahrsgen {metadata.version('ahrsgen')}"


def test_a_closed_pipe_is_a_normal_end():
    """`ahrsgen list | head -1`: the reader closes the pipe; ahrsgen ends quietly with 0."""
    import subprocess
    p = subprocess.Popen([sys.executable, "-m", "ahrsgen.cli", "list"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.readline()
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 0, err
    assert err == ""


def test_ctrl_c_is_one_line_and_130(capsys, monkeypatch):
    """Ctrl-C while the commands are still importing (the first ~0.7 s): one line, exit 130."""
    def interrupted():
        raise KeyboardInterrupt
    monkeypatch.setattr(cli, "_load_extra_commands", interrupted)
    rc, out, err = _run(["list"], capsys)
    assert rc == 130 and err == "ahrsgen: interrupted\n" and out == ""


@pytest.mark.parametrize("how", ["raised", "returned"])
def test_an_error_caused_by_the_same_ctrl_c_is_the_interruption(capsys, monkeypatch, how):
    """A terminal's Ctrl-C reaches the whole process group: a compiler or a lock the command
    waits on can fail from it and surface as an ordinary error (exit 2) before the
    KeyboardInterrupt. When SIGINT was seen during the command, that is still one line and 130
    (CI saw `tune` end with 2 that way); the same error without a Ctrl-C stays exit 2."""
    from ahrsgen.errors import ConfigError

    def failing(args, interrupted=True):
        cli._INTERRUPTED[0] = interrupted
        if how == "raised":
            raise ConfigError("compiling failed: cc killed by signal 2")
        print("ahrsgen: error: compiling failed", file=sys.stderr)
        return 2
    monkeypatch.setattr(cli, "cmd_list", failing)
    rc, out, err = _run(["list"], capsys)
    assert rc == 130 and err.endswith("ahrsgen: interrupted\n"), err
    monkeypatch.setattr(cli, "cmd_list", lambda args: failing(args, interrupted=False))
    rc, out, err = _run(["list"], capsys)
    assert rc == 2 and "interrupted" not in err


def test_a_bad_folder_on_the_filter_path_does_not_break_list(tmp_path, capsys, monkeypatch):
    """A filter folder whose defaults.toml is not UTF-8, on AHRSGEN_FILTER_PATH: `list` still
    lists every other filter, names the bad one in one stderr line and exits 2; a command that
    names the bad folder gets one line too."""
    bad = tmp_path / "filters" / "broken"
    bad.mkdir(parents=True)
    for f in ("model.py", "reference.py", "step.c.j2"):
        (bad / f).write_text("")
    (bad / "defaults.toml").write_bytes(b"[filter]\ntitle = \"\xff\xfe\"\n")
    monkeypatch.setenv("AHRSGEN_FILTER_PATH", str(tmp_path / "filters"))
    rc, out, err = _run(["list"], capsys)
    assert rc == 2 and "qcf:" in out and "mekf:" in out
    assert err.count("\n") == 1 and "broken" in err and "not UTF-8" in err
    rc, out, err = _run(["generate", str(bad), "-o", str(tmp_path / "o")], capsys)
    assert rc == 2 and err.count("\n") == 1 and "not UTF-8" in err


def test_an_error_in_a_users_model_is_its_file_and_line(tmp_path, capsys):
    """An exception raised in a user's model.py: one line naming that file and line, exit 2,
    no traceback (issue 27)."""
    folder = tmp_path / "boomfilt"
    shutil.copytree(REPO / "examples" / "madgwick", folder,
                    ignore=shutil.ignore_patterns("__pycache__"))
    model = folder / "model.py"
    lines = model.read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("class Model"))
    body = next(i for i in range(at + 1, len(lines)) if lines[i].strip().startswith("def "))
    indent = lines[body][:len(lines[body]) - len(lines[body].lstrip())]
    lines.insert(body + 1, indent + "    raise RuntimeError('boom in my model')")
    model.write_text("\n".join(lines) + "\n")
    rc, out, err = _run(["generate", str(folder), "-o", str(tmp_path / "o")], capsys)
    assert rc == 2, err
    assert err.count("\n") == 1 and f"{model}:{body + 2}: RuntimeError: boom in my model" in err, err


def test_a_config_names_a_folder_relative_to_itself_and_says_it_runs_code(tmp_path, capsys, monkeypatch):
    """filter = "../filters/cfgfilt" in proj/cfg/att.toml resolves from proj/cfg/, wherever the
    command runs, and one stderr line says the folder's Python will run (issue 27)."""
    proj = tmp_path / "proj"
    shutil.copytree(REPO / "examples" / "madgwick", proj / "filters" / "cfgfilt",
                    ignore=shutil.ignore_patterns("__pycache__"))
    (proj / "cfg").mkdir()
    cfg = proj / "cfg" / "att.toml"
    cfg.write_text('filter = "../filters/cfgfilt"\n')
    monkeypatch.chdir(tmp_path)
    rc, out, err = _run(["generate", "--config", str(cfg), "-o", str(tmp_path / "o")], capsys)
    assert rc == 0, err
    assert (tmp_path / "o" / "cfgfilt.c").is_file()
    assert err.count("\n") == 1 and "brings in the filter folder" in err and "run as Python" in err


def test_a_run_shorter_than_its_settle_time_is_one_line(capsys):
    """validate mekf --scenario multirotor --scenario-opt duration=5 (settle time 5 s) raised
    a ValueError from the metrics; now one line, exit 2 (issue 27)."""
    rc, out, err = _run(["validate", "mekf", "--scenario", "multirotor", "--scenario-opt", "duration=5"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "shorter than its settle time" in err, err
