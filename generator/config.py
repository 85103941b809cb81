"""Build configurations: a filter's defaults, a TOML file, and --set overrides, validated.

A config file:

    filter = "qcf"            # optional; must match the filter being generated
    preset = "faithful"       # optional: start from a named preset of the filter
    prefix = "att"            # C identifier prefix (default: the filter's name)
    precision = "float"       # or "double"
    [params]
    kp = 1.5

Every problem is a ConfigError whose message names the file, the parameter and what is
allowed; the CLI prints it on one line and exits with status 2.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from generator import filters
from generator.model import ConfigError

PRECISIONS = ("float", "double")
TOP_KEYS = {"filter", "prefix", "precision", "params", "preset"}


@dataclass
class BuildConfig:
    filter: str
    params: dict
    precision: str = "float"
    prefix: str = ""
    overrides: dict = field(default_factory=dict)   # what differs from the defaults

    @property
    def spec(self):
        return filters.load(self.filter)


def _check_prefix(prefix: str) -> str:
    if not prefix.isidentifier() or not prefix.isascii() or prefix.lower() != prefix:
        raise ConfigError(f"prefix {prefix!r} must be a lower-case C identifier (letters, digits, _)")
    return prefix


def resolve(filter_name: str, config_file: str | Path | None = None, sets: list[str] | None = None,
            precision: str | None = None, prefix: str | None = None, preset: str | None = None) -> BuildConfig:
    """Defaults, then a preset, then the config file's [params], then --set (last wins).
    `filter_name` is a name or a filter folder's path (generator.filters); the config keeps the name."""
    spec = filters.load(filter_name)
    filter_name = spec.name
    values = spec.defaults()
    overrides = {}
    file_prefix = file_precision = None
    file_data = _read_config(config_file) if config_file is not None else {}
    preset = preset or file_data.get("preset")
    if preset is not None:
        presets = spec.presets()
        if preset not in presets:
            raise ConfigError(f"unknown preset '{preset}' for filter {filter_name} "
                              f"(known: {', '.join(presets) or 'none'})")
        data = _read_config(presets[preset])
        for name, value in data.get("params", {}).items():
            values[name] = overrides[name] = _check(spec, name, value, f"preset {preset}")
    if config_file is not None:
        path = Path(config_file)
        data = file_data
        unknown = set(data) - TOP_KEYS
        if unknown:
            raise ConfigError(f"{path}: unknown key(s) {', '.join(sorted(unknown))}; allowed: {', '.join(sorted(TOP_KEYS))}")
        if "filter" in data and data["filter"] != filter_name:
            raise ConfigError(f"{path}: written for filter '{data['filter']}', not '{filter_name}'")
        file_prefix, file_precision = data.get("prefix"), data.get("precision")
        table = data.get("params", {})
        if not isinstance(table, dict):
            raise ConfigError(f"{path}: 'params' must be a table ([params])")
        for name, value in table.items():
            values[name] = overrides[name] = _check(spec, name, value, str(path))
    for item in sets or []:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected name=value")
        name, text = item.split("=", 1)
        name = name.strip()
        values[name] = overrides[name] = _check(spec, name, text.strip(), "--set")
    precision = precision or file_precision or "float"
    if precision not in PRECISIONS:
        raise ConfigError(f"precision {precision!r} must be one of {', '.join(PRECISIONS)}")
    prefix = _check_prefix(prefix or file_prefix or filter_name)
    return BuildConfig(filter_name, values, precision, prefix, overrides)


def _read_config(path) -> dict:
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"config file {path} is a directory") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: malformed TOML: {e}") from None


def _check(spec, name, value, source):
    if name not in spec.params:
        raise ConfigError(f"unknown parameter '{name}' for filter {spec.name} ({source}); "
                          f"known: {', '.join(sorted(spec.params))}")
    return spec.params[name].coerce(value, source)
