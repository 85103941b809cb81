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
    """Element `index` of a split kernel's local array `array` (carry or flags); `name`: the
    temporary it hands over, written beside a read of it, `carry[7] /* tmp11 */`."""
    array: str
    index: int
    name: str | None = field(default=None, compare=False)


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
    storage: str = "static "       # what precedes `void`: static, static inline, an attribute

    def prototype(self, storage: str | None = None) -> str:
        """The declaration, continued on lines indented by 4 after a comma where it is too long
        (the storage's own lines, e.g. an attribute, stay as they are)."""
        *above, last = (self.storage if storage is None else storage).split("\n")
        words = _call_words(f"{last}void {self.name}", [p.c() for p in self.params], "")
        return "\n".join(above + fill(words, "", WIDTH, "    "))

    def lines(self, names: bool = True, indent: str = "") -> list[str]:
        return [f"{indent}(void){n};" for n in self.unused] + print_statements(self.body, indent, names)

    def source(self, storage: str | None = None, indent: str = "    ") -> str:
        return "\n".join([self.prototype(storage), "{"] + self.lines(indent=indent) + ["}"])


# ------------------------------------------------------------------ the printer
# C precedence (higher binds tighter) of the binary operators the emitter writes.
_PREC = {"*": 13, "/": 13, "+": 12, "-": 12, "<": 10, "<=": 10, ">": 10, ">=": 10, "==": 9, "!=": 9,
         "&&": 5, "||": 4}


# Lines the printer writes stay within this many columns (DESIGN.md); a longer statement
# continues on lines indented by CONTINUATION more than it, broken between words.
WIDTH = 100
CONTINUATION = "        "


def print_expr(e, names: bool = True) -> str:
    """C text of an expression; names=False leaves the names out (folded parameters', named
    constants' and the temporaries a split kernel's slots hand over)."""
    return " ".join(_words(e, names))


def _words(e, names) -> list[str]:
    """The expression's text as words: joined by single spaces they are its C text, and a line
    may break at any of those spaces (a literal's name comment is one word)."""
    if isinstance(e, Temp):
        return [e.name]
    if isinstance(e, Elem):
        return [e.arg if e.index is None else f"{e.arg}[{e.index}]"]
    if isinstance(e, Ctx):
        return [e.text]
    if isinstance(e, Lit):
        return [f"{e.text} /* {e.name} */" if names and e.name else e.text]
    if isinstance(e, Slot):
        return [f"{e.array}[{e.index}] /* {e.name} */" if names and e.name else f"{e.array}[{e.index}]"]
    if isinstance(e, Call):
        out = []
        for n, a in enumerate(e.args):
            w = _words(a, names)
            w[-1] += "," if n < len(e.args) - 1 else ")"
            out += w
        out[0] = f"{e.fn}(" + out[0]
        return out
    if isinstance(e, Cast):
        return _prefix(f"({e.ctype})", _paren(e.arg, names))
    if isinstance(e, Select):
        side = lambda x: _paren(x, names) if isinstance(x, Select) else _words(x, names)  # noqa: E731
        return _wrap_in(_words(e.cond, names)) + ["?"] + side(e.a) + [":"] + side(e.b)
    if isinstance(e, Op):
        if e.op == "neg":
            return _prefix("-", _operand(e.args[0], 99, False, names))
        if e.op == "!":
            return _prefix("!", _wrap_in(_words(e.args[0], names)))
        a, b = e.args
        if e.op in ("&&", "||"):
            return _paren(a, names) + [e.op] + _paren(b, names)
        p = _PREC[e.op]
        return _operand(a, p, False, names) + [e.op] + _operand(b, p, True, names)
    raise TypeError(f"not an expression: {e!r}")


def _prefix(text: str, words: list[str]) -> list[str]:
    return [text + words[0]] + words[1:]


def _wrap_in(words: list[str]) -> list[str]:
    """The words in parentheses."""
    out = list(words)
    out[0] = "(" + out[0]
    out[-1] = out[-1] + ")"
    return out


def _paren(e, names) -> list[str]:
    w = _words(e, names)
    return w if isinstance(e, ATOMS + (Call,)) else _wrap_in(w)


def _operand(x, p, right, names) -> list[str]:
    if isinstance(x, Op) and x.op not in ("neg", "!"):
        q = _PREC[x.op]
        if q < p or (right and q == p):
            return _wrap_in(_words(x, names))
    elif isinstance(x, (Select, Op)):
        return _wrap_in(_words(x, names))
    return _words(x, names)


