"""Finding filters: one folder per filter (defaults.toml, model.py, reference.py, step.c.j2),
wherever the folder lives. Every command resolves a filter through `load` (a name or a path).

A filter is found by name in three places, all treated alike:
  built-in              the folders of src/ahrsgen/filters/
  AHRSGEN_FILTER_PATH   directories (os.pathsep-separated) holding filter folders, or filter
                        folders themselves
  entry points          group `ahrsgen.filters` of installed packages: `NAME = "pkg.module"`,
                        the (importable) package whose folder is the filter folder
or given as a path to its folder (any argument with a '/' in it, or '.'), e.g.
`ahrsgen validate ./examples/madgwick`; the folder's name is the filter's name. A name that two
places define is an error naming both. The model and reference are imported as modules of the
filter's package (a built-in's or an entry point's own, else one made for the folder), so a
filter folder may import its own helper modules relatively (`from . import helpers`).
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.machinery
import importlib.util
import os
import sys
import tomllib
from dataclasses import dataclass
from functools import cache
from importlib import metadata
from pathlib import Path

from ahrsgen.codegen.model import COMMON_PARAMS, Param, param_from_toml
from ahrsgen.errors import ConfigError

HERE = Path(__file__).parent
PATH_ENV = "AHRSGEN_FILTER_PATH"
ENTRY_POINT_GROUP = "ahrsgen.filters"
FOLDER_FILES = ("defaults.toml", "model.py", "reference.py", "step.c.j2")
# defaults.toml [filter] keys
FILTER_KEYS = {
    "title": "one line",
    "source": "paper, report or notes",
    "sensors": 'aiding sensors the step reads, of "accel", "mag", "gps"',
    "scenario": "scenario of the source experiment: what `ahrsgen target` runs by default",
    "stochastic": "set (to the reason) for a filter whose run is random by design (a particle filter): "
                  "`ahrsgen target` then judges a real-libm run by accuracy, not trajectory",
    "rounding_sensitive": "set (to the reason) for a deterministic filter whose float run parts from the double "
                          "reference by more than rounding (fixed-size normalised-gradient steps, for one): "
                          "`ahrsgen validate` then judges a float build that misses its bound as an estimator, "
                          "float vs double over 10 seeds of the scenario",
    "init": "how the filter initialises (what init sets, which step sets the attitude); printed in the "
            "header, {prefix} stands for the C prefix",
}


@dataclass(frozen=True)
class Location:
    name: str
    folder: Path
    origin: str                  # where it was found, for messages
    package: str | None = None   # importable package of the folder (None: one is made for it)


@dataclass
class FilterSpec:
    name: str
    title: str
    source: str
    folder: Path
    params: dict[str, Param]     # every parameter, common input checks included
    package: str                 # the module package model.py and reference.py are imported from
    origin: str = "built-in"
    scenario: str = "fixedwing_gps"  # the source experiment's scenario ([filter] scenario)
    stochastic: str = ""             # why its runs are random by design, if they are ([filter] stochastic)
    init: str = ""                     # how the filter initialises ([filter] init), for the header
    rounding_sensitive: str = ""       # why its float run parts from double, if it does ([filter] rounding_sensitive)

    def model_class(self):
        return importlib.import_module(f"{self.package}.model").Model

    def reference_class(self):
        return importlib.import_module(f"{self.package}.reference").Reference

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


def is_filter_folder(path: Path) -> bool:
    return (path / "defaults.toml").is_file() and (path / "model.py").is_file()


def _same(a: Path, b: Path) -> bool:
    return a.resolve() == b.resolve()


# Filters given by path in this process: later look-ups by name (a BuildConfig keeps the name)
# find them too.
_BY_PATH: dict[str, Location] = {}
_BROKEN: dict[str, str] = {}      # entry points that do not resolve: name -> why


def _found(given_paths: bool = True) -> dict[str, list[Location]]:
    """Every definition of every name, in the order: built-in, search path, entry points, and
    (given_paths) folders given by path earlier in this process."""
    out: dict[str, list[Location]] = {}

    def add(loc: Location) -> None:
        seen = out.setdefault(loc.name, [])
        if not any(_same(x.folder, loc.folder) for x in seen):
            seen.append(loc)

    for p in sorted(HERE.iterdir()):
        if p.is_dir() and is_filter_folder(p):
            add(Location(p.name, p, "built-in", f"ahrsgen.filters.{p.name}"))
    for entry in filter(None, os.environ.get(PATH_ENV, "").split(os.pathsep)):
        d = Path(entry).expanduser().resolve()
        if is_filter_folder(d):
            add(Location(d.name, d, f"{PATH_ENV} entry {entry}"))
        elif d.is_dir():
            for p in sorted(d.iterdir()):
                if p.is_dir() and is_filter_folder(p):
                    add(Location(p.name, p, f"{PATH_ENV} entry {entry}"))
    for ep in _entry_points(tuple(sys.path)):
        where = f"entry point '{ep.name} = {ep.value}' ({ENTRY_POINT_GROUP})"
        try:
            spec = importlib.util.find_spec(ep.value)
        except (ImportError, ValueError):
            spec = None
        if spec is None or not spec.submodule_search_locations:
            # a broken package must not break the other filters: the error comes when it is asked for
            _BROKEN[ep.name] = f"{where}: '{ep.value}' is not an importable package (a filter folder)"
            continue
        add(Location(ep.name, Path(list(spec.submodule_search_locations)[0]), where, ep.value))
    for loc in _BY_PATH.values() if given_paths else ():
        add(loc)
    return out


@cache
def _entry_points(path: tuple) -> tuple:
    """The group's entry points (scanning every installed distribution takes ~20 ms: once per
    sys.path)."""
    return tuple(metadata.entry_points(group=ENTRY_POINT_GROUP))


def names() -> list[str]:
    """The filters known by name: built-in, AHRSGEN_FILTER_PATH, entry points (not folders
    given by path, though those resolve by name once given)."""
    return sorted(_found(given_paths=False))


def known(name: str) -> Location | None:
    """Where a name is defined (built-in, search path, entry point), if it is."""
    locs = _found(given_paths=False).get(name)
    return locs[0] if locs else None


def is_path(ref: str) -> bool:
    """A filter argument is a folder path when it has a '/' in it (or is '.' or '..')."""
    return "/" in ref or os.sep in ref or ref in (".", "..")


def _locate(ref: str) -> Location:
    ref = str(ref)
    if is_path(ref):
        folder = Path(ref).expanduser()
        if not folder.is_dir():
            raise ConfigError(f"filter folder {ref} does not exist")
        folder = folder.resolve()
        if not is_filter_folder(folder):
            missing = [f for f in FOLDER_FILES if not (folder / f).exists()]
            raise ConfigError(f"{ref} is not a filter folder (missing {', '.join(missing)}; "
                              f"'ahrsgen new NAME -o DIR' writes one)")
        loc = Location(folder.name, folder, f"path {ref}")
        known = _found().get(folder.name, [])
        others = [x for x in known if not _same(x.folder, folder)]
        if others:
            raise ConfigError(_twice(folder.name, [loc, others[0]]))
        if known:                 # the folder of a filter known by name: the same filter
            return known[0]
        _BY_PATH[folder.name] = loc
        return loc
    found = _found()
    if ref not in found and ref in _BROKEN:
        raise ConfigError(_BROKEN[ref])
    if ref not in found:
        raise ConfigError(f"unknown filter '{ref}' (known: {', '.join(names())}; "
                          f"or give a filter folder's path, e.g. ./{ref})")
    if len(found[ref]) > 1:
        raise ConfigError(_twice(ref, found[ref]))
    return found[ref][0]


def _twice(name: str, locs: list[Location]) -> str:
    a, b = locs[:2]
    return (f"filter '{name}' is defined twice: {a.folder} ({a.origin}) and {b.folder} ({b.origin}); "
            f"rename or remove one")


def load(ref: str) -> FilterSpec:
    """The filter a name or a folder path refers to (ConfigError if unknown or ambiguous)."""
    return _load(_locate(ref))


@cache
def _load(loc: Location) -> FilterSpec:
    name, folder = loc.name, loc.folder
    try:
        with open(folder / "defaults.toml", "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{folder / 'defaults.toml'}: malformed TOML: {e}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{folder / 'defaults.toml'}: not UTF-8 text (byte {e.start})") from None
    info = data.get("filter", {})
    unknown = set(info) - set(FILTER_KEYS)
    if unknown:
        raise ConfigError(f"{folder / 'defaults.toml'}: unknown [filter] key(s) {', '.join(sorted(unknown))}; "
                          f"allowed: {', '.join(FILTER_KEYS)}")
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
    package = loc.package or _folder_package(name, folder)
    return FilterSpec(name, info.get("title", name), info.get("source", ""), folder, params, package, loc.origin,
                      info.get("scenario", "fixedwing_gps"), info.get("stochastic", ""), info.get("init", ""),
                      info.get("rounding_sensitive", ""))


def _folder_package(name: str, folder: Path) -> str:
    """Make the folder importable as a package of its own (unique per folder), so model.py and
    reference.py import as <package>.model / <package>.reference and may import siblings."""
    package = f"ahrsgen_filter_{name}_{hashlib.sha256(str(folder).encode()).hexdigest()[:8]}"
    if package not in sys.modules:
        init = folder / "__init__.py"
        if init.exists():
            spec = importlib.util.spec_from_file_location(package, init, submodule_search_locations=[str(folder)])
        else:
            spec = importlib.machinery.ModuleSpec(package, None, is_package=True)
            spec.submodule_search_locations = [str(folder)]
        module = importlib.util.module_from_spec(spec)
        sys.modules[package] = module
        if spec.loader is not None:
            spec.loader.exec_module(module)
    return package


def input_folders(name) -> list:
    """The folders a command reads to build a filter (its model.py, reference.py, ...): what an
    output must never replace (ahrsgen.fileio.check_outputs). Empty for no or an unknown filter."""
    if not name:
        return []
    try:
        return [load(name).folder]
    except ConfigError:
        return []
