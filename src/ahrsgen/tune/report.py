"""What a tune prints and the config it writes."""
from __future__ import annotations

import json
import os
from pathlib import Path

from ahrsgen.errors import ConfigError
from ahrsgen.fileio import write_text_atomic
from ahrsgen.tune.score import PENALTY_DEG
from ahrsgen.tune.study import _fmt

def print_report(rep, out):
    unit = f"{rep['metric']} (deg, mean over logs)"
    print(f"  current  {_fmt(rep['current'])}", file=out)
    print(f"  tuned    {_fmt(rep['tuned'])}", file=out)
    print(f"  {unit}:        current   tuned", file=out)
    print(f"    training ({len(rep['logs'])} logs)   {rep['train']['current']:9.3f} {rep['train']['tuned']:7.3f}",
          file=out)
    if rep["cv"]:
        cv = rep["cv"]
        print(f"    {cv['folds']}-fold cross-validated {cv['current']:9.3f} {cv['tuned']:7.3f}"
              "   (each log scored with values tuned without it)", file=out)
    w = max(len(x) for x in rep["logs"])
    for lbl in rep["logs"]:
        line = f"    {lbl:<{w}} current {rep['train']['per_log_current'][lbl]:7.3f}  tuned {rep['train']['per_log_tuned'][lbl]:7.3f}"
        if rep["cv"]:
            line += f"  held out {rep['cv']['per_log_held_out'][lbl]:7.3f}"
        print(line, file=out)
    print(f"  {rep['trials_run']} trial(s) run in {rep['seconds']:.1f} s", file=out)
    for e in rep["errors"][:5]:
        print(f"  run error (scored {PENALTY_DEG:g} deg): {e}", file=out)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    return json.dumps(str(v))


def filter_ref_for(spec, config_path) -> str:
    """How a config at config_path names the filter so that it resolves again: a built-in by its
    name, a folder by its path relative to the config's own folder (config.config_filter_ref)."""
    if spec.origin == "built-in":
        return spec.name
    return Path(os.path.relpath(spec.folder.resolve(), Path(config_path).resolve().parent)).as_posix()


def write_toml(path, rep, base) -> None:
    """A config `ahrsgen generate --config` takes: the tuned values and the --config/--set ones."""
    lines = ["# written by ahrsgen tune (a later tune may replace this file)",
             f"# ahrsgen tune {rep['filter']}: {', '.join(rep['search'])} on {len(rep['logs'])} log(s), "
             f"{rep['budget']} trials, {rep['metric']}",
             f"# training error: current {rep['train']['current']:.3f} deg, tuned {rep['train']['tuned']:.3f} deg"]
    if rep["cv"]:
        lines.append(f"# {rep['cv']['folds']}-fold cross-validated error: current {rep['cv']['current']:.3f} deg, "
                     f"tuned {rep['cv']['tuned']:.3f} deg")
    lines.append("# site parameters (declination, ...) were set per log and are not written here: set yours.")
    lines.append(f'filter = "{filter_ref_for(base.spec, path)}"')
    lines.append("")
    lines.append("[params]")
    for k, v in rep["overrides"].items():
        lines.append(f"{k} = {_toml_value(v)}")
    path = Path(path)
    if path.parent and not path.parent.is_dir():
        raise ConfigError(f"-o {path}: folder {path.parent} does not exist")
    write_text_atomic(path, "\n".join(lines) + "\n")