def fill(words: list[str], indent: str, width: int = WIDTH, more: str = CONTINUATION) -> list[str]:
    """The words joined by spaces into lines of at most `width` columns (a word longer than a
    line stands alone): the first line indented by `indent`, the rest by indent + more."""
    lines, cur = [], indent + words[0]
    for w in words[1:]:
        if len(cur) + 1 + len(w) > width:
            lines.append(cur)
            cur = indent + more + w
        else:
            cur += " " + w
    return lines + [cur]


def _target(t) -> str:
    if isinstance(t, Elem) and t.index is None:
        return f"*{t.arg}"
    return print_expr(t, False)


def _call_words(fn: str, args: list[str], end: str) -> list[str]:
    """`fn(a, b, ...)` + end as words, broken after each comma."""
    if not args:
        return [f"{fn}(){end}"]
    words = [a + "," for a in args[:-1]] + [args[-1] + ")" + end]
    return _prefix(fn + "(", words)


def print_statements(stmts, indent: str = "", names: bool = True, width: int = WIDTH) -> list[str]:
    out = []

    def put(words, ind=indent):
        out.extend(fill(words, ind, width))
    for s in stmts:
        if isinstance(s, Let):
            put([f"const {s.temp.ctype} {s.temp.name} ="] + _words(s.expr, names)[:-1]
                + [_words(s.expr, names)[-1] + ";"])
        elif isinstance(s, Set):
            w = _words(s.expr, names)
            put([f"{s.temp.name} ="] + w[:-1] + [w[-1] + ";"])
        elif isinstance(s, If):
            out += [f"{indent}{t.ctype} {t.name};" for t in s.declare]
            put(_prefix("if ", _wrap_in(_words(s.cond, names)))[:-1] + [_wrap_in(_words(s.cond, names))[-1] + " {"]
                if len(_words(s.cond, names)) > 1 else [f"if ({_words(s.cond, names)[0]}) {{"])
            out += print_statements(s.then, indent + "    ", names, width)
            out.append(f"{indent}}} else {{")
            out += print_statements(s.orelse, indent + "    ", names, width)
            out.append(f"{indent}}}")
        elif isinstance(s, Store):
            w = _words(s.expr, names)
            put([f"{_target(s.target)} ="] + w[:-1] + [w[-1] + ";"])
        elif isinstance(s, SinCos):
            out += [f"{indent}{s.sin.ctype} {s.sin.name};", f"{indent}{s.cos.ctype} {s.cos.name};"]
            put(_call_words(s.fn, [print_expr(s.arg, names), f"&{s.sin.name}", f"&{s.cos.name}"], ";")
                + ["  /* sin and cos, one reduction */"])
        elif isinstance(s, Unused):
            out.append(f"{indent}(void){s.name};")
        elif isinstance(s, Local):
            out.append(f"{indent}{s.ctype} {s.array}[{s.size}];")
        elif isinstance(s, PartCall):
            put(_call_words(s.part, list(s.args), ";"))
        elif isinstance(s, Comment):
            out += comment(s.text, indent, width)
        else:
            raise TypeError(f"not a statement: {s!r}")
    return out


def comment(text: str, indent: str = "", width: int = WIDTH) -> list[str]:
    """A C comment of the text: `/* text */` on one line if it fits, else wrapped in a block."""
    one = f"{indent}/* {text} */"
    if len(one) <= width:
        return [one]
    return [f"{indent}/*"] + fill(text.split(), indent + " * ", width, "") + [f"{indent} */"]


def with_comment(code: str, text: str, width: int = WIDTH) -> str:
    """`code /* text */` within `width` columns: a long comment continues on lines aligned
    under its first word (the header's parameter, status and field lines)."""
    one = f"{code} /* {text} */"
    if len(one) <= width:
        return one
    lead = code + " /* "
    if len(lead) > width - 30:          # little room beside the code: the comment above it
        return "\n".join(comment(text, _indent_of(code), width) + [code])
    lines = fill(text.split(), "", width - len(lead), "")
    lines[-1] += " */"
    if len(lines[-1]) > width - len(lead):
        lines[-1] = lines[-1][:-3]
        lines.append("*/")
    return "\n".join([lead + lines[0]] + [" " * len(lead) + ln for ln in lines[1:]])


def _indent_of(code: str) -> str:
    return code[:len(code) - len(code.lstrip())]


def define(name: str, items: list[str], sep: str = " |", width: int = WIDTH) -> str:
    """`#define name (a | b | ...)` within `width` columns, continued with backslashes."""
    words = [it + sep for it in items[:-1]] + [items[-1] + ")"] if items else [")"]
    words[0] = "(" + words[0]
    lines = fill([f"#define {name}"] + words, "", width - 2, "    ")
    return " \\\n".join(lines)
