"""One kernel: the walk over a CasADi Function's instructions that writes its C (emit), and
the Kernel it returns."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import casadi as ca

from ahrsgen.codegen import fastmath
from ahrsgen.codegen.emit.branches import _layout
from ahrsgen.codegen.emit.names import _Marks
from ahrsgen.codegen.emit.ops import (_BINARY, _COMPARISONS, _CONNECTIVES, _LOGIC, _TMP_RE, _UNARY, CATEGORIES, PRECISIONS,
                                SUPPORTED, EmitError, _literal_value, literal, op_name)
from ahrsgen.codegen.emit.rewrite import _exact_reciprocals, _fuse_multiply_add, _shared_reciprocals
from ahrsgen.codegen.emit.split import _split

# Selects on one condition whose exclusive operations weigh less than this stay ?: (a
# conditional move is cheaper than a branch around a few adds).
BRANCH_MIN_COST = 12
# A kernel with at most this many temporaries is declared `static inline`: GCC then inlines
# it at every call site (a small kernel called from several places, e.g. R(q) again after an
# attitude reset, otherwise stays a call with its outputs in memory). qcf 723 -> 706
# instructions/step, -120 B; larger kernels called several times stay calls (flash).
INLINE_TEMPS = 32
# A kernel with more temporaries than this is written as parts of about this many, called
# in turn (GCC inlines them at -O1 and above): at -O0 every temporary has its own stack
# slot, and one frame per part keeps a debug build's stack bounded. 40 measured best over
# 24..400 (ahrsgen target all, with the shared carry array): adukf stack 2 008 -> 1 592 B,
# -O0 2 288 -> 1 792 B, 6 222 -> 5 726 instructions/step against 160; mekf -O0 1 360 -> 856 B
# but static stack 456 -> 488 B; GCC's inlining of the parts makes the figures jump with it
# (adukf at 56-100: about 1 950 B), so re-measure when changing it.
SPLIT_TEMPS = 40


@dataclass
class Arg:
    name: str
    size: int
    shape: tuple[int, int]
    expr: str | None = None    # read from a context (e.g. "par->kp") instead of an argument
    flag: bool = False         # a true/false input: C type bool, read as a condition

    @property
    def scalar(self) -> bool:
        return self.size == 1

    def param(self, real: str) -> str:
        """Its declaration as a (read-only) parameter."""
        ctype = "bool" if self.flag else real
        return f"{ctype} {self.name}" if self.scalar else f"const {ctype} {self.name}[{self.size}]"


@dataclass
class Kernel:
    """One emitted C function: prototype, body lines and its operation counts."""
    name: str
    precision: str
    inputs: list[Arg]
    outputs: list[Arg]
    body: list[str]
    ops: dict[str, int]
    doc: str = ""
    n_temporaries: int = 0
    unused_inputs: list[str] = field(default_factory=list)
    helpers: list[str] = field(default_factory=list)   # src/ahrsgen/codegen/fastmath.py helpers called
    branches: list[dict] = field(default_factory=list)  # if/else blocks: condition, ops of each side
    parts: list[str] = field(default_factory=list)      # sources of the part functions of a split kernel
    context: str | None = None    # leading parameter declaration, e.g. "const att_params *par"
    restrict: bool = False        # arrays declared restrict (emit's early_writes)

    @property
    def ops_total(self) -> int:
        return sum(self.ops.values())

    def prototype(self, storage: str = "static ") -> str:
        real = self.precision
        params = [self.context] if self.context else []
        r = "restrict " if self.restrict else ""
        for a in self.inputs:
            if a.expr is not None:
                continue
            params.append(a.param(real).replace("[", "[" + r))
        for a in self.outputs:
            ctype = "bool" if a.flag else real
            params.append(f"{ctype} *{r}{a.name}" if a.scalar else f"{ctype} {a.name}[{r}{a.size}]")
        return f"{storage}void {self.name}({', '.join(params)})"

    def source(self, storage: str = "static ", indent: str = "    ") -> str:
        lines = []
        for part in self.parts:
            lines += [part, ""]
        if self.doc:
            lines.append("/* " + self.doc.replace("*/", "* /") + " */")
        lines.append(self.prototype(storage))
        lines.append("{")
        for name in self.unused_inputs:
            lines.append(f"{indent}(void){name};")
        lines.extend(indent + b for b in self.body)
        lines.append("}")
        return "\n".join(lines)


def _check_name(name: str, what: str) -> None:
    if not name.isidentifier() or name.startswith("tmp") or re.fullmatch(r"carry\d*", name):
        raise EmitError(f"{what} name {name!r} is not a valid C identifier (and must not start with 'tmp' "
                        "or be carry/carry<N>)")


def emit(fn: ca.Function, precision: str = "float", name: str | None = None, doc: str = "",
         math: str = "libm", branch_min_cost: int | None = BRANCH_MIN_COST, fma: bool = False,
         split_temps: int | None = SPLIT_TEMPS, context: tuple[str, dict] | None = None,
         flags: tuple[str, ...] | list[str] = (), names: dict[int, str] | None = None,
         early_writes: bool = False) -> Kernel:
    """Emit an SX Function as a C function body for the given precision.

    ``math="fast"`` (float only; double always uses libm) writes fastmath helpers for the
    trigonometric functions. ``fma=True`` writes a product feeding a sum as fmaf(a, b, c):
    the emitter decides every fusion, so host and target round alike (the compiler's
    -ffp-contract stays off).

    context = (declaration, {input name: C expression}): those scalar inputs are read through
    one leading parameter (e.g. ("const att_params *par", {"param_kp": "par->kp"})) instead of
    being arguments of their own; the kernel takes the declaration first if it reads any.

    flags: names of inputs (and outputs) that only hold 0 or 1 (masks, use-this-sensor switches): they are
    declared bool and tested as conditions, never compared with 0.0f. Comparisons and their
    logic (<, <=, ==, !=, &&, ||, !) become bool temporaries too; where one is used as a number
    it is converted explicitly, (float)x.

    early_writes: store each output element as soon as its value is computed, instead of all
    outputs after all inputs are read, and declare the arrays `restrict` (C99): no output may
    then overlap an input or another output, which the caller must keep (without early_writes
    an output may overlay an input: every input is read before any output is written). A
    kernel with many outputs then does not hold them all until its end, where GCC spills what
    its registers cannot hold, and the compiler may order loads and stores freely.

    names: {instruction index: text} for OP_CONST instructions that are a folded parameter
    expression (src/ahrsgen/codegen/folded.py); the literal is written with the text in a comment
    beside it, `0.0049f /* accel_angle_noise^2 */`. Nothing else changes: until the body is
    written, a named literal is a placeholder that every decision reads as the literal.
    """
    if precision not in PRECISIONS:
        raise EmitError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if math not in fastmath.MATH_MODES:
        raise EmitError(f"math must be one of {fastmath.MATH_MODES}, got {math!r}")
    fast = math == "fast" and precision == "float"
    helpers: set[str] = set()
    if not fn.is_a("SXFunction"):
        raise EmitError(f"kernel {fn.name()}: only SX functions can be emitted (got {fn.class_name()})")
    name = name or fn.name()
    _check_name(name, "kernel")
    F = "f" if precision == "float" else ""
    one, zero = literal(1.0, precision), literal(0.0, precision)

    inputs, outputs = [], []
    for i in range(fn.n_in()):
        sp = fn.sparsity_in(i)
        if not sp.is_dense():
            raise EmitError(f"kernel {name}: input {fn.name_in(i)!r} is sparse; only dense inputs are supported")
        _check_name(fn.name_in(i), f"kernel {name}: input")
        inputs.append(Arg(fn.name_in(i), sp.nnz(), (sp.size1(), sp.size2()), flag=fn.name_in(i) in flags))
        if context and fn.name_in(i) in context[1]:
            if sp.nnz() != 1:
                raise EmitError(f"kernel {name}: context input {fn.name_in(i)!r} must be a scalar")
            inputs[-1].expr = context[1][fn.name_in(i)]
    for o in range(fn.n_out()):
        sp = fn.sparsity_out(o)
        if not sp.is_dense():
            raise EmitError(f"kernel {name}: output {fn.name_out(o)!r} is sparse; densify it in the model")
        _check_name(fn.name_out(o), f"kernel {name}: output")
        outputs.append(Arg(fn.name_out(o), sp.nnz(), (sp.size1(), sp.size2()), flag=fn.name_out(o) in flags))

    work: dict[int, str] = {}       # work index -> C expression (temporary, input ref or literal)
    nodes: dict[str, dict] = {}     # temporary -> {code, cat, expr, args}
    order: list[str] = []
    writes: list[str] = []
    used_inputs: set[int] = set()
    booleans: set[str] = set()      # flag input references and bool temporaries
    unknown = set(flags) - {fn.name_in(i) for i in range(fn.n_in())} - {fn.name_out(o) for o in range(fn.n_out())}
    if unknown:
        raise EmitError(f"kernel {name}: flag(s) {', '.join(sorted(unknown))} are neither inputs nor outputs")

    def ref(w: int) -> str:
        return work[w]

    marks = _Marks()

    def boolish(x: str) -> bool:
        return x in booleans or marks.plain(x) in (one, zero)

    def truth(x: str) -> str:
        x0 = marks.plain(x)
        return "true" if x0 == one else "false" if x0 == zero else x

    def value(x: str) -> str:
        """x read as a number: a bool is converted explicitly."""
        return f"({precision}){x}" if x in booleans else x

    def condition(x: str) -> str:
        """C condition for 'x is true', folding a comparison temporary into it."""
        node = nodes.get(x)
        if node is not None and node["code"] in _COMPARISONS:
            a, b = node["args"]
            return f"{value(a)} {_COMPARISONS[node['code']]} {value(b)}"
        if node is not None and node["code"] == ca.OP_NOT:
            return f"!({condition(node['args'][0])})"
        if x in booleans:
            return x
        return f"{x} != {zero}"

    for k in range(fn.n_instructions()):
        code = fn.instruction_id(k)
        if code == ca.OP_CONST:
            (w,) = fn.instruction_output(k)
            work[w] = literal(fn.instruction_constant(k), precision)
            if names and k in names:
                work[w] = marks.add(work[w], names[k])
            continue
        if code == ca.OP_INPUT:
            (w,) = fn.instruction_output(k)
            i, nz = fn.instruction_input(k)
            used_inputs.add(i)
            a = inputs[i]
            work[w] = a.expr if a.expr is not None else (a.name if a.scalar else f"{a.name}[{nz}]")
            if a.flag:
                booleans.add(work[w])
            continue
        if code == ca.OP_OUTPUT:
            (w,) = fn.instruction_input(k)
            o, nz = fn.instruction_output(k)
            a = outputs[o]
            target = f"*{a.name}" if a.scalar else f"{a.name}[{nz}]"
            if a.flag:
                x = ref(w)
                writes.append(f"{target} = {truth(x) if boolish(x) else f'{x} != {zero}'};")
            else:
                writes.append(f"{target} = {value(ref(w))};")
            continue
        if code == ca.OP_ASSIGN:
            (w_in,) = fn.instruction_input(k)[:1]
            (w,) = fn.instruction_output(k)
            work[w] = ref(w_in)
            continue
        ins = fn.instruction_input(k)
        (w,) = fn.instruction_output(k)
        sel = None
        args = [ref(ins[0])] + ([ref(ins[1])] if code in _BINARY or code == ca.OP_CONSTPOW else [])
        select = _as_select(code, args, nodes)
        args_v = [value(a) for a in args]    # operands read as numbers
        is_bool = select is None and code in _LOGIC
        if is_bool:
            cat, expr = "cmp", _LOGIC[code](*[condition(a) if code in _CONNECTIVES else value(a) for a in args])
        elif select is not None:
            cond, a, b = select
            if boolish(a) and boolish(b):      # a choice between truth values stays bool
                a, b = truth(a), truth(b)
                is_bool = True
            else:
                a, b = value(a), value(b)
            cat, expr = "cmp", f"({condition(cond)}) ? {a} : {b}"
            sel = (condition(cond), a, b)
        elif code == ca.OP_CONSTPOW:
            a, b = args_v
            expo = _literal_value(marks.plain(b))
            if expo == 2.0:
                cat, expr = "mul", f"{a} * {a}"
            elif expo == 3.0:
                cat, expr = "mul", f"{a} * {a} * {a}"
            elif expo == 0.5:
                cat, expr = "sqrt", f"sqrt{F}({a})"
            elif expo == -1.0:
                cat, expr = "div", f"{one} / {a}"
            else:
                cat, expr = "trig", f"pow{F}({a}, {b})"
        elif code == ca.OP_IF_ELSE_ZERO:
            c = condition(args[0])
            if c.startswith("!(") and c.endswith(")"):      # if_else(c, 0, x): same block as c's selects
                cat, expr = "cmp", f"({c[2:-1]}) ? {zero} : {args_v[1]}"
                sel = (c[2:-1], zero, args_v[1])
            else:
                cat, expr = "cmp", f"({c}) ? {args_v[1]} : {zero}"
                sel = (c, args_v[1], zero)
        elif fast and code in fastmath.OPS:
            h = fastmath.OPS[code]
            helpers.add(h)
            cat, expr = "trig", f"{fastmath.HELPERS[h].name}({', '.join(args_v)})"
        elif code in _BINARY:
            cat, fmt = _BINARY[code]
            expr = fmt.format(a=args_v[0], b=args_v[1], F=F, one=one, zero=zero)
        elif code in _UNARY:
            cat, fmt = _UNARY[code]
            expr = fmt.format(a=args_v[0], F=F, one=one, zero=zero)
        else:
            raise EmitError(
                f"kernel {name}: CasADi operation {op_name(code)} is not supported by the emitter "
                f"(supported: {', '.join(SUPPORTED)})")
        tmp = f"t{len(order)}"
        nodes[tmp] = {"code": code, "cat": cat, "expr": expr, "args": args, "sel": sel,
                      "vargs": args_v, "ctype": "bool" if is_bool else precision}
        if is_bool:
            booleans.add(tmp)
        order.append(tmp)
        work[w] = tmp

    # Dead-code elimination: select folding leaves some temporaries unread.
    live = set()
    for line in writes:
        live.update(_TMP_RE.findall(line))
    for tmp in reversed(order):
        if tmp in live:
            live.update(_TMP_RE.findall(nodes[tmp]["expr"]))
    kept = [t for t in order if t in live]
    kept = _exact_reciprocals(kept, nodes, precision, marks)
    kept = _shared_reciprocals(kept, nodes, one)
    if fma:
        kept = _fuse_multiply_add(kept, nodes, writes, "fmaf" if precision == "float" else "fma")
    ops = {c: 0 for c in CATEGORIES}
    for t in kept:
        ops[nodes[t]["cat"]] += 1
        for c in nodes[t].get("extra_ops", ()):
            ops[c] += 1
    body, emitted, branches, tops = _layout(kept, nodes, writes, precision, branch_min_cost, marks.plain)
    if fast:
        body, tops = _pair_sincos(body, tops)
    if early_writes:
        body, tops, writes = _place_writes_early(body, tops, writes)
    # Renumber in emission order so the temporaries count up without gaps.
    rename = {t: f"tmp{i}" for i, t in enumerate(emitted)}
    sub = lambda s: _TMP_RE.sub(lambda m: rename[m.group(0)], s)  # noqa: E731
    parts: list[str] = []
    reads_context = any(a.expr is not None for i, a in enumerate(inputs) if i in used_inputs)
    ctx_decl = context[0] if context and reads_context else None
    if split_temps and len(emitted) > split_temps:
        body, parts = _split(name, precision, inputs, body, writes, tops, split_temps, ctx_decl,
                             frozenset(t for t in kept if nodes[t]["ctype"] == "bool"), outputs)
        body, parts = [sub(line) for line in body], [sub(p) for p in parts]
    else:
        body = [sub(line) for line in body] + [sub(line) for line in writes]
    body, parts = [marks.write(line) for line in body], [marks.write(p) for p in parts]
    for br in branches:
        br["condition"] = sub(br["condition"])
    unused = [a.name for i, a in enumerate(inputs) if i not in used_inputs and a.expr is None]
    text = "\n".join(body + parts)
    used = {h for h in helpers | {"sincos"} if fastmath.HELPERS[h].name + "(" in text}
    return Kernel(name, precision, inputs, outputs, body, ops, doc, len(kept), unused, helpers=sorted(used),
                  branches=branches, parts=parts, context=ctx_decl, restrict=early_writes)


_SIN_OR_COS = re.compile(r"^(\s*)const float (t\d+) = fast_(sin|cos)f\((.+)\);$")


def _pair_sincos(body, tops):
    """A sin and a cos of the same argument in one scope become one fast_sincosf call at the
    first of them: one range reduction, the same floats. A pair is two lines
    `const float tN = fast_sinf(a);` and `fast_cosf(a)` with the same indentation and argument
    text and no line between them less indented (which would close their scope, e.g.
    `} else {`). The argument is an SSA temporary or input, defined before the first, so
    computing the second value there changes nothing; if the two lie in different top-level
    statements, the second's temporary is now defined by the first's (for _split). Returns
    (body, tops) with the lines renumbered."""
    lines: list[str | None] = list(body)
    top_of = {k: n for n, (a, b, _) in enumerate(tops) for k in range(a, b)}
    defs = [list(d) for _, _, d in tops]
    for i, line in enumerate(lines):
        m = _SIN_OR_COS.match(line) if line is not None else None
        if not m:
            continue
        ind, tmp, fn, arg = m.groups()
        for j in range(i + 1, len(lines)):
            other = lines[j]
            if other is None:
                continue
            if other.strip() and len(other) - len(other.lstrip()) < len(ind):
                break
            m2 = _SIN_OR_COS.match(other)
            if m2 and m2.group(1) == ind and m2.group(4) == arg and m2.group(3) != fn:
                second = m2.group(2)
                s, c = (tmp, second) if fn == "sin" else (second, tmp)
                lines[i] = (f"{ind}float {s};\n{ind}float {c};\n"
                            f"{ind}fast_sincosf({arg}, &{s}, &{c});   /* sin and cos, one reduction */")
                lines[j] = None
                if top_of[i] != top_of[j]:
                    defs[top_of[j]].remove(second)
                    defs[top_of[i]].append(second)
                break
    new_body, new_tops = [], []
    for n, (a, b, _) in enumerate(tops):
        start = len(new_body)
        new_body += [ln for text in lines[a:b] if text is not None for ln in text.split("\n")]
        new_tops.append((start, len(new_body), defs[n]))
    return new_body, new_tops


def _place_writes_early(body, tops, writes):
    """Each output write moved to just after the top-level statement that defines the last
    temporary it reads (a write reading only inputs or literals: after the first statement).
    Returns (body, tops, the writes left for the end: none unless the body is empty)."""
    def_top = {t: k for k, (_, _, d) in enumerate(tops) for t in d}
    if not tops:
        return body, tops, writes
    at: dict[int, list[str]] = {}
    for w in writes:
        at.setdefault(max([def_top[t] for t in _TMP_RE.findall(w)] + [0]), []).append(w)
    new_body, new_tops = [], []
    for k, (a, b, d) in enumerate(tops):
        start = len(new_body)
        new_body += body[a:b] + at.get(k, [])
        new_tops.append((start, len(new_body), d))
    return new_body, new_tops, []


def _as_select(code, args, nodes):
    """Recognise CasADi's if_else(c, a, b) = if_else_zero(c, a) + if_else_zero(!c, b)."""
    if code != ca.OP_ADD:
        return None
    n1, n2 = nodes.get(args[0]), nodes.get(args[1])
    if not n1 or not n2 or n1["code"] != ca.OP_IF_ELSE_ZERO or n2["code"] != ca.OP_IF_ELSE_ZERO:
        return None
    c1, c2 = n1["args"][0], n2["args"][0]
    not1, not2 = nodes.get(c1), nodes.get(c2)
    if not2 and not2["code"] == ca.OP_NOT and not2["args"][0] == c1:
        return c1, n1["args"][1], n2["args"][1]
    if not1 and not1["code"] == ca.OP_NOT and not1["args"][0] == c2:
        return c2, n2["args"][1], n1["args"][1]
    return None
