"""A kernel as data: expressions, statements and parameters, and the one printer that writes
them as C.

Every reader of a kernel (the renderer, harden's structure check, the operation counts, the
runtime-parameter calls) reads these objects; none parses the printed C back.

Expressions are trees: Temp (a temporary, named when the kernel is finished), Elem (an
element of an argument), Ctx (a scalar read through the kernel's context pointer), Lit (a
literal, with the folded parameter it stands for), Slot (a value handed between the parts of
a split kernel), Op (an operator), Call (a function call), Cast, Select (`c ? a : b`).
Statements: Let (`const T tmp = e;`), If (with the selects it declares and Sets on both
sides), Store (an output element or a slot), SinCos, Unused (`(void)x;`), Local (an array),
PartCall, Comment.
"""
from __future__ import annotations

from dataclasses import dataclass, field


# ------------------------------------------------------------------ expressions
@dataclass(eq=False)
class Temp:
    """A temporary: identity is the object; `name` is given when the kernel is finished."""
    ctype: str
    name: str = ""


@dataclass(frozen=True)
class Elem:
    """Element `index` of argument `arg` (index None: a scalar argument)."""
    arg: str
    index: int | None = None


@dataclass(frozen=True)
class Ctx:
    """A scalar input `arg` read through the context pointer, as the C expression `text`."""
    arg: str
    text: str


@dataclass(frozen=True)
class Lit:
    """A literal: its C text and value; `name` is the folded expression it stands for."""
    text: str
    value: float | None = None
    name: str | None = field(default=None, compare=False)


@dataclass(frozen=True)
class Slot:
    """Element `index` of a split kernel's local array `array` (carry or flags)."""
    array: str
    index: int


@dataclass(frozen=True)
class Op:
    """An operator: binary (+ - * / < <= > == != && ||) or unary ("neg", "!")."""
    op: str
    args: tuple


@dataclass(frozen=True)
class Call:
    fn: str
    args: tuple


@dataclass(frozen=True)
class Cast:
    ctype: str
    arg: object


@dataclass(frozen=True)
class Select:
    cond: object
    a: object
    b: object


ATOMS = (Temp, Elem, Ctx, Lit, Slot)


def children(e) -> tuple:
    if isinstance(e, (Op, Call)):
        return e.args
    if isinstance(e, Cast):
        return (e.arg,)
    if isinstance(e, Select):
        return (e.cond, e.a, e.b)
    return ()


def walk(e):
    """Every node of an expression tree, root first."""
    stack = [e]
    while stack:
        x = stack.pop()
        yield x
        stack.extend(reversed(children(x)))


def temps(e) -> list[Temp]:
    return [x for x in walk(e) if isinstance(x, Temp)]


def substitute(e, mapping: dict):
    """The expression with each node found in `mapping` (by identity for temporaries)
    replaced by its value."""
    if isinstance(e, Temp):
        return mapping.get(e, e)
    if isinstance(e, Op):
        return Op(e.op, tuple(substitute(a, mapping) for a in e.args))
    if isinstance(e, Call):
        return Call(e.fn, tuple(substitute(a, mapping) for a in e.args))
    if isinstance(e, Cast):
        return Cast(e.ctype, substitute(e.arg, mapping))
    if isinstance(e, Select):
        return Select(substitute(e.cond, mapping), substitute(e.a, mapping), substitute(e.b, mapping))
    return e


# ------------------------------------------------------------------ statements
@dataclass
class Let:
    temp: Temp
    expr: object
    cat: str                       # cost category (ops.CATEGORIES)
    extra: tuple = ()              # further categories it counts (a fused multiply-add: add)


@dataclass
class Set:
    temp: Temp
    expr: object


@dataclass
class If:
    """`T s; ... if (cond) { then } else { orelse }`: the selects `declare` (each counted as
    one cmp) are declared before the if and set once on each side (Set)."""
    cond: object
    then: list
    orelse: list
    declare: list = field(default_factory=list)


@dataclass
class Store:
    target: object                 # Elem of an output, or Slot
    expr: object


