"""Static analysis of the generated C: cppcheck, and for emitted kernels too long for it, the
same questions answered exactly on the kernel's statements (kernel_structure_issues)."""
from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

from ahrsgen.check.layout import BUILD, load_manifest

CPPCHECK = os.environ.get("AHRSGEN_CPPCHECK", "cppcheck")

# Checks asked of cppcheck; every suppression must carry a written reason (none needed so far).
CPPCHECK_ARGS = ["--enable=warning,style,performance,portability", "--std=c99", "--error-exitcode=1",
                 "--inline-suppr", "--quiet", "-U__cplusplus",
                 "--template={file}:{line}: {severity} [{id}] {message}"]
CPPCHECK_SUPPRESSIONS: dict[str, str] = {}   # id -> reason


def build_kernels(man: dict) -> list:
    """The kernel objects (ahrsgen.codegen.emit.Kernel) of a generated build, emitted again
    from its manifest: filter, parameters, precision, prefix, math, fma, runtime parameters."""
    from ahrsgen.generate import config, render
    runtime = [r["name"] for r in man.get("runtime_params", [])]
    cfg = config.resolve(man["filter"], precision=man["precision"], prefix=man["prefix"], math=man["math"],
                         fma=man["fma"], runtime=runtime, values=man["params"])
    return render.render(cfg).kernels


def emitted_functions(text: str, kernels: list) -> tuple[list[dict], list[str]]:
    """Where each C function of the kernels (a split kernel's parts, then itself) lies in a
    generated source: its printed text (ir's printer) found as it is. Returns ([{name, function (ir.Function), lines (body lines), span}], issues: a function
    the source does not hold as the kernels print it)."""
    found, issues = [], []
    for k in kernels:
        for f in k.functions():
            code = f.source()
            at = text.find(code)
            if at < 0:
                issues.append(f"{f.name}: not in the source as its manifest's configuration emits it")
                continue
            found.append({"name": f.name, "function": f, "kernel": k, "lines": len(f.lines()),
                          "span": (at, at + len(code))})
    return found, issues


def kernel_issues(k) -> list[str]:
    """kernel_structure_issues of every function of a kernel; a split kernel's parts may each
    write some of its output elements (emit's early_writes), so across the parts and the
    kernel every output element is written exactly once."""
    issues, written = [], {}
    for f in k.functions():
        got, w = _structure(f, partial=bool(k.parts))
        issues += got
        for key, n in w.items():
            written[key] = written.get(key, 0) + n
    for p in k.function().params:
        if p.output:
            for i in range(p.size or 1):
                if written.get((p.name, i), 0) != 1:
                    issues.append(f"{k.name}: output {p.name}[{i}] written {written.get((p.name, i), 0)} times")
    return issues


def kernel_structure_issues(f, partial: bool = False) -> list[str]:
    """What cppcheck looks for in emitted code, checked exactly on the kernel's statements
    (ahrsgen.codegen.emit.ir.Function): every indexed access within the declared size of its
    array, inputs only read, every temporary defined once before use (a temporary defined inside
    a branch is visible only there; a select an If declares must be set exactly once on each
    side, and is defined after it), every output element written exactly once. A split
    kernel's own local arrays (carry, and flags for its bools) are bounded by their declarations
    and filled by its parts (each part is checked as a function of its own; a part writes only
    the slots of its exports, each at most once). partial: the function is one part of a
    kernel, writing each output element at most once (kernel_issues checks the whole)."""
    return _structure(f, partial)[0]


