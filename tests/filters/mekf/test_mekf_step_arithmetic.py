"""mekf's step function holds control flow, copies and kernel calls only: its arithmetic is in
kernels, so the manifest's per-path op counts (the sums of the kernels' counts) cover the step.

This reads the generated C text of `mekf_step` (and of the step's file-scope helper
`mekf_hard_iron`), removes comments and kernel calls, and fails on any floating-point
operation left: + - * / (and their compound forms), ++/--, comparisons, and any call of a
function that is not a kernel. Allowed (the list is short on purpose):

- integer work: operands that are integer literals (`3u`), loop counters and other names declared
  `uint32_t`/`int` in the function, and the state's uint32 fields (manifest struct layout);
- the input checks that codegen writes before every filter's own step (codegen/input_checks.py,
  the same for all filters): the text before mekf's own step comment "MEKF step" is not read;
- PIVOT_TESTS: a kernel's innovation variance (pivot) compared with S_PIVOT_MIN to decide
  whether its correction is applied (one comparison per correction, not in the op counts);
- GATE: the gyro over-range kernel's skip test (codegen/templates/gyro_recovery.c.j2), once:
  |gyro|^2 (gyro_n2, from the input checks) against parameter bounds and the bit patterns of the
  kernel's state decide whether the kernel runs. Its comparisons are fewer than the 36
  operations of the kernel it skips, which the path op counts count: they still cover the step.

It also checks that every kernel the step calls is on one of the manifest's step paths, except
the first-step initialisation and the hard-iron fit (a step while turning), which no path names.
"""
from __future__ import annotations

import re

import pytest

from ahrsgen.filters.mekf import model as M
from ahrsgen.generate import config, render

CONFIGS = [
    ("float", ()), ("double", ()),
    ("float", ("heading_source=mag",)), ("float", ("heading_source=gps_course",)),
    ("float", ("motion_comp=gps_accel",)), ("float", ("motion_comp=centripetal", "accel_gate=2")),
    ("float", ("motion_comp=none", "heading_source=mag")), ("float", ("mag_bias=false",)),
    ("float", ("measurement=euler_angles",)),
    ("float", ("measurement=euler_angles", "heading_source=mag", "motion_comp=centripetal", "accel_gate=1")),
    ("float", ("measurement=euler_angles", "motion_comp=gps_accel")),
]
RUNTIME = "gps_min_speed,mag_norm_th,accel_gate,rest_tau,rest_gyro_th,mag_bias_min_rate,gps_vel_timeout"
PIVOT_TESTS = {"min_pivot", "s_head"}      # kernel outputs compared with S_PIVOT_MIN
START = "MEKF step"                        # mekf's own step begins at this comment
GATE = re.compile(r"if \(!\((?:gyro_n2 < (\w+) \* \1\s*&&\s*)+"
                  r"\((\w+)_bits\(s->recover_time\)(?:\s*\|\s*\2_bits\(s->gyro_repeats\[[012]\]\)){3}\)"
                  r" == 0u\)\) \{")

_TOKEN = re.compile(r"->|\+\+|--|\+=|-=|\*=|/=|<=|>=|==|!=|&&|\|\||\|=|<<|>>|[A-Za-z_]\w*"
                    r"|(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?[fFuU]?|\S")
_INT_LIT = re.compile(r"^\d+[uU]?$")
_TYPES = {"float", "double", "bool", "const", "void", "int", "uint32_t", "restrict"}
_ARITH = {"+", "-", "*", "/", "+=", "-=", "*=", "/=", "++", "--", "<", ">", "<=", ">=", "==", "!="}
_KEYWORDS = {"if", "for", "while", "return", "sizeof", "switch"}


def _function(text: str, signature: str) -> str:
    """The body of the function whose definition line starts with `signature`."""
    i = text.index(signature)
    j = text.index("\n}\n", i)
    return text[i:j + 2]


def _strip(body: str, prefix: str) -> str:
    body = re.sub(r"/\*.*?\*/", " ", body, flags=re.S)
    return re.sub(rf"\b{prefix}_k_\w+\(", "(", body)   # a kernel call's name (its arguments are read)


def _operand_end(tok: str) -> bool:
    return tok in (")", "]") or (re.match(r"^\w", tok) is not None and tok not in _TYPES | _KEYWORDS
                                 and not tok.endswith("_state") and not tok.endswith("_status"))


