"""Hardening of the generated C (src/ahrsgen/check/harden.py): cppcheck, libFuzzer under ASan/UBSan,
soak over varied motion with glitches. Every generated/*/ directory is checked.

The invariants are physical (finite state, |q| = 1, covariance symmetric positive definite,
weights summing to 1) and checked in double by src/ahrsgen/sim/fuzz/ahrs_invariants.h; the
harness itself is checked below on states that must fail it.
"""
from __future__ import annotations

import json
import shutil

import pytest

from conftest import needs
from ahrsgen.check import harden, static, tools

pytestmark = pytest.mark.slow       # tests/README.md: left out of the quick run

GEN_DIRS = harden.generated_dirs()
IDS = [d.name for d in GEN_DIRS]

needs_cppcheck = needs("cppcheck")
needs_fuzzer = needs("clang-fuzzer")
needs_cc = needs("cc")


def test_every_generated_filter_is_covered():
    assert {"qcf"} <= set(IDS), IDS


# cppcheck's value flow takes minutes on the longest emitted kernels (adukf's 3268-line update);
# in CI those are checked structurally (harden.kernel_structure_issues: bounds, definitions,
# outputs, exact for straight-line code) and everything else by cppcheck. The whole-file run is
# `ahrsgen harden` (figures in docs/hardening.md).
CI_MAX_KERNEL_LINES = 400


@needs_cppcheck
@pytest.mark.parametrize("gen_dir", GEN_DIRS, ids=IDS)
def test_cppcheck_clean(gen_dir):
    r = harden.run_cppcheck(gen_dir, max_kernel_lines=CI_MAX_KERNEL_LINES, timeout=120)
    assert not r["timed_out"]
    assert r["ok"], f"cppcheck findings in {gen_dir}:\n" + "\n".join(r["issues"] + r["structural_issues"])


def test_kernel_structure_check_catches_planted_defects():
    from ahrsgen.codegen.emit.ir import (Elem, Function, If, Let, Local, Op, Param, PartCall, Set, Slot, Store,
                                         Temp)
    params = [Param("a", "float", 3, const=True), Param("dt", "float"), Param("out", "float", 2),
              Param("piv", "float", pointer=True)]
    t = [Temp("float", f"tmp{i}") for i in range(4)]

    def fn(body, ps=params, name="x_k_demo"):
        return Function(name, ps, body)

    def issues(body, **kw):
        return harden.kernel_structure_issues(fn(body, **kw))
    mul = lambda x, y: Op("*", (x, y))     # noqa: E731
    good = [Let(t[0], mul(Elem("a", 0), Elem("dt")), "mul"), Let(t[1], Op("+", (t[0], Elem("a", 2))), "add"),
            Store(Elem("out", 0), t[1]), Store(Elem("out", 1), t[0]), Store(Elem("piv"), t[1])]
    assert issues(good) == []
    bad = [Let(t[0], mul(Elem("a", 3), Elem("dt")), "mul"), Let(t[1], Op("+", (t[2], Elem("a", 2))), "add"),
           Store(Elem("out", 0), t[1]), Store(Elem("out", 0), t[0]), Store(Elem("a", 1), t[0])]
    text = "\n".join(issues(bad))
    for what in ("a[3] out of bounds", "tmp2 used before it is defined", "output out[1] written 0 times",
                 "output out[0] written 2 times", "writes a, which is not an output", "output piv[0] written 0 times"):
        assert what in text, text
    # branches: a select declared by the If, set once on each side, defined after it; a
    # temporary of one side is not visible after the block
    branch = [Let(t[0], mul(Elem("a", 0), Elem("dt")), "mul"),
              If(Op("<", (t[0], Elem("a", 1))), [Let(t[2], mul(t[0], t[0]), "mul"), Set(t[1], t[2])],
                 [Set(t[1], Elem("a", 2))], [t[1]]),
              Store(Elem("out", 0), t[1]), Store(Elem("out", 1), t[0]), Store(Elem("piv"), t[1])]
    assert issues(branch) == []
    bad = [Let(t[0], mul(Elem("a", 0), Elem("dt")), "mul"),
           If(Op("<", (t[0], Elem("a", 1))), [Let(t[2], mul(t[0], t[0]), "mul"), Set(t[1], t[2]), Set(t[1], t[0])],
              [Set(t[1], t[2]), Set(t[3], Elem("a", 0))], [t[1], t[3]]),
           Store(Elem("out", 0), t[2]), Store(Elem("out", 1), t[1]), Store(Elem("piv"), t[1])]
    text = "\n".join(issues(bad))
    for what in ("tmp1 set twice on one side", "statement 2.else.1: tmp2 used before it is defined",
                 "the sides set different selects: ['tmp3']", "statement 3: tmp2 used before it is defined",
                 "tmp3 declared but not set on both sides"):
        assert what in text, text
    # a split kernel: its local carry array bounded by its declaration
    split = [Local("float", "carry", 2), PartCall("x_k_demo_part0", ["a", "dt", "carry"]),
             Store(Elem("out", 0), Slot("carry", 1)), Store(Elem("out", 1), Slot("carry", 2)),
             Store(Elem("piv"), Slot("carry", 0))]
    assert issues(split) == ["x_k_demo statement 4: carry[2] out of bounds (size 2)"]
    # a part writes only its own carry slots (others hold live values), but none twice
    part_params = [Param("a", "float", 3, const=True), Param("carry", "float", 4)]
    part = [Let(t[0], mul(Slot("carry", 0), Elem("a", 0)), "mul"), Store(Slot("carry", 2), t[0])]
    assert issues(part, ps=part_params, name="x_k_demo_part1") == []
    twice = part + [Store(Slot("carry", 2), Elem("a", 1))]
    assert issues(twice, ps=part_params, name="x_k_demo_part1") == ["x_k_demo_part1: output carry[2] written 2 times"]
    # a part of a kernel that stores its outputs where computed writes some of them
    early = [Param("a", "float", 3, const=True), Param("out", "float", 2)]
    one = [Let(t[0], mul(Elem("a", 0), Elem("a", 1)), "mul"), Store(Elem("out", 1), t[0])]
    assert harden.kernel_structure_issues(Function("x_k_demo_part0", early, one), partial=True) == []
    assert issues(one, ps=early) == ["x_k_demo: output out[0] written 0 times"]