def _structure(f, partial: bool) -> tuple[list[str], dict]:
    from ahrsgen.codegen.emit import ir
    issues, written = [], {}
    params = {p.name: p for p in f.params}
    arrays = {p.name: p.size for p in f.params if p.size is not None}
    for name in f.unused:
        if name not in params:
            issues.append(f"{f.name}: (void) of unknown name {name}")
    scopes = [set()]            # temporaries defined, innermost scope last
    pending: set = set()        # selects declared by the enclosing Ifs and not yet defined

    def visible(t):
        return any(t in sc for sc in scopes)

    def check_expr(e, where):
        for x in ir.walk(e):
            if isinstance(x, ir.Elem):
                p = params.get(x.arg)
                if p is None:
                    issues.append(f"{where}: {x.arg} is not a parameter")
                elif (x.index is None) != (p.size is None):
                    issues.append(f"{where}: {x.arg} read unlike its declaration")
                elif x.index is not None and not 0 <= x.index < p.size:
                    issues.append(f"{where}: {x.arg}[{x.index}] out of bounds (size {p.size})")
            elif isinstance(x, ir.Slot):
                if x.array not in arrays:
                    issues.append(f"{where}: {x.array}[{x.index}] is not an array")
                elif not 0 <= x.index < arrays[x.array]:
                    issues.append(f"{where}: {x.array}[{x.index}] out of bounds (size {arrays[x.array]})")
            elif isinstance(x, ir.Ctx):
                if not any(p.pointer and p.const and p.size is None for p in f.params):
                    issues.append(f"{where}: {x.text} read without a context parameter")
            elif isinstance(x, ir.Temp) and not visible(x):
                issues.append(f"{where}: {x.name} used before it is defined")

    def define(t, where):
        if visible(t) or t in pending:
            issues.append(f"{where}: {t.name} defined twice")
        scopes[-1].add(t)

    def run(stmts, path, selects) -> set:
        """Check a statement list; returns the selects (of `selects`, the enclosing If's) it sets."""
        done = set()
        for n, s in enumerate(stmts, 1):
            where = f"{f.name} statement {path}{n}"
            if isinstance(s, ir.Let):
                check_expr(s.expr, where)
                define(s.temp, where)
            elif isinstance(s, ir.SinCos):
                check_expr(s.arg, where)
                define(s.sin, where)
                define(s.cos, where)
            elif isinstance(s, ir.If):
                check_expr(s.cond, where)
                for t in s.declare:
                    if visible(t) or t in pending:
                        issues.append(f"{where}: {t.name} defined twice")
                pending.update(s.declare)
                sides = []
                for side, block in (("then", s.then), ("else", s.orelse)):
                    scopes.append(set())
                    sides.append(run(block, f"{path}{n}.{side}.", set(s.declare)))
                    scopes.pop()
                if sides[0] != sides[1]:
                    issues.append(f"{where}: the sides set different selects: "
                                  f"{sorted(t.name for t in sides[0] ^ sides[1])}")
                for t in s.declare:
                    pending.discard(t)
                    if t in sides[0] and t in sides[1]:
                        scopes[-1].add(t)
                    else:
                        issues.append(f"{where}: {t.name} declared but not set on both sides")
            elif isinstance(s, ir.Set):
                check_expr(s.expr, where)
                if s.temp not in selects:
                    issues.append(f"{where}: {s.temp.name} set outside its branch or not declared")
                elif s.temp in done:
                    issues.append(f"{where}: {s.temp.name} set twice on one side")
                done.add(s.temp)
            elif isinstance(s, ir.Store):
                check_expr(s.expr, where)
                t = s.target
                name, i = (t.array, t.index) if isinstance(t, ir.Slot) else (t.arg, t.index or 0)
                p = params.get(name)
                if isinstance(t, ir.Slot) and name in arrays and (p is None or not p.const):
                    if not 0 <= i < arrays[name]:
                        issues.append(f"{where}: {name}[{i}] out of bounds (size {arrays[name]})")
                elif p is None or not p.output:
                    issues.append(f"{where}: writes {name}, which is not an output parameter")
                    continue
                elif (t.index is None) != (p.size is None) or (p.size is not None and not 0 <= i < p.size):
                    issues.append(f"{where}: {name}[{i}] out of bounds")
                written[(name, i)] = written.get((name, i), 0) + 1
            elif isinstance(s, ir.Local):
                arrays[s.array] = s.size
            elif isinstance(s, ir.PartCall):
                for a in s.args:
                    if a not in params and a not in arrays:
                        issues.append(f"{where}: {a} passed to {s.part} is neither a parameter nor a local array")
            elif not isinstance(s, ir.Comment):
                issues.append(f"{where}: not an emitted statement: {s!r}")
        return done

    run(f.body, "", set())
    for p in f.params:
        if not p.output:
            continue
        for i in range(p.size or 1):
            c = written.get((p.name, i), 0)
            if c != 1 and not ((partial or p.name in ("carry", "flags")) and c == 0):
                issues.append(f"{f.name}: output {p.name}[{i}] written {c} times")
    return issues, written


