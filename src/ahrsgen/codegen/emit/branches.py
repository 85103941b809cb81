"""Branches: a select whose sides cost more than a few operations becomes if/else."""
from __future__ import annotations

from ahrsgen.codegen.emit.ir import If, Let, Set, temps
from ahrsgen.codegen.emit.ops import _WEIGHT, CATEGORIES


def _exclusive(group, side, kept, idx, nodes, users, refs):
    """Temporaries computed only for `side` (1 = then, 2 = else) of the selects in `group`:
    every use of each lies on that side (CSE-shared work stays outside)."""
    sel = set(group)
    other = 3 - side
    # Work that reads a select of this group (a chain of selects on one condition) cannot go
    # inside the block: it would read the select before the block assigns it. Left outside,
    # it makes the group depend on itself and the group stays `?:` (see _emit_groups).
    reads_sel: set[str] = set()
    for t in kept[:max(idx[s] for s in group)]:
        if refs[t] & (sel | reads_sel):
            reads_sel.add(t)
    cond_refs = set()
    for g in group:
        cond_refs.update(temps(nodes[g]["sel"][0]))
    # Latest first, so that a temporary's users are decided before it: each is read only by
    # exclusive work or by selects of the group that take it as this side's value (and not as
    # the other's), e.g. cos|v| both returned by the else side and read by it.
    E: set[str] = set()
    for t in reversed(kept[:max(idx[s] for s in group)]):
        if t in sel or t in reads_sel or not users[t] or t in cond_refs:
            continue
        takes = {g for g in group if nodes[g]["sel"][side] == t and nodes[g]["sel"][other] != t}
        if users[t] <= E | takes:
            E.add(t)
    return E


def _layout(kept, nodes, writes, precision, min_cost):
    """Body statements (ir), the temporaries in emission order, and the branches.

    Selects on the same condition form a group; a group whose exclusive operations weigh
    at least `min_cost` is written as one if/else that computes only the taken side.
    Groups nest when all of a group's selects lie on one side of another. Selects are grouped
    by their condition (equal expressions; a named literal equals the plain one), which the
    if () shows."""
    idx = {t: i for i, t in enumerate(kept)}
    refs = {t: set(temps(nodes[t]["expr"])) for t in kept}
    users: dict[str, set] = {t: set() for t in kept}
    for t in kept:
        for r in refs[t]:
            users[r].add(t)
    for w in writes:
        for r in temps(w.expr):
            users[r].add("<out>")
    by_cond: dict[tuple, list] = {}
    for t in kept:
        if nodes[t]["sel"] is not None:       # keyed apart from temporaries: a condition may be one
            by_cond.setdefault((_IF, nodes[t]["sel"][0]), []).append(t)

    def cost(E):
        return sum(_WEIGHT[nodes[t]["cat"]] for t in E)

    groups = {}
    for cond, sels in by_cond.items():
        if min_cost is None:
            break
        ea, eb = (_exclusive(sels, side, kept, idx, nodes, users, refs) for side in (1, 2))
        if cost(ea) + cost(eb) >= min_cost:
            groups[cond] = (sels, ea, eb)

    while True:
        try:
            return _emit_groups(kept, idx, nodes, refs, groups)
        except _Cycle as c:        # this group cannot be placed as one block: keep it ?:
            del groups[c.cond]


_IF = "if"      # a group's key: (_IF, its condition), apart from any temporary


class _Cycle(Exception):
    def __init__(self, cond):
        self.cond = cond


def _emit_groups(kept, idx, nodes, refs, groups):
    import heapq
    # parent of each group: the (group, side) whose exclusive set holds all its selects
    parent = {}
    for c, (sels, _, _) in groups.items():
        best = None
        for d, (_, ea, eb) in groups.items():
            if d == c:
                continue
            for side, E in ((1, ea), (2, eb)):
                inside = [s in E for s in sels]
                if all(inside) and (best is None or len(E) < len(groups[best[0]][best[1]])):
                    best = (d, side)
                elif any(inside):
                    raise _Cycle(c)   # straddles a side: not a block of its own
        parent[c] = best
    emitted, branches = [], []

    def block(members, key) -> list:
        out = []
        here = [c for c in groups if parent[c] == key]
        inner = set()
        for c in here:
            inner |= groups[c][1] | groups[c][2]
        owner = {}
        items = {}
        for t in members:
            if t in inner:
                continue
            sel = nodes[t]["sel"]
            g = (_IF, sel[0]) if sel is not None and (_IF, sel[0]) in here else None
            owner[t] = g if g is not None else t
            items.setdefault(owner[t], idx[t])
            items[owner[t]] = min(items[owner[t]], idx[t])
        deps = {i: set() for i in items}
        for i in items:
            if i in groups:
                sels, ea, eb = groups[i]
                mem = set(sels) | ea | eb
            else:
                mem = {i}
            for t in mem:
                for r in refs[t]:
                    o = owner.get(r)
                    if o is not None and o != i and r not in mem:
                        deps[i].add(o)
        indeg = {i: len(d) for i, d in deps.items()}
        rdeps = {i: [] for i in items}
        for i, d in deps.items():
            for o in d:
                rdeps[o].append(i)
        order = {i: n for n, i in enumerate(items)}       # a tie-breaker that never compares keys
        ready = [(items[i], order[i], i) for i in items if indeg[i] == 0]
        heapq.heapify(ready)
        done = 0
        while ready:
            _, _, i = heapq.heappop(ready)
            done += 1
            if i in groups:
                sels, ea, eb = groups[i]
                emitted.extend(sels)
                branches.append({"condition": i[1], "then": _ops(ea, nodes), "else": _ops(eb, nodes)})
                then = block(sorted(ea, key=idx.get), (i, 1)) + [Set(s, nodes[s]["sel"][1]) for s in sels]
                orelse = block(sorted(eb, key=idx.get), (i, 2)) + [Set(s, nodes[s]["sel"][2]) for s in sels]
                out.append(If(i[1], then, orelse, list(sels)))
            else:
                n = nodes[i]
                out.append(Let(i, n["expr"], n["cat"], tuple(n.get("extra_ops", ()))))
                emitted.append(i)
            for j in rdeps[i]:
                indeg[j] -= 1
                if indeg[j] == 0:
                    heapq.heappush(ready, (items[j], order[j], j))
        if done != len(items):
            stuck = [i for i in items if indeg[i] > 0 and i in groups]
            raise _Cycle(stuck[0] if stuck else next(iter(here)))
        return out

    body = block(kept, None)
    return body, emitted, branches


def _ops(E, nodes) -> dict:
    ops = {c: 0 for c in CATEGORIES}
    for t in E:
        ops[nodes[t]["cat"]] += 1
    return {c: n for c, n in ops.items() if n}
