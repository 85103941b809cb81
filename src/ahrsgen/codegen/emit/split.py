"""A long kernel cut into part functions called in turn (bounded -O0 frames)."""
from __future__ import annotations

import re

from ahrsgen.codegen.emit.ops import _TMP_RE

_WORD = re.compile(r"\b[A-Za-z_]\w*\b")


def _split(name, precision, inputs, body, writes, tops, size, ctx_decl=None, bools=frozenset(), outputs=()):
    """Cut the top-level statements into parts of about `size` temporaries; each part is a
    static function that reads the kernel inputs it uses and the values earlier parts
    exported, and exports what later parts and the outputs read. The exported values live in
    one array `carry` in the kernel's frame; a slot is reused once the value in it is dead (its
    last reader is an earlier part, or the part writing the new value: a part writes its
    exports after all its reads), so the frame holds the values live at once, not every value
    ever handed over. A part whose statements store outputs (emit's early_writes) takes those
    outputs as parameters. Returns the kernel's body and the parts' sources (temporaries as t<N>).
    A bool temporary travels in a second array, `flags` (bool), with slots reused the same way."""
    chunks, cur, count = [], [], 0
    for item in tops:
        if cur and count + len(item[2]) > size:
            chunks.append(cur)
            cur, count = [], 0
        cur.append(item)
        count += len(item[2])
    if cur:
        chunks.append(cur)
    texts = [[ln for a, b, _ in ch for ln in body[a:b]] for ch in chunks]
    defs = [[t for _, _, d in ch for t in d] for ch in chunks]
    used = [set(_TMP_RE.findall("\n".join(tx))) for tx in texts]
    used_out = set(_TMP_RE.findall("\n".join(writes)))
    exports = []
    for k, d in enumerate(defs):
        later = set().union(*used[k + 1:]) | used_out
        exports.append([t for t in d if t in later])
    # slots: the last part reading each exported value (len(chunks): an output reads it)
    last = {t: max([j for j in range(k + 1, len(chunks)) if t in used[j]] + [len(chunks) if t in used_out else -1])
            for k, ex in enumerate(exports) for t in ex}
    def array_of(t):            # the array a handed value travels in
        return "flags" if t in bools else "carry"
    slot, pool = {}, {}
    for kind in ("carry", "flags"):
        holder, free, pool[kind] = {}, [], 0
        for k, ex in enumerate(exports):
            for s, t in list(holder.items()):
                if last[t] <= k:
                    free.append(s)
                    del holder[s]
            free.sort()
            for t in ex:
                if array_of(t) != kind:
                    continue
                if free:
                    s = free.pop(0)
                else:
                    s, pool[kind] = pool[kind], pool[kind] + 1
                slot[t], holder[s] = s, t
    producer = {t: k for k, ex in enumerate(exports) for t in ex}
    real = precision
    array_type = {"carry": real, "flags": "bool"}

    def carried(t):
        return f"{array_of(t)}[{slot[t]}]"
    parts = []
    held = [a for a in ("carry", "flags") if pool[a]]
    call_lines = [f"/* {len(chunks)} parts called in turn (inlined when optimising): bounded -O0 frames; "
                  f"{' and '.join(held)} {'hold' if len(held) > 1 else 'holds'} the values handed between "
                  f"them (a slot reused once its value is dead) */"]
    call_lines += [f"{array_type[a]} {a}[{pool[a]}];" for a in held]
    for k, tx in enumerate(texts):
        text = "\n".join(tx)
        words = set(_WORD.findall(text))
        ins = [a for a in inputs if a.expr is None and a.name in words]
        ctx = ctx_decl is not None and any(a.expr is not None and a.expr in text for a in inputs)
        imported = {t: carried(t) for t in used[k] if t in producer and producer[t] < k}
        outs = [a for a in outputs if re.search(rf"^\*?{a.name}\b", text, re.M)]
        params = ([ctx_decl] if ctx else []) + [a.param(real) for a in ins] + [
            (f"{'bool' if a.flag else real} *{a.name}" if a.scalar else f"{'bool' if a.flag else real} {a.name}[{a.size}]")
            for a in outs]
        arrays = []
        for a in ("carry", "flags"):
            writes_a = any(array_of(t) == a for t in exports[k])
            reads_a = any(array_of(t) == a for t in imported)
            if writes_a or reads_a:
                params.append(f"{'' if writes_a else 'const '}{array_type[a]} {a}[{pool[a]}]")
                arrays.append(a)
        lines = [_TMP_RE.sub(lambda m: imported.get(m.group(0), m.group(0)), ln) for ln in tx]
        lines += [f"{carried(t)} = {t};" for t in exports[k]]
        pname = f"{name}_part{k}"
        parts.append(f"static void {pname}({', '.join(params)})\n{{\n" + "\n".join("    " + ln for ln in lines) + "\n}")
        args = ([_WORD.findall(ctx_decl)[-1]] if ctx else []) + [a.name for a in ins] + [a.name for a in outs] + arrays
        call_lines.append(f"{pname}({', '.join(args)});")
    out = [_TMP_RE.sub(lambda m: carried(m.group(0)), w) for w in writes]
    return call_lines + out, parts
