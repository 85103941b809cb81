"""Configuration: presets, files and --set, and the one-line errors users get."""
from __future__ import annotations

import subprocess
import sys

import pytest

from ahrsgen.generate import config
from ahrsgen import filters
from ahrsgen.codegen.model import ConfigError


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "ahrsgen.cli", *args], capture_output=True, text=True)


def test_every_filter_has_a_faithful_preset_that_applies():
    for name in filters.names():
        spec = filters.load(name)
        assert "faithful" in spec.presets(), name
        cfg = config.resolve(name, preset="faithful")
        assert cfg.overrides, name          # it changes something
    q = config.resolve("qcf", preset="faithful")
    assert q.params["faithful"] is True and q.params["motion_accel_model"] == "differentiator"


def test_set_wins_over_file_wins_over_preset(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('preset = "faithful"\nprefix = "att"\nprecision = "double"\n[params]\nkp = 0.7\nmotion_accel_model = "centripetal"\n')
    cfg = config.resolve("qcf", f, ["kp=0.9"])
    assert cfg.params["faithful"] is True                       # from the preset
    assert cfg.params["motion_accel_model"] == "centripetal"   # file over preset
    assert cfg.params["kp"] == 0.9                              # --set over file
    assert cfg.prefix == "att" and cfg.precision == "double"


@pytest.mark.parametrize("content, words", [
    ("[params]\nkpp = 1\n", ["unknown parameter 'kpp'", "known:"]),
    ("[params]\nkp = -1\n", ["'kp'", "out of range", "(0.0, 100.0]"]),
    ("[params]\nkp = \"fast\"\n", ["'kp'", "must be a number"]),
    ("[params]\nfaithful = 3\n", ["'faithful'", "true or false"]),
    ("[params]\nmotion_accel_model = \"magic\"\n", ["'motion_accel_model'", "one of"]),
    ("[params\nkp = 1\n", ["malformed TOML"]),
    ("colour = \"red\"\n", ["unknown key", "colour"]),
    ("filter = \"mekf\"\n", ["written for filter 'mekf'"]),
    ("preset = \"nope\"\n", ["unknown preset 'nope'"]),
    ("prefix = \"My-Att\"\n", ["prefix", "C identifier"]),
])
def test_bad_config_file_is_one_clear_line_and_exit_2(tmp_path, content, words):
    f = tmp_path / "bad.toml"
    f.write_text(content)
    with pytest.raises(ConfigError):
        config.resolve("qcf", f)
    r = run_cli("generate", "qcf", "--config", str(f), "-o", str(tmp_path / "out"))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ahrsgen: error:"), r.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert not (tmp_path / "out").exists()                      # nothing half-written


@pytest.mark.parametrize("args, word", [
    (["--set", "kp"], "expected name=value"),
    (["--set", "dt_max=0"], "out of range"),
    (["--set", "gyro_max=nan"], "finite"),
    (["--config", "/does/not/exist.toml"], "does not exist"),
])
def test_bad_cli_values(tmp_path, args, word):
    r = run_cli("generate", "qcf", *args, "-o", str(tmp_path / "o"))
    assert r.returncode == 2 and word in r.stderr, r.stderr


def test_unknown_filter_and_scenario():
    r = run_cli("generate", "ekf9", "-o", "/tmp/x")
    assert r.returncode == 2 and "unknown filter 'ekf9'" in r.stderr and "qcf" in r.stderr
    r = run_cli("validate", "qcf", "--scenario", "moon_landing")
    assert r.returncode == 2 and "unknown scenario" in r.stderr


def test_list_shows_ranges_units_and_presets():
    r = run_cli("list", "qcf")
    assert r.returncode == 0
    assert "kp" in r.stdout and "allowed (0.0, 100.0]" in r.stdout and "[rad/s]" in r.stdout
    assert "preset 'faithful'" in r.stdout


def test_math_and_fma_build_options(tmp_path):
    assert config.resolve("qcf").math == "fast" and config.resolve("qcf").fma is False
    f = tmp_path / "c.toml"
    f.write_text('math = "libm"\nfma = true\n')
    cfg = config.resolve("qcf", f)
    assert (cfg.math, cfg.fma) == ("libm", True)
    assert config.resolve("qcf", f, math="fast").math == "fast"          # the command line wins
    f.write_text('math = "approx"\n')
    with pytest.raises(ConfigError, match="math"):
        config.resolve("qcf", f)
    f.write_text('fma = "yes"\n')
    with pytest.raises(ConfigError, match="fma"):
        config.resolve("qcf", f)


@pytest.mark.parametrize("decl_deg", [-0.001, -1e-7, 3.0])
def test_site_parameters_pass_as_numbers(decl_deg):
    """A log's site (declination, inclination) reaches the build as numbers, never through
    "k=v" text: a declination of -0.001 deg is -1.745e-05 rad, which the former text round
    trip returned as a string that resolve refused (issue 27)."""
    import math
    from ahrsgen.bench import site_values
    values, applied = site_values("adukf", {"declination_deg": decl_deg, "inclination_deg": 64.5})
    assert applied and values == {"declination": math.radians(decl_deg), "inclination_deg": 64.5,
                                  "mag_ref": "inclination"}
    cfg = config.resolve("adukf", values=values)
    assert cfg.params["declination"] == math.radians(decl_deg) and cfg.params["inclination_deg"] == 64.5
    assert config.resolve("adukf", values=values, sets=["declination=0.5"]).params["declination"] == 0.5


def test_validate_runs_the_filters_own_scenario(capsys):
    """validate without --scenario uses the filter's source experiment (as target does): adukf's
    is the static magnetic disturbance, not the fixed-wing flight it was never made for."""
    from ahrsgen import cli
    assert cli.main(["validate", "adukf", "--scenario-opt", "duration=20"]) == 0
    assert "validate adukf (float) on static_mag_disturbance seed 0" in capsys.readouterr().out