@dataclass
class SinCos:
    """sin and cos of one argument by one fast_sincosf call (one range reduction)."""
    arg: object
    sin: Temp
    cos: Temp
    fn: str = "fast_sincosf"


@dataclass
class Unused:
    name: str


@dataclass
class Local:
    ctype: str
    array: str
    size: int


@dataclass
class PartCall:
    part: str
    args: list


@dataclass
class Comment:
    text: str


def blocks(s) -> list[list]:
    """The statement lists nested in a statement."""
    return [s.then, s.orelse] if isinstance(s, If) else []


def exprs(s) -> list:
    """The expressions a statement reads."""
    if isinstance(s, (Let, Set)):
        return [s.expr]
    if isinstance(s, Store):
        return [s.expr]
    if isinstance(s, If):
        return [s.cond]
    if isinstance(s, SinCos):
        return [s.arg]
    return []


def all_statements(stmts):
    """Every statement, nested ones included, in order."""
    for s in stmts:
        yield s
        for b in blocks(s):
            yield from all_statements(b)


def defined(s) -> list[Temp]:
    """The temporaries a statement (and the statements nested in it) define."""
    out = []
    for x in all_statements([s]):
        if isinstance(x, Let):
            out.append(x.temp)
        elif isinstance(x, If):
            out += x.declare
        elif isinstance(x, SinCos):
            out += [x.sin, x.cos]
    return out


def reads(stmts) -> list[Temp]:
    """The temporaries read anywhere in the statements."""
    return [t for s in all_statements(stmts) for e in exprs(s) for t in temps(e)]


def map_exprs(stmts, fn) -> list:
    """The statements with fn applied to each expression they read."""
    out = []
    for s in stmts:
        if isinstance(s, Let):
            out.append(Let(s.temp, fn(s.expr), s.cat, s.extra))
        elif isinstance(s, Set):
            out.append(Set(s.temp, fn(s.expr)))
        elif isinstance(s, Store):
            out.append(Store(s.target, fn(s.expr)))
        elif isinstance(s, If):
            out.append(If(fn(s.cond), map_exprs(s.then, fn), map_exprs(s.orelse, fn), s.declare))
        elif isinstance(s, SinCos):
            out.append(SinCos(fn(s.arg), s.sin, s.cos, s.fn))
        else:
            out.append(s)
    return out


# ------------------------------------------------------------------ parameters
@dataclass
class Param:
    """A parameter of a kernel or part: an array (size), a pointer to one value, or a value."""
    name: str
    ctype: str
    size: int | None = None
    pointer: bool = False
    const: bool = False
    restrict: bool = False

    @property
    def output(self) -> bool:
        return not self.const and (self.size is not None or self.pointer)

    def c(self) -> str:
        r = "restrict " if self.restrict else ""
        c = "const " if self.const else ""
        if self.size is not None:
            return f"{c}{self.ctype} {self.name}[{r}{self.size}]"
        if self.pointer:
            return f"{c}{self.ctype} *{r}{self.name}"
        return f"{self.ctype} {self.name}"


@dataclass
class Function:
    """One C function of a kernel: the kernel itself or one of its parts."""
    name: str
    params: list[Param]
    body: list
    unused: list[str] = field(default_factory=list)

    def prototype(self, storage: str = "static ") -> str:
        return f"{storage}void {self.name}({', '.join(p.c() for p in self.params)})"

    def lines(self, names: bool = True) -> list[str]:
        return [f"(void){n};" for n in self.unused] + print_statements(self.body, "", names)

    def source(self, storage: str = "static ", indent: str = "    ") -> str:
        return "\n".join([self.prototype(storage), "{"] + [indent + ln for ln in self.lines()] + ["}"])


# ------------------------------------------------------------------ the printer
# C precedence (higher binds tighter) of the binary operators the emitter writes.
_PREC = {"*": 13, "/": 13, "+": 12, "-": 12, "<": 10, "<=": 10, ">": 10, ">=": 10, "==": 9, "!=": 9,
         "&&": 5, "||": 4}