def test_every_generated_kernel_is_found_and_structurally_sound():
    """Each function of each kernel lies in the committed source as the kernel objects print it
    (so harden's structure check and stubs are about that text), and passes the check."""
    for gen_dir in GEN_DIRS:
        man = harden.load_manifest(gen_dir)
        text = (gen_dir / man["files"]["source"]).read_text()
        kernels = harden.build_kernels(man)
        found, missing = harden.emitted_functions(text, kernels)
        assert missing == [] and len(found) == sum(len(k.functions()) for k in kernels)
        for k in kernels:
            assert harden.kernel_issues(k) == [], k.name


def _copy_build(name: str, tmp_path):
    """The committed generated/<name> build copied into tmp_path (to plant a defect in); its manifest."""
    src = harden.GENERATED / name
    man = harden.load_manifest(src)
    for f in [*man["files"].values(), "manifest.json"]:
        shutil.copy(src / f, tmp_path / f)
    return man


@needs_cppcheck
def test_kernel_stub_keeps_the_rest_checked(tmp_path):
    """With every kernel stubbed, cppcheck still sees (and flags) a defect in the step code."""
    man = _copy_build("qcf", tmp_path)
    c = tmp_path / man["files"]["source"]
    c.write_text(c.read_text().replace("\n    return status;\n}", "\n    float z[2] = { 0.0f, 0.0f };\n"
                                       "    status |= (qcf_status)z[2];\n    return status;\n}", 1))
    r = harden.run_cppcheck(tmp_path, max_kernel_lines=0, timeout=120)
    kernels = harden.build_kernels(man)
    assert len(r["structurally_checked"]) == sum(len(k.functions()) for k in kernels)
    assert not r["ok"] and any("arrayIndexOutOfBounds" in i for i in r["issues"]), r["issues"]


