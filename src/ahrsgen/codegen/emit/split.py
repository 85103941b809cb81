"""A long kernel cut into part functions called in turn (bounded -O0 frames)."""
from __future__ import annotations

from ahrsgen.codegen.emit import ir
from ahrsgen.codegen.emit.ir import Comment, Ctx, Elem, Local, Param, PartCall, Slot, Store


def _split(name, precision, inputs, body, writes, size, ctx=None, bools=frozenset(), outputs=()):
    """Cut the top-level statements into parts of about `size` temporaries; each part is a
    static function that reads the kernel inputs it uses and the values earlier parts
    exported, and exports what later parts and the outputs read. The exported values live in
    one array `carry` in the kernel's frame; a slot is reused once the value in it is dead (its
    last reader is an earlier part, or the part writing the new value: a part writes its
    exports after all its reads), so the frame holds the values live at once, not every value
    ever handed over. A part whose statements store outputs (emit's early_writes) takes those
    outputs as parameters. ctx: the context pointer's Param, if the kernel reads one. Returns
    the kernel's body and its parts (ir.Function). A bool temporary travels in a second array,
    `flags` (bool), with slots reused the same way. A slot read names the temporary it hands
    over, `carry[7] /* tmp11 */`, so the code reads as the kernel's comment (its branch
    conditions) and the unsplit kernel do."""
    chunks, cur, count = [], [], 0
    for s in body:
        n = len(ir.defined(s))
        if cur and count + n > size:
            chunks.append(cur)
            cur, count = [], 0
        cur.append(s)
        count += n
    if cur:
        chunks.append(cur)
    defs = [[t for s in ch for t in ir.defined(s)] for ch in chunks]
    used = [set(ir.reads(ch)) for ch in chunks]
    used_out = set(ir.reads(writes))
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
    array_type = {"carry": precision, "flags": "bool"}

    def carried(t):             # a read of it names the temporary (the store reads `slot = tmp`)
        return Slot(array_of(t), slot[t], t.name)
    parts = []
    held = [a for a in ("carry", "flags") if pool[a]]
    calls = [Comment(f"{len(chunks)} parts called in turn (inlined when optimising): bounded -O0 frames; "
                     f"{' and '.join(held)} {'hold' if len(held) > 1 else 'holds'} the values handed between "
                     f"them (a slot reused once its value is dead)")]
    calls += [Local(array_type[a], a, pool[a]) for a in held]
    for k, ch in enumerate(chunks):
        read = {x for s in ir.all_statements(ch) for e in ir.exprs(s) for x in ir.walk(e) if isinstance(x, (Elem, Ctx))}
        read_args = {x.arg for x in read}
        stored = {s.target.arg for s in ir.all_statements(ch) if isinstance(s, Store) and isinstance(s.target, Elem)}
        ins = [a for a in inputs if a.expr is None and a.name in read_args]
        uses_ctx = ctx is not None and any(isinstance(x, Ctx) for x in read)
        imported = {t: carried(t) for t in used[k] if t in producer and producer[t] < k}
        stmts = ir.map_exprs(ch, lambda e: ir.substitute(e, imported))
        stmts += [Store(carried(t), t) for t in exports[k]]
        params = ([ctx] if uses_ctx else []) + [a.as_param(precision) for a in ins] + [
            a.as_param(precision, output=True) for a in outputs if a.name in stored]
        for a in ("carry", "flags"):
            writes_a = any(array_of(t) == a for t in exports[k])
            reads_a = any(array_of(t) == a for t in imported)
            if writes_a or reads_a:
                params.append(Param(a, array_type[a], pool[a], const=not writes_a))
        pname = f"{name}_part{k}"
        parts.append(ir.Function(pname, params, stmts))
        calls.append(PartCall(pname, [p.name for p in params]))
    out = ir.map_exprs(writes, lambda e: ir.substitute(e, {t: carried(t) for t in used_out}))
    return calls + out, parts