def print_expr(e, names: bool = True) -> str:
    """C text of an expression; names=False leaves folded parameters' names out."""
    return _expr(e, names)


def _paren(e, names) -> str:
    return _expr(e, names) if isinstance(e, ATOMS + (Call,)) else f"({_expr(e, names)})"


def _expr(e, names) -> str:
    if isinstance(e, Temp):
        return e.name
    if isinstance(e, Elem):
        return e.arg if e.index is None else f"{e.arg}[{e.index}]"
    if isinstance(e, Ctx):
        return e.text
    if isinstance(e, Lit):
        return f"{e.text} /* {e.name} */" if names and e.name else e.text
    if isinstance(e, Slot):
        return f"{e.array}[{e.index}]"
    if isinstance(e, Call):
        return f"{e.fn}({', '.join(_expr(a, names) for a in e.args)})"
    if isinstance(e, Cast):
        return f"({e.ctype}){_paren(e.arg, names)}"
    if isinstance(e, Select):
        side = lambda x: _paren(x, names) if isinstance(x, Select) else _expr(x, names)  # noqa: E731
        return f"({_expr(e.cond, names)}) ? {side(e.a)} : {side(e.b)}"
    if isinstance(e, Op):
        if e.op == "neg":
            return "-" + _operand(e.args[0], 99, False, names)
        if e.op == "!":
            return f"!({_expr(e.args[0], names)})"
        a, b = e.args
        if e.op in ("&&", "||"):
            return f"{_paren(a, names)} {e.op} {_paren(b, names)}"
        p = _PREC[e.op]
        return f"{_operand(a, p, False, names)} {e.op} {_operand(b, p, True, names)}"
    raise TypeError(f"not an expression: {e!r}")


def _operand(x, p, right, names) -> str:
    if isinstance(x, Op) and x.op not in ("neg", "!"):
        q = _PREC[x.op]
        if q < p or (right and q == p):
            return f"({_expr(x, names)})"
    elif isinstance(x, (Select, Op)):
        return f"({_expr(x, names)})"
    return _expr(x, names)


def _target(t) -> str:
    if isinstance(t, Elem) and t.index is None:
        return f"*{t.arg}"
    return _expr(t, False)


def print_statements(stmts, indent: str = "", names: bool = True) -> list[str]:
    out = []
    for s in stmts:
        if isinstance(s, Let):
            out.append(f"{indent}const {s.temp.ctype} {s.temp.name} = {_expr(s.expr, names)};")
        elif isinstance(s, Set):
            out.append(f"{indent}{s.temp.name} = {_expr(s.expr, names)};")
        elif isinstance(s, If):
            out += [f"{indent}{t.ctype} {t.name};" for t in s.declare]
            out.append(f"{indent}if ({_expr(s.cond, names)}) {{")
            out += print_statements(s.then, indent + "    ", names)
            out.append(f"{indent}}} else {{")
            out += print_statements(s.orelse, indent + "    ", names)
            out.append(f"{indent}}}")
        elif isinstance(s, Store):
            out.append(f"{indent}{_target(s.target)} = {_expr(s.expr, names)};")
        elif isinstance(s, SinCos):
            a = _expr(s.arg, names)
            out += [f"{indent}{s.sin.ctype} {s.sin.name};", f"{indent}{s.cos.ctype} {s.cos.name};",
                    f"{indent}{s.fn}({a}, &{s.sin.name}, &{s.cos.name});   /* sin and cos, one reduction */"]
        elif isinstance(s, Unused):
            out.append(f"{indent}(void){s.name};")
        elif isinstance(s, Local):
            out.append(f"{indent}{s.ctype} {s.array}[{s.size}];")
        elif isinstance(s, PartCall):
            out.append(f"{indent}{s.part}({', '.join(s.args)});")
        elif isinstance(s, Comment):
            out.append(f"{indent}/* {s.text} */")
        else:
            raise TypeError(f"not a statement: {s!r}")
    return out
