"""Limits tested at their edges (issue 30, class 3): for every parameter of every filter that can
be a runtime parameter, the C setter of a double build accepts exactly what the declared range
says, at min and at max, and refuses the next double beyond each end (and the bound itself where
it is exclusive); the defaults always set.

The expected answers come from the declared range (defaults.toml / the common input checks),
not from the code under test. Which parameters can be runtime is found by asking the model and
the renderer (a parameter that shapes the code is refused with one line and left out here).
"""
from __future__ import annotations

import math
import re

import pytest

from ahrsgen import filters
from ahrsgen.errors import ConfigError
from ahrsgen.generate import config, render
from ahrsgen.sim import host


def _eligible(name: str) -> list[str]:
    spec = filters.load(name)
    params = spec.defaults()
    out = []
    for n, p in spec.params.items():
        if p.type != "float" or p.choices or p.min is None or p.max is None:
            continue
        try:
            render._model_parts(spec, params, (n,))
        except Exception:
            continue
        out.append(n)
    while out:                       # the templates may read a value to shape the code
        try:
            render.render(config.resolve(name, precision="double", runtime=",".join(out)))
            return out
        except ConfigError as e:
            m = re.search(r"parameter '(\w+)' cannot be a runtime parameter", str(e))
            assert m and m.group(1) in out, str(e)
            out.remove(m.group(1))
    return out


def _edges(p) -> list[tuple[float, bool]]:
    """(value, accepted?) at both ends of the declared range: the bound itself, and the next
    double beyond it and inside it."""
    lo, hi = float(p.min), float(p.max)
    return [(lo, not p.min_exclusive), (math.nextafter(lo, -math.inf), False), (math.nextafter(lo, math.inf), True),
            (hi, not p.max_exclusive), (math.nextafter(hi, math.inf), False), (math.nextafter(hi, -math.inf), True)]


@pytest.mark.parametrize("name", filters.names())
def test_setter_accepts_exactly_the_declared_range(name):
    runtime = _eligible(name)
    assert runtime, f"{name}: no runtime-eligible parameter found"
    hf = host.build(config.resolve(name, precision="double", runtime=",".join(runtime)))
    spec = filters.load(name)
    s = hf.new_state()
    assert hf.set_params(s, {}) == 0, "the defaults must always set"
    assert hf.set_params(s, {n: spec.params[n].default for n in runtime}) == 0
    wrong = []
    for n in runtime:
        for v, ok in _edges(spec.params[n]):
            before = hf.state_bytes(s)
            code = hf.set_params(s, {n: v})
            if (code == 0) != ok:
                wrong.append(f"{n} = {v!r}: {'refused' if code else 'accepted'}, range {spec.params[n].range_text()}")
            if code:
                assert hf.state_bytes(s) == before, f"{n} = {v!r}: a refused set changed the state"
            assert hf.set_params(s, {}) == 0
    assert not wrong, wrong
