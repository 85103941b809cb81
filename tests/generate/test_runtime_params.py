"""Runtime parameters (--runtime): kept out of the folding, set in C with <prefix>_set_params.

Checked against the baked builds (the folded code): a runtime build with the default values
equals the baked build, one with values set at run time equals the baked build of those
values; set_params refuses out-of-range values as a whole with the state untouched (a C
program, tests/c/runtime_params_test.c); structural parameters are refused with one line.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from ahrsgen.sim import host
from ahrsgen.sim.metrics import max_angle_diff_rad
from ahrsgen import cli
from ahrsgen.generate import config, render

from conftest import scenario, TESTS
from ahrsgen.sim.readers import EXCERPTS

# float: constants folded at generation time (in double) vs products computed in float at run
# time round differently; measured 4.1e-7 rad (MEKF) and 1e-17 (QCF) over 120 s
FLOAT_BOUND_RAD = 1e-5
CASES = [("qcf", "kp,ki", {"kp": 1.3, "ki": 0.05}),
         ("mekf", "gyro_noise,accel_angle_noise,gps_min_speed", {"gyro_noise": 0.01, "gps_min_speed": 3.0})]


@pytest.mark.parametrize("precision", ["double", "float"])
@pytest.mark.parametrize("name,runtime,values", CASES)
def test_runtime_build_equals_baked(name, runtime, values, precision):
    log = scenario("fixedwing_gps", 0, duration=120.0)
    bound = 1e-12 if precision == "double" else FLOAT_BOUND_RAD
    rt = host.build(config.resolve(name, precision=precision, runtime=runtime))
    baked = host.build(config.resolve(name, precision=precision))
    assert max_angle_diff_rad(rt.run(log).q, baked.run(log).q) <= bound
    sets = [f"{k}={v!r}" for k, v in values.items()]
    baked_new = host.build(config.resolve(name, precision=precision, sets=sets))
    res = rt.run(log, params=values)
    assert max_angle_diff_rad(res.q, baked_new.run(log).q) <= bound
    # and the new values do change the estimate (the set reached the kernels)
    assert max_angle_diff_rad(res.q, baked.run(log).q) > 1e-4


def test_header_and_manifest(tmp_path, capsys):
    assert cli.main(["generate", "qcf", "--runtime", "kp,ki", "-o", str(tmp_path)]) == 0
    h = (tmp_path / "qcf.h").read_text()
    for text in ("} qcf_params;", "void qcf_params_default(qcf_params *p);",
                 "uint32_t qcf_set_params(qcf_state *s, const qcf_params *p);", "qcf_params params;",
                 "#define QCF_PARAM_KP 1u", "#define QCF_PARAM_KI 2u"):
        assert text in h
    assert "#define QCF_KP " not in h and "#define QCF_DECLINATION 0.0f" in h   # everything else folded
    import json
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert [r["name"] for r in man["runtime_params"]] == ["kp", "ki"]
    assert man["runtime_params"][0]["allowed"] == "(0.0, 100.0]"
    assert man["structs"]["params"]["size"] == 8
    assert man["structs"]["state"]["fields"][-1]["name"] == "params"
    # the TOML key does the same as the option
    cfg_file = tmp_path / "rt.toml"
    cfg_file.write_text('runtime = ["kp", "ki"]\n')
    assert render.render(config.resolve("qcf", cfg_file)).files["qcf.h"] == h


def test_set_params_refusals_in_c(tmp_path):
    gen = render.render(config.resolve("qcf", prefix="att", runtime="kp,ki"))
    render.write(gen, tmp_path)
    exe = tmp_path / "rt_test"
    cmd = [host.cc(), *host.STRICT, "-O1", f"-I{tmp_path}", str(tmp_path / "att.c"),
           str(TESTS / "c" / "runtime_params_test.c"), "-o", str(exe), "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([str(exe)], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stdout


@pytest.mark.parametrize("name,runtime,words", [
    ("qcf", "motion_accel_model", "is a choice"),
    ("qcf", "faithful", "is a boolean"),
    ("cpf", "n_particles", "is an integer"),
    ("mekf", "p0_att", "state field 'P' starts from a runtime parameter"),
    ("qcf", "kp,kp", "listed twice"),
    ("qcf", "nope", "not a parameter"),
])
def test_structural_refused(name, runtime, words, tmp_path, capsys):
    assert cli.main(["generate", name, "--runtime", runtime, "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]
    assert not (tmp_path / "o").exists()


def test_run_and_validate_take_runtime(capsys):
    from ahrsgen.bench import run_on_log
    log = str(EXCERPTS / "broad_01_excerpt.csv.gz")
    baked = run_on_log("qcf", log, sets=["kp=0.5"], out=open("/dev/null", "w"))
    rt = run_on_log("qcf", log, sets=["kp=0.5"], runtime="kp,ki", out=open("/dev/null", "w"))
    assert rt["score"]["total_rms"] == pytest.approx(baked["score"]["total_rms"], abs=1e-9)
    assert cli.main(["validate", "qcf", "--runtime", "kp,ki", "--precision", "double",
                     "--scenario-opt", "duration=30"]) == 0
    assert "PASS" in capsys.readouterr().out


@pytest.mark.parametrize("name,runtime", [("qcf", "dt_max"), ("qcf", ""), ("mekf", "dt_max,gyro_max")])
def test_header_names_only_what_it_defines(name, runtime, tmp_path):
    """Every PREFIX_NAME the header's prose mentions is defined in the header: a parameter made
    runtime is named as its params field, not as the macro it replaced (issue 27)."""
    import re
    args = ["generate", name, "-o", str(tmp_path)] + (["--runtime", runtime] if runtime else [])
    assert cli.main(args) == 0
    h = (tmp_path / f"{name}.h").read_text()
    P = name.upper()
    defined = set(re.findall(rf"#define ({P}_\w+)", h)) | set(re.findall(rf"\b({P}_\w+)\s*=", h))
    mentioned = {m for m in re.findall(rf"\b{P}_[A-Z0-9_]+\b", h) if not m.endswith("_")} - {f"{P}_H"}
    assert mentioned <= defined, sorted(mentioned - defined)
    for n in filter(None, runtime.split(",")):
        assert f"{name}_params.{n}" in h
