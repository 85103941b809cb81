"""One kernel: the walk over a CasADi Function's instructions that writes its C (emit), and
the Kernel it returns."""
from __future__ import annotations

import textwrap
from dataclasses import dataclass, field

import casadi as ca

from ahrsgen.codegen import fastmath
from ahrsgen.codegen.emit import ir
from ahrsgen.codegen.emit.branches import _layout
from ahrsgen.codegen.emit.ir import Call, Cast, Ctx, Elem, If, Let, Lit, Op, Param, Select, SinCos, Store, Temp
from ahrsgen.codegen.emit.ops import (_BINARY, _COMPARISONS, _CONNECTIVES, _LOGIC, _UNARY, CATEGORIES, PRECISIONS,
                                      SUPPORTED, EmitError, lit, op_name)
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

    def as_param(self, real: str, output: bool = False, restrict: bool = False) -> Param:
        """Its parameter: an input read-only (a scalar by value), an output written through."""
        ctype = "bool" if self.flag else real
        if output:
            return Param(self.name, ctype, None if self.scalar else self.size, pointer=self.scalar, restrict=restrict)
        if self.scalar:
            return Param(self.name, ctype)
        return Param(self.name, ctype, self.size, const=True, restrict=restrict)

    def param(self, real: str) -> str:
        """Its declaration as a (read-only) parameter."""
        return self.as_param(real).c()


def context_param(decl: str) -> Param:
    """The context pointer's parameter from its declaration, e.g. "const att_params *par"."""
    ctype, _, name = decl.rpartition("*")
    ctype = ctype.strip()
    const = ctype.startswith("const ")
    return Param(name.strip(), ctype.removeprefix("const ").strip(), pointer=True, const=const)


@dataclass
class Kernel:
    """One emitted C function as data: its arguments, its statements (ir), the part functions
    of a split kernel, its operation counts. ir's printer writes it as C."""
    name: str
    precision: str
    inputs: list[Arg]
    outputs: list[Arg]
    body: list                     # ir statements
    ops: dict[str, int]
    doc: str = ""
    n_temporaries: int = 0
    unused_inputs: list[str] = field(default_factory=list)
    helpers: list[str] = field(default_factory=list)   # src/ahrsgen/codegen/fastmath.py helpers called
    branches: list[dict] = field(default_factory=list)  # if/else blocks: condition, ops of each side
    parts: list[ir.Function] = field(default_factory=list)   # the part functions of a split kernel
    context: str | None = None    # leading parameter declaration, e.g. "const att_params *par"
    restrict: bool = False        # arrays declared restrict (emit's early_writes) ...
    shared: frozenset = frozenset()   # ... except these (emit's in_place: an output and its input)
    source_fn: ca.Function | None = field(default=None, repr=False, compare=False)  # what was emitted
    storage: str = "static "      # what precedes `void` in its definition (the renderer decides)

    @property
    def ops_total(self) -> int:
        return sum(self.ops.values())

    def params(self) -> list[Param]:
        out = [context_param(self.context)] if self.context else []
        out += [a.as_param(self.precision, restrict=self.restrict and a.name not in self.shared)
                for a in self.inputs if a.expr is None]
        out += [a.as_param(self.precision, output=True, restrict=self.restrict and a.name not in self.shared)
                for a in self.outputs]
        return out

    def function(self) -> ir.Function:
        """The kernel's own function (a split kernel's calls its parts)."""
        return ir.Function(self.name, self.params(), self.body, list(self.unused_inputs), self.storage)

    def functions(self) -> list[ir.Function]:
        """Every C function of the kernel, in the order printed: its parts, then itself."""
        return list(self.parts) + [self.function()]

    def prototype(self, storage: str | None = None) -> str:
        return self.function().prototype(storage)

    def lines(self) -> list[str]:
        """The printed body of the kernel's own function."""
        return self.function().lines()

    def part_sources(self) -> list[str]:
        return [p.source() for p in self.parts]

    def comment(self, width: int = 100) -> list[str]:
        """The block above the kernel's function, as PX4's and SymForce's generated functions
        carry: what it computes (doc), Args and Outputs (name, C type and shape; a matrix is
        stated column-major), the total operation count and its categories."""
        wrap = lambda text, first="", rest="": textwrap.wrap(  # noqa: E731
            text, width - 3, initial_indent=first, subsequent_indent=rest, break_on_hyphens=False)
        lines = wrap(self.doc.replace("*/", "* /")) + [""] if self.doc else []
        lines.append("Args:")
        if self.context:
            read = ", ".join(a.expr for a in self.inputs if a.expr is not None)
            lines += wrap(f"{context_param(self.context).name}: runtime parameters, reads {read}", "    ", "        ")
        for a in self.inputs:
            if a.expr is None:
                lines += wrap(f"{a.name}: {_shape_text(a, self.precision)}"
                              + (" (unused)" if a.name in self.unused_inputs else ""), "    ", "        ")
        lines.append("Outputs:")
        for a in self.outputs:
            lines += wrap(f"{a.name}: {_shape_text(a, self.precision)}", "    ", "        ")
        lines += ["", f"Total ops: {self.ops_total} ("
                  + ", ".join(f"{n} {c}" for n, c in self.ops.items() if c) + ")"]
        for b in self.branches:
            lines += wrap(f"of which only one side runs: if ({b['condition']}) {sum(b['then'].values())}, "
                          f"else {sum(b['else'].values())}", "    ", "        ")
        return ["/*"] + [(" * " + ln).rstrip() for ln in lines] + [" */"]

    def source(self, storage: str | None = None, indent: str = "    ") -> str:
        """The kernel's C: its parts (a split kernel), then its comment and its function."""
        lines = []
        for part in self.parts:
            lines += [part.source(indent=indent), ""]
        lines += self.comment()
        lines.append(self.function().source(storage, indent))
        return "\n".join(lines)