@needs_cppcheck
def test_cppcheck_catches_a_planted_defect(tmp_path):
    """The cppcheck invocation does report problems (so 'clean' means something)."""
    man = _copy_build("qcf", tmp_path)
    c = tmp_path / man["files"]["source"]
    c.write_text(c.read_text() + "\nint harden_planted(void)\n{\n    int a[3] = { 0, 1, 2 };\n    return a[3];\n}\n")
    r = harden.run_cppcheck(tmp_path, max_kernel_lines=CI_MAX_KERNEL_LINES, timeout=120)
    assert not r["ok"] and any("arrayIndexOutOfBounds" in i for i in r["issues"]), r["issues"]


@pytest.mark.parametrize("gen_dir", GEN_DIRS, ids=IDS)
def test_layout_follows_manifest(gen_dir):
    man = harden.load_manifest(gen_dir)
    plan = harden.invariant_plan(man)
    assert ("q", 1) in plan["quaternions"]
    reals = [f["name"] for f in man["structs"]["state"]["fields"] if f["type"] == "real"]
    assert plan["finite"] == reals
    if any(f["name"] == "P" for f in man["structs"]["state"]["fields"]):
        assert plan["covariances"] and plan["covariances"][0][0] == "P"
    text = harden.layout_header(man)
    assert f"#define AHRS_REFUSED_MASK {man['refused_mask']}u" in text
    names = {f["name"] for f in man["structs"]["state"]["fields"]}
    assert ("#define AHRS_WEIGHT_SUM_FIELD weight_sum" in text) == ("weight_sum" in names and "weights" in names)


# ------------------------------------------------------------------ fuzz

def _fuzzed(gen_dir, tmp_path, runs):
    return harden.run_fuzz(gen_dir, runs=runs, seed=1234, workdir=tmp_path / "fuzz")


# Inputs per filter in CI: a few seconds each (cpf steps 100 particles, so fewer inputs).
CI_RUNS = {"cpf": 60, "adukf": 400, "mekf": 600}


@needs_fuzzer
@pytest.mark.parametrize("gen_dir", GEN_DIRS, ids=IDS)
def test_fuzz_finds_no_crash(gen_dir, tmp_path):
    """Short deterministic libFuzzer run (fixed seed, bounded runs) under ASan+UBSan: no sanitizer
    report, no invariant violation. Known issues are excluded (and replayed by the next test)."""
    r = _fuzzed(gen_dir, tmp_path, CI_RUNS.get(gen_dir.name, 1500))
    assert r["executions"] and r["executions"] > 0, r
    assert not r["crashes"], "\n".join(c["message"] + "\n" + "\n".join(c.get("input", [])) for c in r["crashes"])
    assert r["returncode"] == 0


KNOWN = [(d, i) for d in GEN_DIRS for i in harden.known_issues(d)]

if KNOWN:   # defined only while harden.KNOWN_ISSUES lists something (empty now: all fixed)
    @needs_fuzzer
    @pytest.mark.parametrize("gen_dir,issue", KNOWN, ids=[i["id"] for _, i in KNOWN])
    def test_known_issue_reproducer(gen_dir, issue):
        """A bug the fuzzer found that is not fixed yet: xfail while it reproduces; the day it is
        fixed this test fails and says to move it to harden.REGRESSIONS."""
        rc, err = harden.replay(gen_dir, bytes.fromhex(issue["reproducer"]))
        if rc != 0:
            assert "ahrs invariant violated" in err or "runtime error" in err, err[-2000:]
            pytest.xfail(f"{issue['id']}: {issue['what']}")
        pytest.fail(f"{issue['id']} no longer reproduces: move it to harden.REGRESSIONS")


@needs_fuzzer
@pytest.mark.parametrize("gen_dir", GEN_DIRS, ids=IDS)
def test_fixed_fuzz_findings_stay_fixed(gen_dir):
    """Every crash the fuzzer found (harden.REGRESSIONS) replays clean on every filter."""
    man = harden.load_manifest(gen_dir)
    for reg in harden.regressions_for(man):
        rc, err = harden.replay(gen_dir, bytes.fromhex(reg["reproducer"]))
        assert rc == 0, f"{reg['id']} ({reg['what']}) is back in {gen_dir.name}:\n{err[-1500:]}"


