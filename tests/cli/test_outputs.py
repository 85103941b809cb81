"""Nothing of the user's is lost (issue 27): one rule for every output path of every command
(src/ahrsgen/fileio.py, docs/output-files.md), tried through the CLI.

1. An output is never an input of the same command (compared as real paths and by inode: the
   same name, a symbolic link, a hard link), nor another output of it. Refused even with --force.
2. An existing file is replaced only if ahrsgen wrote it (its marker) or with --force.

Every refusal is one line on stderr, exit 2, before anything is built (host.build raises), and
every file that was there before is byte-for-byte what it was.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from conftest import cli_run as _run, REPO

from ahrsgen.sim.readers import EXCERPTS
from ahrsgen import cli
from ahrsgen.fileio import written_by_ahrsgen

BROAD = EXCERPTS / "broad_01_excerpt.csv.gz"
MADGWICK = REPO / "examples" / "madgwick"


def _copy_log(t, name="in.csv.gz"):
    p = t / name
    shutil.copy(BROAD, p)
    return str(p)


def _file(t, name, content):
    p = t / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    return str(p)


def _symlink(t, target, name):
    os.symlink(target, t / name)
    return str(t / name)


def _hardlink(t, target, name):
    os.link(target, t / name)
    return str(t / name)


def _filter_folder(t):
    """A user's filter folder (a copy of examples/madgwick under its own name: a second folder
    named madgwick would clash with the example, which other tests load in this process)."""
    shutil.copytree(MADGWICK, t / "mymadg", ignore=shutil.ignore_patterns("__pycache__"))
    return str(t / "mymadg")


CONFIG = 'filter = "qcf"\n[params]\nkp = 0.5\n'
TUNE = ["--scenario", "turntable", "--params", "kp", "--budget", "2", "--folds", "0"]

# (id, argv builder tmp -> argv, text expected in the one error line)
REFUSED = [
    # class: an output that is an input of the same command (name, symlink, hard link; every input kind)
    ("run-csv-is-log", lambda t: ["run", "qcf", "--log", _copy_log(t), "--csv", str(t / "in.csv.gz")],
     "is an input of this command"),
    ("run-csv-is-log-relative", lambda t: ["run", "qcf", "--log", _copy_log(t), "--csv", "./in.csv.gz"],
     "is an input of this command"),
    ("run-export-log-is-log", lambda t: ["run", "qcf", "--log", _copy_log(t), "--export-log", str(t / "in.csv.gz")],
     "is an input of this command"),
    ("run-csv-symlink-to-log", lambda t: ["run", "qcf", "--log", _copy_log(t), "--csv",
                                          _symlink(t, t / "in.csv.gz", "l.csv")], "is an input of this command"),
    ("run-csv-hardlink-of-log", lambda t: ["run", "qcf", "--log", _copy_log(t), "--csv",
                                           _hardlink(t, t / "in.csv.gz", "h.csv")], "is an input of this command"),
    ("run-csv-is-config", lambda t: ["run", "qcf", "--log", str(BROAD), "--config", _file(t, "c.toml", CONFIG),
                                     "--csv", str(t / "c.toml"), "--force"], "is an input of this command"),
    ("run-csv-in-filter-folder", lambda t: ["run", _filter_folder(t), "--log", str(BROAD), "--csv",
                                            str(t / "mymadg" / "model.py"), "--force"],
     "is an input of this command"),
    ("run-input-forced", lambda t: ["run", "qcf", "--log", _copy_log(t), "--csv", str(t / "in.csv.gz"), "--force"],
     "is an input of this command"),
    ("generate-o-holds-config", lambda t: ["generate", "qcf", "--config", _file(t, "o/qcf.h", CONFIG), "-o",
                                           str(t / "o"), "--force"], "is an input of this command"),
    ("tune-o-is-log", lambda t: ["tune", "qcf", "--log", _copy_log(t), *TUNE, "-o", str(t / "in.csv.gz"), "--force"],
     "is an input of this command"),
    ("tune-report-is-config", lambda t: ["tune", "qcf", "--config", _file(t, "t.toml.json", CONFIG), *TUNE, "-o",
                                         str(t / "t.toml"), "--force"], "is an input of this command"),
    ("target-json-is-config", lambda t: ["target", "qcf", "--config", _file(t, "c.toml", CONFIG), "--json",
                                         str(t / "c.toml"), "--force"], "is an input of this command"),
    # class: two outputs of one command on one file
    ("run-csv-is-export-log", lambda t: ["run", "qcf", "--log", str(BROAD), "--csv", str(t / "o.csv"),
                                         "--export-log", str(t / "o.csv")], "is also the output of --csv"),
    ("run-plot-symlink-to-csv", lambda t: ["run", "qcf", "--log", str(BROAD), "--csv", str(t / "o.csv"), "--plot",
                                           _symlink(t, t / "o.csv", "o.png")], "is also the output of --csv"),
    # class: an existing file ahrsgen did not write (every command's every output)
    ("run-csv-foreign", lambda t: ["run", "qcf", "--log", str(BROAD), "--csv", _file(t, "mine.csv", "a,b\n1,2\n")],
     "was not written by ahrsgen"),
    ("run-plot-foreign", lambda t: ["run", "qcf", "--log", str(BROAD), "--plot", _file(t, "mine.png", b"\x89PNG")],
     "was not written by ahrsgen"),
    ("run-export-log-foreign", lambda t: ["run", "qcf", "--log", str(BROAD), "--export-log", _file(t, "e.csv", "x")],
     "was not written by ahrsgen"),
    ("generate-manifest-not-json", lambda t: ["generate", "qcf", "-o", str(t / "web"),
                                              _file(t, "web/manifest.json", "<html>not json</html>") and "--math=fast"],
     "was not written by ahrsgen"),
    ("generate-manifest-web-app", lambda t: ["generate", "qcf", "-o", str(t / "web"),
                                             _file(t, "web/manifest.json", '{"name": "app", "start_url": "/"}')
                                             and "--math=fast"], "was not written by ahrsgen"),
    ("generate-foreign-header", lambda t: ["generate", "qcf", "-o", str(t / "src"),
                                           _file(t, "src/qcf.h", "/* my own qcf.h */\n") and "--math=fast"],
     "was not written by ahrsgen"),
    ("tune-o-foreign", lambda t: ["tune", "qcf", *TUNE, "-o", _file(t, "t.toml", "# my notes\n")],
     "was not written by ahrsgen"),
    ("tune-report-foreign", lambda t: ["tune", "qcf", *TUNE, "-o", str(t / "t.toml"),
                                       _file(t, "t.toml.json", "{}") and "--seed=0"], "was not written by ahrsgen"),
    ("target-json-foreign", lambda t: ["target", "qcf", "--json", _file(t, "r.json", '{"mine": 1}')],
     "was not written by ahrsgen"),
    ("harden-json-foreign", lambda t: ["harden", "qcf", "--no-cppcheck", "--fuzz-seconds", "0", "--json",
                                       _file(t, "h.json", '{"mine": 1}')], "was not written by ahrsgen"),
    ("bench-md-foreign", lambda t: ["bench", "--quick", "--scenarios-only", "-o", str(t / "b"),
                                    _file(t, "b/bench.md", "# my bench notes\n") and "--seeds=1"],
     "was not written by ahrsgen"),
    ("bench-config-foreign", lambda t: ["bench", "--scenarios", "handheld_rolled_180", "--scenarios-only",
                                        "-o", str(t / "b"),
                                        _file(t, "b/configs/handheld_rolled_180.toml", "# mine\n") and "--seeds=1"],
     "was not written by ahrsgen"),
    ("bench-plot-foreign", lambda t: ["bench", "--quick", "--scenarios-only", "-o", str(t / "b"),
                                      _file(t, "b/img/err_turntable.png", b"\x89PNG mine") and "--seeds=1"],
     "was not written by ahrsgen"),
]





def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.is_symlink(), p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


@pytest.mark.parametrize("case", REFUSED, ids=[c[0] for c in REFUSED])
def test_output_refused_nothing_changed(case, tmp_path, capsys, no_build, monkeypatch):
    _, build, expect = case
    monkeypatch.chdir(tmp_path)
    argv = build(tmp_path)
    before = _snapshot(tmp_path)
    rc, out, err = _run(argv, capsys)
    assert rc == 2, (rc, out, err)
    assert err.count("\n") == 1 and err.startswith("ahrsgen: error:"), err
    assert expect in err, err
    assert _snapshot(tmp_path) == before


@pytest.mark.slow
def test_outputs_carry_the_marker_and_are_replaced_by_a_later_run(tmp_path, capsys):
    """What run writes (CSV, plots in the three formats, the harness log) is recognised as
    ahrsgen's, so the same command twice works; a foreign file goes only with --force."""
    outs = {"--csv": tmp_path / "o.csv", "--export-log": tmp_path / "h.csv"}
    for fmt in ("png", "svg", "pdf"):
        argv = ["run", "qcf", "--log", str(BROAD), "--plot", str(tmp_path / f"o.{fmt}")]
        if fmt == "png":
            argv += [x for k, v in outs.items() for x in (k, str(v))]
        for _ in range(2):
            rc, out, err = _run(argv, capsys)
            assert rc == 0, err
        assert written_by_ahrsgen(tmp_path / f"o.{fmt}")
    assert all(written_by_ahrsgen(p) for p in outs.values())
    foreign = tmp_path / "mine.csv"
    foreign.write_text("a,b\n")
    assert not written_by_ahrsgen(foreign)
    rc, out, err = _run(["run", "qcf", "--log", str(BROAD), "--csv", str(foreign), "--force"], capsys)
    assert rc == 0 and written_by_ahrsgen(foreign), err


def test_generate_replaces_its_own_files_only(tmp_path, capsys):
    d = tmp_path / "g"
    assert _run(["generate", "qcf", "-o", str(d)], capsys)[0] == 0
    assert all(written_by_ahrsgen(p) for p in d.iterdir())
    assert _run(["generate", "qcf", "--set", "kp=0.5", "-o", str(d)], capsys)[0] == 0
    assert "0.5f" in (d / "qcf.c").read_text()
    (d / "manifest.json").write_text("{}")
    rc, _, err = _run(["generate", "qcf", "-o", str(d)], capsys)
    assert rc == 2 and "manifest.json exists and was not written by ahrsgen" in err
    assert (d / "manifest.json").read_text() == "{}"
    assert _run(["generate", "qcf", "-o", str(d), "--force"], capsys)[0] == 0
    assert written_by_ahrsgen(d / "manifest.json")


def test_every_writing_command_has_force():
    """The rule is the same for every command that writes a file: each has --force."""
    cli._load_extra_commands()
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name in ("generate", "run", "bench", "tune", "target", "harden"):
        assert "--force" in sub.choices[name].format_help(), name