def _shape_text(a: Arg, real: str) -> str:
    """C type and shape of an argument; a matrix is flattened column-major (CasADi's order)."""
    ctype = "bool" if a.flag else real
    rows, cols = a.shape
    if a.size == 1:
        return ctype
    if rows == 1 or cols == 1:
        return f"{ctype}[{a.size}]"
    return f"{ctype}[{a.size}], {rows}x{cols} matrix, column-major: row i, column j at [i + {rows} * j]"


def _check_name(name: str, what: str) -> None:
    if (not name.isidentifier() or name.startswith("tmp") or
            (name.startswith("carry") and (name[5:] == "" or name[5:].isdigit()))):
        raise EmitError(f"{what} name {name!r} is not a valid C identifier (and must not start with 'tmp' "
                        "or be carry/carry<N>)")


def _literal_name(name: str) -> str:
    """A folded parameter's text as it rides in a C comment."""
    return name.replace("*/", "* /").replace("/*", "/ *")


def emit(fn: ca.Function, precision: str = "float", name: str | None = None, doc: str = "",
         math: str = "libm", branch_min_cost: int | None = BRANCH_MIN_COST, fma: bool = False,
         split_temps: int | None = SPLIT_TEMPS, context: tuple[str, dict] | None = None,
         flags: tuple[str, ...] | list[str] = (), names: dict[int, str] | None = None,
         early_writes: bool = False, in_place: dict[str, str] | None = None) -> Kernel:
    """Emit an SX Function as a kernel (statements as data, ir) for the given precision.

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

    in_place: {output name: input name} (with early_writes): that output may be that input itself
    (the same array, the state updated in place): each of its element writes is placed after
    the last statement reading the input's element of the same index too, and those two arrays
    are not declared restrict (the others are: no other overlap is allowed).

    names: {(instruction index, operand): text} for the constants operations read that are a
    folded parameter expression or a named constant (src/ahrsgen/codegen/folded.py), named per
    use (one constant of the graph may stand for a parameter at one use and for an equal
    structural constant at another); the literal (ir.Lit) carries the text, printed in a
    comment beside it, `0.0049f /* accel_angle_noise^2 */`. Nothing else changes: every
    decision reads a named literal as the literal.
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
    one, zero = lit(1.0, precision), lit(0.0, precision)
    true, false = Lit("true", 1.0), Lit("false", 0.0)

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

    work: dict[int, object] = {}    # work index -> expression (temporary, input element or literal)
    nodes: dict[Temp, dict] = {}    # temporary -> {code, cat, expr, args, sel, vargs, ctype}
    order: list[Temp] = []
    writes: list[Store] = []
    used_inputs: set[int] = set()
    booleans: set = set()           # flag input elements and bool temporaries
    unknown = set(flags) - {fn.name_in(i) for i in range(fn.n_in())} - {fn.name_out(o) for o in range(fn.n_out())}
    if unknown:
        raise EmitError(f"kernel {name}: flag(s) {', '.join(sorted(unknown))} are neither inputs nor outputs")

    def is_lit(x, v) -> bool:
        return isinstance(x, Lit) and x.value == v

    def boolish(x) -> bool:
        return x in booleans or is_lit(x, 1.0) or is_lit(x, 0.0)

    def truth(x):
        return true if is_lit(x, 1.0) else false if is_lit(x, 0.0) else x

    def value(x):
        """x read as a number: a bool is converted explicitly."""
        return Cast(precision, x) if x in booleans else x

    def condition(x):
        """The condition 'x is true', folding a comparison temporary into it."""
        node = nodes.get(x)
        if node is not None and node["code"] in _COMPARISONS:
            a, b = node["args"]
            return Op(_COMPARISONS[node["code"]], (value(a), value(b)))
        if node is not None and node["code"] == ca.OP_NOT:
            return Op("!", (condition(node["args"][0]),))
        if x in booleans:
            return x
        return Op("!=", (x, zero))

    def operand(k, j, w):
        """Operand j of instruction k (work element w): a literal with the name this use of it
        has (names), if any."""
        x = work[w]
        if names and (k, j) in names and isinstance(x, Lit):
            return Lit(x.text, x.value, _literal_name(names[(k, j)]))
        return x

    for k in range(fn.n_instructions()):
        code = fn.instruction_id(k)
        if code == ca.OP_CONST:
            (w,) = fn.instruction_output(k)
            work[w] = lit(fn.instruction_constant(k), precision)
            continue
        if code == ca.OP_INPUT:
            (w,) = fn.instruction_output(k)
            i, nz = fn.instruction_input(k)
            used_inputs.add(i)
            a = inputs[i]
            work[w] = Ctx(a.name, a.expr) if a.expr is not None else Elem(a.name, None if a.scalar else nz)
            if a.flag:
                booleans.add(work[w])
            continue
        if code == ca.OP_OUTPUT:
            (w,) = fn.instruction_input(k)
            o, nz = fn.instruction_output(k)
            a = outputs[o]
            target = Elem(a.name, None if a.scalar else nz)
            x = operand(k, 0, w)
            if a.flag:
                writes.append(Store(target, truth(x) if boolish(x) else Op("!=", (x, zero))))
            else:
                writes.append(Store(target, value(x)))
            continue
        if code == ca.OP_ASSIGN:
            (w_in,) = fn.instruction_input(k)[:1]
            (w,) = fn.instruction_output(k)
            work[w] = operand(k, 0, w_in)
            continue
        ins = fn.instruction_input(k)
        (w,) = fn.instruction_output(k)
        sel = None
        extra: tuple = ()
        args = [operand(k, 0, ins[0])] + ([operand(k, 1, ins[1])] if code in _BINARY or code == ca.OP_CONSTPOW else [])
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
            sel = (condition(cond), a, b)
            cat, expr = "cmp", Select(*sel)
        elif code == ca.OP_CONSTPOW:
            a, b = args_v
            expo = b.value if isinstance(b, Lit) else None
            if expo == 2.0:
                cat, expr = "mul", Op("*", (a, a))
            elif expo == 3.0:
                cat, expr, extra = "mul", Op("*", (Op("*", (a, a)), a)), ("mul",)
            elif expo == 0.5:
                cat, expr = "sqrt", Call(f"sqrt{F}", (a,))
            elif expo == -1.0:
                cat, expr = "div", Op("/", (one, a))
            else:
                cat, expr = "trig", Call(f"pow{F}", (a, b))
        elif code == ca.OP_IF_ELSE_ZERO:
            c = condition(args[0])
            if isinstance(c, Op) and c.op == "!":      # if_else(c, 0, x): same block as c's selects
                sel = (c.args[0], zero, args_v[1])
            else:
                sel = (c, args_v[1], zero)
            cat, expr = "cmp", Select(*sel)
        elif fast and code in fastmath.OPS:
            h = fastmath.OPS[code]
            helpers.add(h)
            cat, expr = "trig", Call(fastmath.HELPERS[h].name, tuple(args_v))
        elif code in _BINARY:
            cat, build = _BINARY[code]
            expr = build(args_v[0], args_v[1], F, one, zero)
        elif code in _UNARY:
            cat, build = _UNARY[code]
            expr = build(args_v[0], F, one, zero)
        else:
            raise EmitError(
                f"kernel {name}: CasADi operation {op_name(code)} is not supported by the emitter "
                f"(supported: {', '.join(SUPPORTED)})")
        tmp = Temp("bool" if is_bool else precision)
        nodes[tmp] = {"code": code, "cat": cat, "expr": expr, "args": args, "sel": sel,
                      "vargs": args_v, "ctype": tmp.ctype, "extra_ops": extra}
        if is_bool:
            booleans.add(tmp)
        order.append(tmp)
        work[w] = tmp

    # Dead-code elimination: select folding leaves some temporaries unread.
    live = set(ir.reads(writes))
    for tmp in reversed(order):
        if tmp in live:
            live.update(ir.temps(nodes[tmp]["expr"]))
    kept = [t for t in order if t in live]
    kept = _exact_reciprocals(kept, nodes, precision)
    kept = _shared_reciprocals(kept, nodes, one)
    if fma:
        kept = _fuse_multiply_add(kept, nodes, writes, "fmaf" if precision == "float" else "fma")
    ops = {c: 0 for c in CATEGORIES}
    for t in kept:
        ops[nodes[t]["cat"]] += 1
        for c in nodes[t].get("extra_ops", ()):
            ops[c] += 1
    body, emitted, branches = _layout(kept, nodes, writes, precision, branch_min_cost)
    if fast:
        body = _pair_sincos(body)
    if in_place and not early_writes:
        raise EmitError(f"kernel {name}: in_place needs early_writes")
    for o, i in (in_place or {}).items():
        out_a = next((a for a in outputs if a.name == o), None)
        in_a = next((a for a in inputs if a.name == i), None)
        if out_a is None or in_a is None or out_a.size != in_a.size:
            raise EmitError(f"kernel {name}: in_place {o!r} <- {i!r}: an output and an input of one size")
    if early_writes:
        body, writes = _place_writes_early(body, writes, in_place or {})
    # Named in emission order so the temporaries count up without gaps.
    for i, t in enumerate(emitted):
        t.name = f"tmp{i}"
    parts: list[ir.Function] = []
    reads_context = any(a.expr is not None for i, a in enumerate(inputs) if i in used_inputs)
    ctx_decl = context[0] if context and reads_context else None
    if split_temps and len(emitted) > split_temps:
        body, parts = _split(name, precision, inputs, body, writes, split_temps,
                             context_param(ctx_decl) if ctx_decl else None,
                             frozenset(t for t in kept if nodes[t]["ctype"] == "bool"), outputs)
    else:
        body = body + writes
    for br in branches:
        br["condition"] = ir.print_expr(br["condition"], names=False)
    unused = [a.name for i, a in enumerate(inputs) if i not in used_inputs and a.expr is None]
    called = {s.fn for f in [body] + [p.body for p in parts] for s in ir.all_statements(f) if isinstance(s, SinCos)}
    called |= {x.fn for f in [body] + [p.body for p in parts] for s in ir.all_statements(f)
               for e in ir.exprs(s) for x in ir.walk(e) if isinstance(x, Call)}
    used = {h for h in helpers | {"sincos"} if fastmath.HELPERS[h].name in called}
    return Kernel(name, precision, inputs, outputs, body, ops, doc, len(kept), unused, helpers=sorted(used),
                  branches=branches, parts=parts, context=ctx_decl, restrict=early_writes,
                  shared=frozenset(in_place or {}) | frozenset((in_place or {}).values()), source_fn=fn)


_SINCOS = {"fast_sinf": "sin", "fast_cosf": "cos"}


def _trig_of(s):
    """("sin" or "cos", argument) of a statement `const float t = fast_sinf(a);`, else None."""
    if isinstance(s, Let) and isinstance(s.expr, Call) and s.expr.fn in _SINCOS and len(s.expr.args) == 1:
        return _SINCOS[s.expr.fn], s.expr.args[0]
    return None


def _pair_sincos(stmts: list) -> list:
    """A sin and a cos of the same argument in one statement list (one scope) become one
    fast_sincosf call at the first of them: one range reduction, the same floats. The argument
    is an SSA temporary or input, defined before the first, so computing the second value there
    changes nothing (a split kernel's parts read where each temporary is defined: now at the
    first)."""
    out: list = [If(s.cond, _pair_sincos(s.then), _pair_sincos(s.orelse), s.declare) if isinstance(s, If) else s
                 for s in stmts]
    for i, s in enumerate(out):
        first = _trig_of(s) if s is not None else None
        if first is None:
            continue
        for j in range(i + 1, len(out)):
            second = _trig_of(out[j]) if out[j] is not None else None
            if second is not None and second[1] == first[1] and second[0] != first[0]:
                sin, cos = (s.temp, out[j].temp) if first[0] == "sin" else (out[j].temp, s.temp)
                out[i] = SinCos(first[1], sin, cos)
                out[j] = None
                break
    return [s for s in out if s is not None]


def _place_writes_early(body: list, writes: list, in_place: dict | None = None):
    """Each output write moved to just after the top-level statement that defines the last
    temporary it reads (a write reading only inputs or literals: after the first statement);
    a write to an output of `in_place` ({output: input}, the same array) not before the last
    top-level statement reading the input's element it overwrites.
    Returns (body, the writes left for the end: none unless the body is empty)."""
    if not body:
        return body, writes
    in_place = in_place or {}
    def_top = {t: k for k, s in enumerate(body) for t in ir.defined(s)}
    last_read: dict = {}            # input element -> last top-level statement reading it
    for k, s in enumerate(body):
        for s2 in ir.all_statements([s]):
            for e in ir.exprs(s2):
                for x in ir.walk(e):
                    if isinstance(x, Elem) and x.arg in in_place.values():
                        last_read[x] = k
    at: dict[int, list] = {}
    for w in writes:
        after = [def_top[t] for t in ir.temps(w.expr)] + [0]
        if w.target.arg in in_place:
            after.append(last_read.get(Elem(in_place[w.target.arg], w.target.index), 0))
        at.setdefault(max(after), []).append(w)
    out = []
    for k, s in enumerate(body):
        out.append(s)
        out += at.get(k, [])
    return out, []


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