def _plant_at_step_end(text: str, code: str, prefix: str = "qcf") -> str:
    """Insert code before the final `return status;` of <prefix>_step itself (other functions of
    the file, such as qcf_check_inputs, end the same way)."""
    step = text.index(f"{prefix}_status {prefix}_step(")
    end = text.index("\n}\n", step)
    marker = "\n    return status;"
    at = text.rindex(marker, step, end)
    return text[:at] + "\n" + code + text[at:]


@needs_fuzzer
def test_fuzz_harness_detects_a_broken_state(tmp_path):
    """Plant a bug in a copy of a generated filter (the step scales q by 1.001 on a GPS sample) and
    check the harness aborts with the quaternion-norm message: the invariant checks are live."""
    man = _copy_build("qcf", tmp_path)
    c = tmp_path / man["files"]["source"]
    text = c.read_text()
    c.write_text(_plant_at_step_end(text, "    if ((in->valid & 8u) != 0u) {\n        s->q[0] *= 1.001f;\n    }"))
    data = harden.seed_inputs(man)["nominal"]
    rc, err = harden.replay(tmp_path, data)
    assert rc != 0 and "quaternion 0: | |q| - 1 |" in err, err[-2000:]


@needs_fuzzer
def test_fuzz_harness_checks_weights_against_their_stored_sum(tmp_path):
    """cpf keeps its weights unnormalised with their sum: a planted step end that doubles the
    stored sum breaks the weights' invariant and the harness reports it."""
    man = _copy_build("cpf", tmp_path)
    c = tmp_path / man["files"]["source"]
    c.write_text(_plant_at_step_end(c.read_text(), "    s->weight_sum *= 2.0f;", "cpf"))
    data = harden.seed_inputs(man)["nominal"]
    rc, err = harden.replay(tmp_path, data)
    assert rc != 0 and "state.weights sum to" in err, err[-2000:]


@needs_fuzzer
def test_fuzz_harness_detects_state_change_on_refusal(tmp_path):
    man = _copy_build("qcf", tmp_path)
    c = tmp_path / man["files"]["source"]
    text = c.read_text()
    old = "    if (!(qcf_bits(dt) - 1u < qcf_bits(QCF_DT_MAX))) {\n"   # the step's refusal of a bad dt
    step = text.index("qcf_status qcf_step(")
    assert text.find(old, step) > step
    c.write_text(text[:step] + text[step:].replace(old, old + "        s->gps_age = 0.0f;\n", 1))
    data = b"\x00" + harden.make_record(man, dt=1.0)
    rc, err = harden.replay(tmp_path, data)
    assert rc != 0 and "refused step changed the state" in err, err[-2000:]


def test_describe_input_roundtrip():
    man = harden.load_manifest(harden.GENERATED / "qcf")
    data = b"\x01" + harden.make_record(man, gyro=(1.5, float("nan"), 0), dt=0.02, valid=0x5)
    lines = harden.describe_input(data, man)
    assert lines[0].startswith("flags 0x01")
    assert "valid 0x05" in lines[1] and "gyro [1.5, nan, 0]" in lines[1] and "dt 0.0199999996" in lines[1]


# ------------------------------------------------------------------ soak

CI_SOAK = {"cpf": 60_000, "adukf": 300_000}


@needs_cc
@pytest.mark.parametrize("gen_dir", GEN_DIRS, ids=IDS)
def test_soak_invariants(gen_dir):
    """Float soak in CI (the full 1e7 steps is `ahrsgen harden`): no invariant violation at any
    step, no drift of |q| - 1 between the first and last tenth of the run, covariance PD."""
    n = CI_SOAK.get(gen_dir.name, 1_000_000)
    r = harden.run_soak(gen_dir, steps=n, seed=7, glitch_rate=1e-3)
    assert r["steps"] == n
    assert r["violations"] == 0, f"step {r['first_violation_step']}: {r['first_violation']}"
    assert r["glitches"] > 0 and r["refused"] > 0          # the glitches really were injected
    tol = 1e-5 if r["precision"] == "float" else 1e-12
    assert r["max_qnorm_err"] <= tol
    dec = r["deciles"]["max_qnorm_err"]
    assert dec[-1] <= 4 * max(dec[0], 1.2e-7 if r["precision"] == "float" else 1e-15), dec   # no drift
    if r["has_covariance"]:
        assert r["min_pivot"] > 0 and r["max_asym_rel"] <= 1e-5
        # the smallest pivot in the last tenth has not collapsed relative to the first
        piv = r["deciles"]["min_pivot_rel"]
        assert piv[-1] > 1e-3 * piv[0], piv


