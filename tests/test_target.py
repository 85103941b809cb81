"""Cortex-M4F target checks: the cross-built image in QEMU gives the host's answers, and the
footprint figures come from instruments that are checked against each other.

Needs arm-none-eabi-gcc + newlib, qemu-system-arm, and the Python packages unicorn and
pyelftools (CI installs them); skipped with the list of what is missing otherwise.
"""
from __future__ import annotations

import ctypes
import subprocess

import numpy as np
import pytest

from firmware_sim import target as T

_MISSING = T.missing_tools()
pytestmark = [
    pytest.mark.target,
    pytest.mark.skipif(bool(_MISSING), reason="target toolchain missing: " + ", ".join(_MISSING)),
]


def _toy_records(n=600, seed=0):
    rng = np.random.default_rng(seed)
    rec = np.zeros(n, dtype=T.RECORD_DTYPE)
    rec["gyro"] = rng.normal(0.0, 1.0, (n, 3))
    rec["accel"] = rng.normal(0.0, 1.0, (n, 3)) + [0.0, 0.0, -9.81]
    rec["valid"] = 3
    rec["dt"] = 0.01
    rec["dt"][5] = -1.0          # refused: state must not change
    rec["valid"][7] = 2          # gyro missing: refused
    rec["valid"][9] = 1          # accel missing: no tilt update
    return rec


@pytest.fixture(scope="module")
def toy_o2(tmp_path_factory):
    wd = tmp_path_factory.mktemp("toy")
    return T.check_filter(T.toy_binding(), _toy_records(), wd, opt="-O2", count_steps=150)


def _host_toy(tmp_path, rec):
    """The toy compiled for the host (x86-64 gcc, same math flags), driven through ctypes."""
    so = tmp_path / "toy_host.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O2", *T.MATH_FLAGS, *T.WARN_FLAGS,
                    str(T.TARGET_DIR / "toy.c"), "-lm", "-o", str(so)], check=True)
    lib = ctypes.CDLL(str(so))

    class State(ctypes.Structure):
        _fields_ = [("q", ctypes.c_float * 4), ("tilt", ctypes.c_float * 2)]

    class Input(ctypes.Structure):
        _fields_ = [("gyro", ctypes.c_float * 3), ("accel", ctypes.c_float * 3),
                    ("mag", ctypes.c_float * 3), ("gps_vel_ned", ctypes.c_float * 3),
                    ("valid", ctypes.c_uint32)]

    lib.toy_step.restype = ctypes.c_uint32
    lib.toy_step.argtypes = [ctypes.POINTER(State), ctypes.POINTER(Input), ctypes.c_float]
    s = State()
    lib.toy_init(ctypes.byref(s))
    status = np.zeros(len(rec), np.uint32)
    states = np.zeros((len(rec), 24), np.uint8)
    for k, r in enumerate(rec):
        inp = Input()
        inp.gyro[:] = [float(x) for x in r["gyro"]]
        inp.accel[:] = [float(x) for x in r["accel"]]
        inp.valid = int(r["valid"])
        status[k] = lib.toy_step(ctypes.byref(s), ctypes.byref(inp), ctypes.c_float(r["dt"]))
        states[k] = np.frombuffer(bytes(s), np.uint8)
    return status, states


