"""Every emitted kernel carries an Args/Outputs block above its function (DESIGN.md: name,
shape, layout; the total op count), checked in the generated source of every filter, float
and double, default and runtime builds, against the CasADi Function the kernel was emitted
from (names and shapes) and the manifest (op counts)."""
from __future__ import annotations

import pytest

from conftest import kernel_builds, rendered


def _block_above(lines: list[str], name: str) -> list[str]:
    """The comment lines right above the definition of function `name`."""
    at = [i for i, ln in enumerate(lines) if f"void {name}(" in ln and not ln.startswith(" ")]
    assert len(at) == 1, (name, at)
    i = at[0] - 1
    while lines[i].startswith(("#", "__attribute__")):     # a noinline kernel's attribute
        i -= 1
    assert lines[i] == " */", (name, lines[i])
    end = i
    while not lines[i].startswith("/*"):
        i -= 1
    return lines[i:end + 1]


def _section(block: list[str], head: str) -> list[str]:
    start = block.index(f" * {head}:") + 1
    out = []
    for ln in block[start:]:
        if not ln.startswith(" *     "):
            break
        if not ln.startswith(" *         "):        # a wrapped line continues the one above
            out.append(ln[len(" *     "):])
    return out


@pytest.mark.parametrize("name,precision,runtime", kernel_builds())
def test_every_kernel_has_its_args_outputs_block(name, precision, runtime):
    gen = rendered(name, precision, runtime)
    man = gen.manifest
    lines = gen.files[man["files"]["source"]].splitlines()
    totals = {k["c_name"]: k["total"] for k in man["kernels"].values()}
    assert set(totals) == {k.name for k in gen.kernels}
    for k in gen.kernels:
        fn = k.source_fn
        block = _block_above(lines, k.name)
        args, outs = _section(block, "Args"), _section(block, "Outputs")
        expect_in = [(fn.name_in(i), fn.size1_in(i), fn.size2_in(i)) for i in range(fn.n_in())
                     if not fn.name_in(i).startswith("param_")]
        expect_out = [(fn.name_out(i), fn.size1_out(i), fn.size2_out(i)) for i in range(fn.n_out())]
        if any(fn.name_in(i).startswith("param_") for i in range(fn.n_in())):
            assert args[0].startswith("par: runtime parameters"), (k.name, args)
            args = args[1:]
        for got, want in ((args, expect_in), (outs, expect_out)):
            assert [g.split(":")[0] for g in got] == [w[0] for w in want], (k.name, got)
            for g, (arg, r, c) in zip(got, want):
                shape = g.split(": ", 1)[1]
                real = "bool" if shape.startswith("bool") else precision
                assert shape.startswith(real + (f"[{r * c}]" if r * c > 1 else "")), (k.name, g)
                assert ("column-major" in shape) == (r > 1 and c > 1), (k.name, g)
        assert f" * Total ops: {totals[k.name]} (" in "\n".join(block), (k.name, block)
