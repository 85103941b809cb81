"""Filter discovery: one folder per filter (defaults.toml, model.py, reference.py, step.c.j2)."""
from __future__ import annotations

import importlib
import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from generator.model import COMMON_PARAMS, ConfigError, Param, param_from_toml

HERE = Path(__file__).parent


@dataclass
class FilterSpec:
    name: str
    title: str
    source: str
    folder: Path
    params: dict[str, Param]     # every parameter, common input checks included

    def model_class(self):
        return importlib.import_module(f"generator.filters.{self.name}.model").Model

    def reference_class(self):
        return importlib.import_module(f"generator.filters.{self.name}.reference").Reference

    def presets(self) -> dict[str, Path]:
        """Named parameter sets in presets/<name>.toml (e.g. 'faithful': the source as published)."""
        d = self.folder / "presets"
        return {p.stem: p for p in sorted(d.glob("*.toml"))} if d.is_dir() else {}

    def defaults(self) -> dict:
        return {n: p.default for n, p in self.params.items()}

    def model(self, params: dict | None = None):
        values = self.defaults()
        values.update(params or {})
        return self.model_class()(values)

    def reference(self, params: dict | None = None):
        values = self.defaults()
        values.update(params or {})
        return self.reference_class()(values)


def names() -> list[str]:
    return sorted(p.name for p in HERE.iterdir()
                  if p.is_dir() and (p / "defaults.toml").exists() and (p / "model.py").exists())


@cache
def load(name: str) -> FilterSpec:
    if name not in names():
        raise ConfigError(f"unknown filter '{name}' (known: {', '.join(names())})")
    folder = HERE / name
    with open(folder / "defaults.toml", "rb") as fh:
        data = tomllib.load(fh)
    info = data.get("filter", {})
    sensors = info.get("sensors", ["accel", "mag", "gps"])
    params: dict[str, Param] = {}
    for key in [None, *sensors]:
        for p in COMMON_PARAMS.get(key, []):
            params[p.name] = Param(**vars(p))
    for pname, spec in data.get("params", {}).items():
        if pname in params:   # a filter may override a common parameter's default or bounds
            merged = {k: v for k, v in vars(params[pname]).items() if k != "name"}
            merged.update(spec)
            params[pname] = Param(name=pname, **merged)
        else:
            params[pname] = param_from_toml(pname, spec)
    for p in params.values():
        p.coerce(p.default, f"default in {name}/defaults.toml")
    return FilterSpec(name, info.get("title", name), info.get("source", ""), folder, params)