def _numpy_toy_q(rec):
    """Independent float64 integration of the toy's attitude (exact quaternion exponential)."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    out = np.zeros((len(rec), 4))
    for k, r in enumerate(rec):
        if r["dt"] > 0 and r["valid"] & 1:
            w = r["gyro"].astype(float)
            n = np.linalg.norm(w)
            h = 0.5 * n * float(r["dt"])
            dq = np.r_[np.cos(h), np.sin(h) / n * w]
            a, b = q, dq
            q = np.array([a[0] * b[0] - a[1:] @ b[1:], *(a[0] * b[1:] + b[0] * a[1:] + np.cross(a[1:], b[1:]))])
            q /= np.linalg.norm(q)
        out[k] = q
    return out


def test_target_image_runs_and_matches_host_build(toy_o2, tmp_path):
    rec = _toy_records()
    run = toy_o2.run
    assert run.state_bytes == 24 and len(run.status) == len(rec)
    h_status, h_state = _host_toy(tmp_path, rec)
    np.testing.assert_array_equal(run.status, h_status)
    assert run.status[5] == 1 and run.status[7] == 4
    # refused steps leave the state bit-identical
    np.testing.assert_array_equal(run.state[5], run.state[4])
    np.testing.assert_array_equal(run.state[7], run.state[6])
    b = T.toy_binding()
    q_t = run.field(b, "q").astype(float)
    q_h = h_state[:, :16].copy().view("<f4").astype(float)
    # newlib sinf/cosf/atan2f vs glibc: may differ in the last ulp, so a bound, stated:
    # 600 steps of unit-rate gyro keep |dq| under 1e-5.
    assert np.max(np.abs(q_t - q_h)) < 1e-5
    # and both agree with an independent float64 integration (float round-off only)
    q_ref = _numpy_toy_q(rec)
    assert np.max(np.abs(q_t - q_ref)) < 1e-4


def test_unicorn_reproduces_qemu_bit_for_bit(toy_o2):
    c = toy_o2.counts
    n = len(c.status)
    np.testing.assert_array_equal(c.status, toy_o2.run.status[:n])
    np.testing.assert_array_equal(c.state, toy_o2.run.state[:n])


def test_instruction_count_agrees_with_qemu_icount_and_per_instruction_hook(toy_o2):
    rec = _toy_records()
    emu = T.Emulator(toy_o2.build.elf)
    st, rp = emu.scratch, emu.scratch + 0x1000
    emu.call("glue_init", st)
    for k in range(3):
        emu.uc.mem_write(rp, rec[k:k + 1].tobytes())
        one_by_one = emu.count_call_per_instruction("glue_step", st, rp)
        assert one_by_one == emu._total          # block counting == unicorn's own decoder
    # QEMU -icount + SysTick over the WHOLE run vs unicorn over the first steps: the glue
    # call is the same code; QEMU's window also holds the bl and one load (2 instructions).
    glue_mean = toy_o2.counts.glue_instructions.mean()
    icount = toy_o2.run.instructions_per_step_icount
    n = len(toy_o2.counts.status)
    whole = T.Emulator(toy_o2.build.elf).count_steps("toy_step", rec, 24)
    assert abs(whole.glue_instructions.mean() + 2 - icount) < 0.5, (whole.glue_instructions.mean(), icount)
    assert abs(glue_mean - whole.glue_instructions[:n].mean()) < 1e-9
    # the step itself: a full step of the toy (exp map + 2 atan2f) is a few hundred
    full = toy_o2.counts.instructions[toy_o2.counts.status == 0]
    assert 150 < full.mean() < 1500
    assert toy_o2.counts.instructions[5] < 30     # refused at the dt check


def test_stack_bound_covers_measured_stack(toy_o2):
    fp = toy_o2.footprint
    su = T.parse_stack_usage(toy_o2.build.stack_usage_files)
    assert fp.stack_path[0] == "toy_step"
    assert fp.stack_bytes >= su["toy_step"][0] > 0
    assert 0 < fp.stack_measured_bytes <= fp.stack_bytes


def test_footprint_counts_libm_and_flags_no_double(toy_o2):
    fp = toy_o2.footprint
    assert fp.double_helpers == []
    assert {"sinf", "cosf", "atan2f"} <= set(fp.library_calls)
    assert "sqrtf" not in fp.library_calls      # -fno-math-errno: vsqrt.f32 inline
    # flash includes libm's sinf/cosf/atan2f, so more than the toy's own code
    assert fp.flash_bytes > fp.object_sections["text"] > 0
    assert fp.ram_static_bytes == fp.state_bytes == 24
    assert "-ffp-contract=off" in fp.flags and "-fno-math-errno" in fp.flags


def test_hidden_double_is_detected(tmp_path):
    """A float filter with an unsuffixed sin() and a double literal must be flagged."""
    src = tmp_path / "dbl.c"
    hdr = tmp_path / "dbl.h"
    hdr.write_text((T.TARGET_DIR / "toy.h").read_text().replace("toy_", "dbl_").replace("TOY_H", "DBL_H"))
    src.write_text('#include "dbl.h"\n#include <math.h>\n'
                   "void dbl_init(dbl_state *s) { s->q[0] = 1.0f; }\n"
                   "uint32_t dbl_step(dbl_state *s, const dbl_input *in, float dt) {\n"
                   "  s->q[1] = (float)(sin((double)in->gyro[0]) * (double)dt);\n  return 0u;\n}\n")
    b = T.toy_binding()
    b.name, b.prefix, b.sources, b.include_dirs = "dbl", "dbl", [src], [tmp_path]
    b.header, b.state_type, b.input_type = "dbl.h", "dbl_state", "dbl_input"
    bld = T.build(b, tmp_path / "w", "-O2")
    fp = T.footprint(b, bld)
    assert "sin" in fp.library_calls
    assert any(h.startswith("__aeabi_d") or h.startswith("__aeabi_f2d") for h in fp.double_helpers)


def test_thumb_length_rule():
    # 16-bit: movs r0,#1 (2001); 32-bit: bl (f000 f800), vadd.f32 (ee30 0a00)
    code = bytes.fromhex("0120" "00f000f8" "30ee000a" "7047")
    assert T.thumb_instruction_count(code) == 4
