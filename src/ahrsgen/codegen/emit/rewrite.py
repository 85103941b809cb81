"""Rewrites of the operation list before layout: exact reciprocals, fused multiply-adds."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from ahrsgen.codegen.emit.ir import Call, Lit, Op, Temp, temps
from ahrsgen.codegen.emit.names import _reciprocal_name
from ahrsgen.codegen.emit.ops import lit


def _exact_reciprocals(kept, nodes, precision):
    """x / c with c a power of two -> x * (1 / c): the same value to the last bit (1 / c is
    exact), a multiplication instead of a division (14 cycles on the M4F, GCC keeps the
    division without -freciprocal-math). A named c gives a named 1 / c."""
    for t in kept:
        n = nodes[t]
        d = n["args"][1] if n["code"] == ca.OP_DIV and n["sel"] is None else None
        c = d.value if isinstance(d, Lit) else None
        if _power_of_two(c, precision):
            r = lit(1.0 / c, precision, _reciprocal_name(d.name) if d.name else None)
            x = n["vargs"][0]
            n.update(code=ca.OP_MUL, cat="mul", expr=Op("*", (x, r)), args=[n["args"][0], r], vargs=[x, r])
    return kept


def _shared_reciprocals(kept, nodes, one):
    """Two or more quotients by one computed denominator d (a temporary or an input, not a
    literal) -> r = 1 / d once and products x * r: one division (14 cycles on the M4F) instead
    of several, as a hand-writer normalises a vector. x * (1 / d) may differ from x / d in the
    last bit (the double build stays within 1e-9 rad of the reference; the float effect is
    measured in docs/target.md). r is placed just before the first quotient, so the branch
    layout puts it where its users are."""
    by_den: dict[str, list[str]] = {}
    for t in kept:
        n = nodes[t]
        if n["code"] == ca.OP_DIV and n["sel"] is None and not isinstance(n["args"][1], Lit):
            by_den.setdefault(n["args"][1], []).append(t)
    first = {ts[0]: d for d, ts in by_den.items() if len(ts) >= 2}
    if not first:
        return kept
    out = []
    for t in kept:
        d = first.get(t)
        if d is not None:
            r = Temp(nodes[t]["ctype"])
            den = nodes[t]["vargs"][1]
            nodes[r] = {"code": ca.OP_DIV, "cat": "div", "expr": Op("/", (one, den)), "args": [one, d],
                        "sel": None, "vargs": [one, den], "ctype": nodes[t]["ctype"]}
            out.append(r)
            for q in by_den[d]:
                x = nodes[q]["args"][0]
                nodes[q].update(code=ca.OP_MUL, cat="mul", expr=Op("*", (nodes[q]["vargs"][0], r)), args=[x, r],
                                vargs=[nodes[q]["vargs"][0], r])
        out.append(t)
    return out


def _power_of_two(c, precision) -> bool:
    """c = +-2^k with 1 / c a normal number of the precision (so x * (1 / c) == x / c)."""
    if c is None or c == 0.0 or not np.isfinite(c) or math.frexp(abs(c))[0] != 0.5:
        return False
    r = abs(1.0 / c)
    fi = np.finfo(np.float32 if precision == "float" else np.float64)
    return float(fi.tiny) <= r <= float(fi.max)     # as Python floats: no float32 cast of r to overflow


def _fuse_multiply_add(kept, nodes, writes, fname):
    """a * b + c, c + a * b, a * b - c and c - a * b -> one fused multiply-add (rounded once).
    Every sum with a product operand fuses it; the product's own temporary disappears when
    no other use is left. Counted as one mul and one add."""
    uses: dict[str, int] = {t: 0 for t in kept}
    for t in kept:
        for r in temps(nodes[t]["expr"]):
            uses[r] += 1
    for w in writes:
        for r in temps(w.expr):
            uses[r] += 1
    fused: dict[str, int] = {}
    for t in kept:
        node = nodes[t]
        if node["code"] not in (ca.OP_ADD, ca.OP_SUB) or node["sel"] is not None:
            continue
        x, y = node["vargs"]
        for pos, m in ((0, x), (1, y)):
            mn = nodes.get(m)
            if mn is None or mn["code"] != ca.OP_MUL or m == (y if pos == 0 else x):
                continue
            a, b = mn["vargs"]
            other = y if pos == 0 else x
            if node["code"] == ca.OP_ADD:
                expr = Call(fname, (a, b, other))
            elif pos == 0:                       # a * b - c
                expr = Call(fname, (a, b, Op("neg", (other,))))
            else:                                # c - a * b
                expr = Call(fname, (Op("neg", (a,)), b, other))
            node["expr"] = expr
            node["cat"] = "mul"
            node["extra_ops"] = ("add",)
            fused[m] = fused.get(m, 0) + 1
            break
    return [t for t in kept if not (t in fused and fused[t] == uses[t])]
