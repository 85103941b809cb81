"""Every value a filter's configuration accepts generates C that is finite and compiles (issue 11).

For every filter and every parameter: its minimum, its maximum (just inside an exclusive bound)
and a middle value (geometric for ranges spanning decades), each choice and both booleans, the
other parameters at their defaults. Each value is generated; the C must hold no inf/nan literal;
all values of one filter are compiled together with the strict flags in one compiler call (one
object per value). The expected result (compiles, finite) is independent of the generator: it is
what the C compiler and the C standard say about the text.
"""
from __future__ import annotations

import math
import os
import re
import subprocess
from pathlib import Path

import pytest

from conftest import needs
from ahrsgen.sim import host
from ahrsgen.generate import config, render
from ahrsgen import filters
from ahrsgen.codegen.model import ConfigError

pytestmark = pytest.mark.slow       # tests/README.md: left out of the quick run

# A parameter value folded into a literal that overflowed prints as inf / inff (nan / nanf);
# comments are left out, and the C99 macros NAN / INFINITY a template writes on purpose (e.g. a
# fast sine returning NAN out of range) are not literals of a parameter.
_NONFINITE = re.compile(r"\b(inff?|nanf?)\b")
_COMMENT = re.compile(r"/\*.*?\*/|//[^\n]*", re.S)


def _inside(p, v, toward):
    """v nudged inside an exclusive bound, toward `toward`."""
    return v + (toward - v) * 1e-6 if v != 0 else (1e-6 if toward > 0 else -1e-6) * max(1.0, abs(toward))


def sweep_values(p) -> list:
    if p.choices:
        return list(p.choices)
    if p.type == "bool":
        return [False, True]
    if p.type == "str":
        return []
    lo, hi = p.min, p.max
    assert lo is not None and hi is not None, f"{p.name}: range must be bounded ({p.range_text()})"
    lo_v = _inside(p, lo, hi) if p.min_exclusive else lo
    hi_v = _inside(p, hi, lo) if p.max_exclusive else hi
    if lo_v > 0 and hi_v / lo_v > 1e3:
        mid = math.sqrt(lo_v * hi_v)
    else:
        mid = 0.5 * (lo_v + hi_v)
    vals = [lo_v, mid, hi_v]
    if p.type == "int":
        vals = sorted({int(math.ceil(lo_v)), int(round(mid)), int(math.floor(hi_v))})
    return vals


def cases(name: str) -> list[tuple[str, object]]:
    spec = filters.load(name)
    return [(pn, v) for pn, p in spec.params.items() for v in sweep_values(p)]


def _generate(job):
    """One value: (set text, problem or None, C source folder or None). Runs in a worker."""
    name, i, pn, v, out = job
    text = f"{pn}={str(v).lower() if isinstance(v, bool) else v if isinstance(v, str) else repr(v)}"
    try:
        cfg = config.resolve(name, sets=[text], prefix=f"v{i}")
    except ConfigError as e:      # the sweep only uses declared values: a refusal is a bug
        return text, f"{text}: refused: {e}", None
    try:
        gen = render.render(cfg)
    except Exception as e:        # noqa: BLE001 - report every failing value, not just the first
        return text, f"{text}: generation failed: {type(e).__name__}: {e}", None
    src = gen.files[f"v{i}.c"] + gen.files[f"v{i}.h"]
    bad = sorted(set(_NONFINITE.findall(_COMMENT.sub(" ", src))))
    d = Path(out) / f"v{i}"
    render.write(gen, d)
    return text, f"{text}: non-finite literal(s) {bad} in the C" if bad else None, str(d / f"v{i}.c")


@needs("cc")
@pytest.mark.parametrize("name", filters.names())
def test_every_accepted_value_generates_finite_c_that_compiles(name, tmp_path):
    from concurrent.futures import ProcessPoolExecutor
    jobs = [(name, i, pn, v, str(tmp_path)) for i, (pn, v) in enumerate(cases(name))]
    with ProcessPoolExecutor(max(1, min(4, os.cpu_count() or 1))) as pool:     # generation is the cost
        done = list(pool.map(_generate, jobs, chunksize=4))
    problems = [p for _, p, _ in done if p]
    sources = [(t, Path(c)) for t, _, c in done if c]
    # one compiler call for the whole filter: -c of every value's source (objects named apart)
    cmd = ["cc", *host.STRICT, "-O0", "-c"]
    for _, c in sources:
        cmd += [f"-I{c.parent}", str(c)]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path)
    if r.returncode != 0:
        failing = {t for t, c in sources if f"v{c.stem[1:]}.c" in r.stderr or str(c) in r.stderr}
        problems.append(f"compile failed for {sorted(failing) or 'some value'}:\n{r.stderr[:3000]}")
    assert not problems, f"{name}:\n" + "\n".join(problems)