def float_ops(body: str, prefix: str, int_names: set[str]) -> list[str]:
    """The floating-point operations (and non-kernel calls) left in `body`, with context."""
    toks = _TOKEN.findall(_strip(body, prefix))
    ints = set(int_names) | set(re.findall(r"\b(?:uint32_t|int)\s+(\w+)", body))
    helpers = {f"{prefix}_hard_iron"}

    def is_int(t):
        return bool(_INT_LIT.match(t)) or t in ints

    found = []
    for n, t in enumerate(toks):
        ctx = " ".join(toks[max(0, n - 4):n + 5])
        prev = toks[n - 1] if n else ";"
        nxt = toks[n + 1] if n + 1 < len(toks) else ";"
        if re.match(r"^[A-Za-z_]\w*$", t) and nxt == "(" and t not in _KEYWORDS and prev not in _TYPES \
                and not prev.endswith(("_state", "_status")) and t not in helpers:
            found.append(f"call {t}: {ctx}")
            continue
        if t not in _ARITH:
            continue
        if t in ("*", "-") and not _operand_end(prev):
            if t == "-" and not is_int(nxt):
                found.append(f"negation: {ctx}")
            continue                                   # a pointer declarator, a dereference
        if t in ("++", "--"):
            if not (is_int(prev) or is_int(nxt)):
                found.append(f"{t}: {ctx}")
            continue
        if is_int(prev) and is_int(nxt):
            continue
        if t == ">" and prev in PIVOT_TESTS and re.match(r"^[\d.]+(?:[eE][-+]?\d+)?f?$", nxt) and \
                float(nxt.rstrip("f")) == M.S_PIVOT_MIN:
            continue
        found.append(f"{t}: {ctx}")
    return found


def _generated(precision, sets, runtime=None):
    cfg = config.resolve("mekf", sets=list(sets), precision=precision, runtime=runtime)
    gen = render.render(cfg)
    return gen, gen.files[f"{cfg.prefix}.c"]


def _check(gen, text):
    prefix = gen.manifest["prefix"]
    fields = gen.manifest["structs"]["state"]["fields"]
    ints = {f["name"] for f in fields if f["type"] != "real"}
    step = _function(text, f"{prefix}_status {prefix}_step(")
    own = step[step.rindex("\n", 0, step.index(START)):]     # from the comment's line
    own, gates = GATE.subn("if (gate) {", own)
    assert gates <= 1
    bad = float_ops(own, prefix, ints)
    if f"static void {prefix}_hard_iron(" in text:
        bad += float_ops(_function(text, f"static void {prefix}_hard_iron("), prefix, ints)
    assert bad == [], "floating-point work outside the kernels:\n" + "\n".join(bad)
    called = set(re.findall(rf"\b{prefix}_k_(\w+)\(", own))
    on_paths = {k for p in gen.manifest["step_paths"].values() for k in p["kernels"]}
    assert called - on_paths <= {"init_attitude", "hard_iron"}, called - on_paths


@pytest.mark.parametrize("precision,sets", CONFIGS, ids=lambda v: ",".join(v) if isinstance(v, tuple) else v)
def test_step_is_control_flow_copies_and_kernel_calls(precision, sets):
    _check(*_generated(precision, sets))


def test_runtime_build_step_too():
    _check(*_generated("float", (), runtime=RUNTIME))


def test_the_reader_sees_arithmetic():
    """The reader itself: the old template's hand-written lines are found, integer work is not."""
    ints = {"initialised", "a_ok"}
    body = """START
    const float a_rest = dt / (MEKF_REST_TAU + dt);
    s->rest_time += dt;
    const bool moving = s->v_age <= MEKF_GPS_VEL_TIMEOUT;
    mag_in[0] = in->mag[0] - s->mag_bias[0];
    use_tilt = mekf_norm2(up) > 0.25f;
    x = -y;
    for (uint32_t i = 0u; i < 3u; i++) { P[i + 6u * j] = P_saved[k]; h = &v[3u * i]; k++; }
    mekf_k_rest(in->gyro, dt, &at_rest);   /* a + b */
    mekf_k_rest(in->gyro, 0.5f * dt, &h[3u * i], s->a_ok != 0u);
    float *const q = s->q;
    if (s->initialised == 0u && *mag_use) { status |= MEKF_AT_REST; }
    usable = min_pivot > 1e-12f;
    usable = min_pivot > 1e-6f;
    """
    bad = float_ops(body, "mekf", ints | {"j", "k"})
    kinds = [b.split(":")[0] for b in bad]
    assert kinds == ["/", "+", "+=", "<=", "-", "call mekf_norm2", ">", "negation", "*", ">"], bad