def _stub(f) -> str:
    """The function with a body that only touches its parameters (cppcheck sees the call sites)."""
    body = []
    for p in f.params:
        if not p.output:
            body.append(f"    (void){p.name};")
        elif p.size is None:
            body.append(f"    *{p.name} = 0;")
        else:
            body.append(f"    for (int i = 0; i < {p.size}; i++) {{\n        {p.name}[i] = 0;\n    }}")
    return f.prototype() + "\n{\n" + "\n".join(body) + "\n}"


def run_cppcheck(gen_dir: str | Path, max_kernel_lines: int | None = None, timeout: float | None = None) -> dict:
    """cppcheck the generated source (CPPCHECK_ARGS). cppcheck's value-flow analysis grows
    steeply with function length (a 3270-line emitted kernel takes it over ten minutes), so with
    max_kernel_lines the emitted kernels longer than that are checked by kernel_structure_issues
    instead (bounds, definitions, outputs - exactly, for straight-line code) and replaced by a stub
    for cppcheck; the rest of the file (template, step partial, helpers, shorter kernels) is
    analysed by cppcheck as usual. Without it the whole file goes to cppcheck."""
    gen_dir = Path(gen_dir)
    man = load_manifest(gen_dir)
    src = gen_dir / man["files"]["source"]
    text = src.read_text()
    target, structural, stubbed = src, [], []
    tmpdir = None
    if max_kernel_lines is not None:
        found, structural = emitted_functions(text, build_kernels(man))
        pieces, last, checked = [], 0, []
        for k in sorted(found, key=lambda k: k["span"]):
            if k["lines"] > max_kernel_lines:
                if not any(k["kernel"] is c for c in checked):
                    structural += kernel_issues(k["kernel"])
                    checked.append(k["kernel"])
                stubbed.append(f"{k['name']} ({k['lines']} lines)")
                pieces += [text[last:k["span"][0]], _stub(k["function"])]
                last = k["span"][1]
        if stubbed:
            pieces.append(text[last:])
            tmpdir = BUILD / "cppcheck" / f"{man['prefix']}-{os.getpid()}"
            tmpdir.mkdir(parents=True, exist_ok=True)
            target = tmpdir / src.name
            target.write_text("".join(pieces))
    supp = [f"--suppress={k}" for k in CPPCHECK_SUPPRESSIONS]
    cmd = [CPPCHECK, *CPPCHECK_ARGS, *supp, f"-I{gen_dir}", str(target)]
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        rc, err, timed_out = r.returncode, r.stderr, False
    except subprocess.TimeoutExpired:
        rc, err, timed_out = None, "", True
    finally:
        if tmpdir is not None:
            shutil.rmtree(tmpdir, ignore_errors=True)
    issues = [ln for ln in err.splitlines() if ln.strip() and "missingInclude" not in ln]
    return {"filter": man["filter"], "ok": (not timed_out and rc == 0 and not issues and not structural),
            "timed_out": timed_out, "timeout_s": timeout, "returncode": rc, "issues": issues,
            "structural_issues": structural, "structurally_checked": stubbed,
            "command": " ".join(cmd), "wall_s": round(time.perf_counter() - t0, 2),
            "suppressed": CPPCHECK_SUPPRESSIONS}