@needs_cc
def test_soak_flags_a_broken_filter(tmp_path):
    """The soak's checks are live: a copy of qcf whose step leaves |q| 1e-4 off fails."""
    man = _copy_build("qcf", tmp_path)
    c = tmp_path / man["files"]["source"]
    text = c.read_text()
    c.write_text(_plant_at_step_end(text, "    s->q[0] *= 1.0001f;"))
    r = harden.run_soak(tmp_path, steps=200_000, seed=7, glitch_rate=0.0)
    assert r["violations"] > 0 and "| |q| - 1 |" in r["first_violation"]


@needs_cc
def test_soak_motion_is_consistent():
    """The soak's synthetic sensors agree with its truth: the MEKF, which tracks gentle motion well
    (see tests/filters/mekf/test_mekf_c.py), stays within a degree on the gentle profile."""
    r = harden.run_soak(harden.GENERATED / "mekf", steps=30_000, seed=3, glitch_rate=0.0, varied=False) \
        if (harden.GENERATED / "mekf" / "manifest.json").exists() else None
    if r is None:
        pytest.skip("generated/mekf not present")
    assert r["att_err_rms_deg"] < 1.0, r["att_err_rms_deg"]


# ------------------------------------------------------------------ CLI

@needs_cc
def test_cli_harden_soak_only(tmp_path, capsys):
    from ahrsgen import cli
    out = tmp_path / "h.json"
    rc = cli.main(["harden", "qcf", "--fuzz-seconds", "0", "--soak-steps", "20000", "--no-cppcheck",
                   "--json", str(out)])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "max||q|-1|" in text and "qcf" in text
    res = json.loads(out.read_text())["results"][0]
    assert res["soak"]["steps"] == 20000 and res["ok"]


def test_cli_unknown_filter(capsys):
    from ahrsgen import cli
    assert cli.main(["harden", "no_such_filter", "--soak-steps", "0", "--fuzz-seconds", "0"]) == 2
    assert "unknown filter 'no_such_filter'" in capsys.readouterr().err


def test_cli_refuses_a_check_it_cannot_run(monkeypatch, capsys):
    """Fuzzing asked for but the fuzzer cannot link: one line, exit 2, not a table of '-'."""
    from ahrsgen import cli
    monkeypatch.setattr(tools, "CLANG", "no-such-clang-ahrsgen")
    rc = cli.main(["harden", "qcf", "--fuzz-seconds", "20", "--soak-steps", "1e5", "--no-cppcheck"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "fuzzing" in err and "libclang-rt" in err, err
    monkeypatch.setattr(static, "CPPCHECK", "no-such-cppcheck-ahrsgen")
    assert cli.main(["harden", "qcf", "--fuzz-seconds", "0", "--soak-steps", "0"]) == 2
    assert "cppcheck" in capsys.readouterr().err


@pytest.mark.parametrize("text,value", [("1e5", 100000), ("1e7", 10_000_000), ("0", 0), ("250", 250),
                                        ("-5", None), ("1.5", None), ("abc", None), ("1e30", None)])
def test_cli_soak_steps_parsing(text, value, capsys):
    """--soak-steps takes what its help writes (1e7); a negative count is refused (it used to wrap in
    strtoull and run for ever)."""
    from ahrsgen import cli
    cli._load_extra_commands()
    parser = cli.build_parser()
    if value is None:
        with pytest.raises(SystemExit) as e:
            parser.parse_args(["harden", "qcf", "--soak-steps", text])
        assert e.value.code == 2 and capsys.readouterr().err.count("\n") == 1
    else:
        assert parser.parse_args(["harden", "qcf", "--soak-steps", text]).soak_steps == value
