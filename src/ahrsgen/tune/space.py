"""The search space: --params entries -> dimensions inside the parameters' declared ranges."""
from __future__ import annotations

from dataclasses import dataclass, field

from ahrsgen.errors import ConfigError

@dataclass
class Dim:
    name: str
    kind: str                   # "float" | "int" | "cat"
    low: float = 0.0
    high: float = 0.0
    log: bool = False
    choices: list = field(default_factory=list)

    def distribution(self):
        import optuna.distributions as d
        if self.kind == "float":
            return d.FloatDistribution(self.low, self.high, log=self.log)
        if self.kind == "int":
            return d.IntDistribution(int(self.low), int(self.high), log=self.log)
        return d.CategoricalDistribution(self.choices)

    def contains(self, v) -> bool:
        return v in self.choices if self.kind == "cat" else self.low <= v <= self.high

    def text(self) -> str:
        if self.kind == "cat":
            return "{" + ", ".join(map(str, self.choices)) + "}"
        return f"[{self.low:g}, {self.high:g}]{' log' if self.log else ''}"


def _open_low(p, hi):
    """Lower search bound of a positive range that is open at or below 0."""
    lo = hi * 1e-4
    if isinstance(p.default, (int, float)) and not isinstance(p.default, bool) and p.default > 0:
        lo = min(lo, p.default / 10)
    return lo


def search_space(spec, items: list[str]) -> list[Dim]:
    """--params entries 'name' or 'name=lo:hi' -> dimensions inside the declared ranges."""
    dims = []
    for item in items:
        name, eq, rng = item.partition("=")
        name = name.strip()
        if name not in spec.params:
            raise ConfigError(f"--params: unknown parameter '{name}' for filter {spec.name}; "
                              f"known: {', '.join(sorted(spec.params))}")
        if any(d.name == name for d in dims):
            raise ConfigError(f"--params: '{name}' given twice")
        p = spec.params[name]
        if p.type == "bool":
            dims.append(Dim(name, "cat", choices=[False, True]))
            continue
        if p.type == "str":
            if not p.choices:
                raise ConfigError(f"--params: '{name}' is free text, nothing to search")
            dims.append(Dim(name, "cat", choices=list(p.choices)))
            continue
        if eq:
            lo_t, colon, hi_t = rng.partition(":")
            if not colon:
                raise ConfigError(f"--params {item!r}: expected {name}=LOW:HIGH")
            lo = p.coerce(lo_t, f"--params {name} lower bound")
            hi = p.coerce(hi_t, f"--params {name} upper bound")
            if not lo < hi:
                raise ConfigError(f"--params {item!r}: LOW must be below HIGH")
        else:
            lo, hi = p.min, p.max
            positive = not isinstance(p.default, bool) and p.default > 0
            if hi is None and positive and (lo is None or lo >= 0):
                hi = p.default * 100           # no upper bound: two decades above the default
                lo = p.default / 100 if lo is None else lo
            if lo is None or hi is None:
                raise ConfigError(f"--params: '{name}' has an unbounded range {p.range_text()}; "
                                  f"give one as {name}=LOW:HIGH")
            if p.max_exclusive and hi == p.max:
                hi = hi - abs(hi) * 1e-9 if p.type == "float" else hi - 1
            if lo == 0 < hi and p.type == "float":
                lo = _open_low(p, hi)
            elif p.min_exclusive:
                lo = lo + abs(lo) * 1e-9 + (1e-12 if lo == 0 else 0.0) if p.type == "float" else lo + 1
        log = lo > 0 and hi / lo >= 100
        dims.append(Dim(name, "int" if p.type == "int" else "float", float(lo), float(hi), log))
    if not dims:
        raise ConfigError("--params: name at least one parameter to tune")
    return dims


def set_text(name, value) -> str:
    """name=value as --set takes it."""
    if isinstance(value, bool):
        return f"{name}={'true' if value else 'false'}"
    if isinstance(value, float):
        return f"{name}={value!r}"
    return f"{name}={value}"
