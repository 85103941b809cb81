"""The `ahrsgen` command: list, generate, validate (and more subcommands registered below).

Exit status: 0 success, 1 a check failed (validation disagreement), 2 bad usage or
configuration (one line naming the problem).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ahrsgen.argtypes import nonneg_int_arg, positive_float_arg
from ahrsgen.errors import ConfigError
from ahrsgen.fileio import add_force_option

EPILOG = """\
Conventions of every filter, log and output:
  frames      NED navigation frame, FRD body frame
  quaternion  Hamilton, scalar first [w, x, y, z], rotating body to NED (as PX4's
              vehicle_attitude.q)
  Euler       Z-Y-X: roll, pitch, yaw in rad, yaw in (-pi, pi]
  sensors     gyro rad/s; accelerometer as specific force in m/s^2 (level at rest reads
              [0, 0, -9.81]); magnetometer in any unit; GPS velocity NED in m/s
  dt          seconds covered by the step's gyro sample
Logs: CSV (docs/log-format.md) or PX4 ULog. Exit status: 0 ok, 1 a check failed,
2 bad usage, configuration, log or path (one line on stderr).
Outputs: never an input of the command; an existing file is replaced only if ahrsgen
wrote it, or with --force (docs/output-files.md).

Run 'ahrsgen COMMAND --help' for the options of each command."""


class _Formatter(argparse.HelpFormatter):
    """Help text wrapped at spaces only: a path or an option like --set=a-b stays whole, so it
    can be copied from the help."""

    def _split_lines(self, text, width):
        import textwrap
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False, break_long_words=False)


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one line on stderr (exit 2), like every other CLI error."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _add_build_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("filter", nargs="?", help="filter name (see 'ahrsgen list') or a filter folder's path; may be "
                                            "left out when the --config file names it (filter = \"...\")")
    p.add_argument("--config", metavar="FILE.toml", help="TOML file: prefix, precision and a [params] table")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[],
                   help="override one parameter (repeatable); wins over --config")
    p.add_argument("--preset", help="start from a named parameter set of the filter, e.g. 'faithful' "
                                    "(the source as published; see 'ahrsgen list FILTER')")
    p.add_argument("--precision", choices=["float", "double"], help="C floating-point type (default float)")
    p.add_argument("--prefix", help="C identifier prefix of the generated API (default: the filter name)")
    p.add_argument("--runtime", metavar="NAME,NAME", help="parameters read at run time (<prefix>_set_params) "
                                                          "instead of folded into the code; real-valued ones only")
    p.add_argument("--math", choices=["fast", "libm"],
                   help="float trigonometry: 'fast' = own helpers, no libm (default; errors in "
                        "src/ahrsgen/codegen/fastmath.py), 'libm' = sinf/cosf/atan2f...")
    p.add_argument("--fma", action="store_true", default=None,
                   help="write fused multiply-adds (fmaf) where a product feeds one sum: the emitter "
                        "chooses them, so host and target stay bit-identical")


def _resolve(args):
    from ahrsgen.generate import config
    if args.filter is None:
        args.filter = config.filter_of(args.config)
    return config.resolve(args.filter, args.config, args.set, args.precision, args.prefix, args.preset,
                          getattr(args, "runtime", None), getattr(args, "math", None), getattr(args, "fma", None))


def cmd_list(args) -> int:
    from ahrsgen import filters
    from ahrsgen.sim import scenarios
    names = [args.filter] if args.filter else filters.names()
    broken = 0
    for name in names:
        try:
            spec = filters.load(name)
        except ConfigError as e:
            if args.filter:
                raise
            # one bad folder on AHRSGEN_FILTER_PATH does not hide the others
            print(f"ahrsgen: warning: filter {name} left out: {e}", file=sys.stderr)
            broken += 1
            continue
        print(f"{name}: {spec.title}")
        print(f"  source: {spec.source}")
        if spec.origin != "built-in":
            print(f"  folder: {spec.folder} ({spec.origin})")
        width = max(len(n) for n in spec.params)
        for pname, p in spec.params.items():
            unit = f" [{p.unit}]" if p.unit else ""
            print(f"  {pname:<{width}}  default {p.default!r:<10} allowed {p.range_text()}{unit}")
            print(f"  {'':<{width}}  {p.doc}")
        for pname, path in spec.presets().items():
            import tomllib
            with open(path, "rb") as fh:
                vals = tomllib.load(fh).get("params", {})
            print(f"  preset '{pname}': " + ", ".join(f"{k}={v!r}" for k, v in vals.items()))
        print()
    if not args.filter:
        print("scenarios:")
        for s in scenarios.names():
            print(f"  {s:<26} {getattr(scenarios.module(s), 'DESCRIPTION', '')}")
    return 2 if broken else 0


def cmd_generate(args) -> int:
    from ahrsgen.generate import render
    from ahrsgen.fileio import check_output_dir, check_outputs
    out = check_output_dir(args.output, "-o")
    cfg = _resolve(args)
    for w in cfg.spec.model(cfg.params).stability_warnings():
        print(f"ahrsgen: warning: {cfg.filter}: {w}", file=sys.stderr)
    gen = render.render(cfg)
    if out.is_dir():                # files there are replaced only if ahrsgen wrote them
        check_outputs([("-o", out / name) for name in gen.files], [args.config, *filter_inputs(args.filter)],
                      args.force)
    paths = render.write(gen, out)
    for p in paths:
        print(p)
    paths_ops = gen.manifest["step_paths"]
    for name, info in paths_ops.items():
        print(f"  step path '{name}': {info['total']} ops ({', '.join(f'{k} {v}' for k, v in info['ops'].items() if v)})")
    print(f"  state struct: {gen.manifest['structs']['state']['size']} bytes")
    return 0


def filter_inputs(name) -> list:
    """The files a command reads to build a filter: its folder (model.py, reference.py, ...)."""
    from ahrsgen import filters
    return filters.input_folders(name)


def cmd_validate(args) -> int:
    import numpy as np
    from ahrsgen.sim import host, metrics, scenarios
    cfg = _resolve(args)
    args.scenario = args.scenario or cfg.spec.scenario     # the filter's own, as `target` uses
    try:
        opts = scenarios.parse_options(args.scenario, args.scenario_opt)
        log = scenarios.make(args.scenario, seed=args.seed, **opts)
    except KeyError as e:
        raise ConfigError(str(e.args[0])) from None
    except ConfigError:
        raise
    except ValueError as e:          # e.g. a duration shorter than one step
        raise ConfigError(f"scenario {args.scenario}: {e}") from None
    site = scenario_site_params(cfg, log)
    if site:
        from ahrsgen.generate import config as _config
        cfg = _config.resolve(args.filter, args.config, args.set, args.precision, args.prefix, args.preset,
                              args.runtime, getattr(args, "math", None), getattr(args, "fma", None), values=site)
        print("  site parameters from the scenario (override with --set): "
              + ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in site.items()))
    for w in cfg.spec.model(cfg.params).stability_warnings():
        print(f"ahrsgen: warning: {cfg.filter}: {w}", file=sys.stderr)
    bound = args.tolerance if args.tolerance is not None else (1e-9 if cfg.precision == "double" else 1e-3)
    print(f"validate {cfg.filter} ({cfg.precision}) on {args.scenario} seed {args.seed}: "
          f"{len(log)} steps, {log.t[-1] - log.t[0]:.1f} s")
    t0 = time.perf_counter()
    hf = host.build(cfg)
    t1 = time.perf_counter()
    c = hf.run(log)
    t2 = time.perf_counter()
    ref = cfg.spec.reference(cfg.params)
    # the reference works in body axes: the config's calibration and mounting applied in NumPy
    # (the C applies them itself, to the raw samples)
    r = host.run_reference(ref, cfg.frame.apply(log) if cfg.frame is not None else log, progress=sys.stderr.isatty())
    t3 = time.perf_counter()
    print(f"  compiled in {t1 - t0:.2f} s, C run {t2 - t1:.3f} s, NumPy reference {t3 - t2:.2f} s")
    diff = np.degrees(np.abs(metrics.wrap_deg_diff(c.rpy, r.rpy)))
    qdiff = metrics.max_angle_diff_rad(c.q, r.q)
    print(f"  C vs reference: max |d roll| {diff[:, 0].max():.3g} deg, |d pitch| {diff[:, 1].max():.3g} deg, "
          f"|d yaw| {diff[:, 2].max():.3g} deg; max attitude difference {qdiff:.3g} rad (bound {bound:g} rad)")
    same_status = bool(np.array_equal(c.status, r.status))
    print(f"  status codes identical: {'yes' if same_status else 'NO'}"
          f" (non-zero in {int(np.count_nonzero(c.status))} steps)")
    ok = qdiff <= bound and same_status
    from ahrsgen.bench.scoring import refusal_failure
    failed = refusal_failure(c.status, log, cfg.params, cfg.filter)
    if failed:                       # C and reference agree on doing nothing: not a PASS
        print(f"ahrsgen: validate failed: {failed}", file=sys.stderr)
        return 1
    if log.q_true is not None:
        s = metrics.euler_stats(c.q, log.q_true, log.t, log.settle_time)
        print(f"  accuracy vs truth after {log.settle_time:g} s (C {cfg.precision}), degrees:")
        print("           RMS   mean|e|   max|e|")
        for a in ("roll", "pitch", "yaw"):
            print(f"    {a:<5} {s[a]['rms']:7.3f} {s[a]['mean_abs']:8.3f} {s[a]['max_abs']:8.3f}")
    # A filter that draws random numbers (a particle filter) declares `random_state(stream)` on its
    # Model. Its float build follows the double reference only until rounding flips a resampling
    # decision; it is then judged as an estimator: the double C against the reference sample by
    # sample, and float vs double over several particle-noise streams (src/ahrsgen/sim/stochastic.py).
    # A deterministic filter can declare the same ([filter] rounding_sensitive, with the reason): the
    # pairs are then seeds of the scenario.
    model = cfg.spec.model(cfg.params)
    random = hasattr(model, "random_state")
    if (not ok and (random or cfg.spec.rounding_sensitive) and cfg.precision == "float" and args.tolerance is None
            and log.q_true is not None):
        import dataclasses
        from ahrsgen.sim import stochastic
        hf_d = host.build(dataclasses.replace(cfg, precision="double"))
        cd = hf_d.run(log)
        dd = metrics.max_angle_diff_rad(cd.q, r.q)
        d_same = bool(np.array_equal(cd.status, r.status))
        why = ("rounding flips a resampling decision" if random else
               f"the filter declares it rounding-sensitive: {cfg.spec.rounding_sensitive}")
        print(f"  float and reference part ways ({why}); judged as estimators:")
        print(f"  double C vs reference: max attitude difference {dd:.3g} rad (bound 1e-9 rad), status codes "
              f"identical: {'yes' if d_same else 'NO'}")
        if random:
            st = stochastic.float_vs_double(hf, hf_d, log, model)
            pairs = f"{st['streams']} particle-noise streams"
        else:
            seeds = [args.seed + k for k in range(1, stochastic.STREAMS + 1)]
            st = stochastic.float_vs_double_seeds(hf, hf_d, (scenarios.make(args.scenario, seed=k, **opts)
                                                             for k in seeds))
            pairs = f"{st['streams']} seeds of {args.scenario} ({seeds[0]}-{seeds[-1]})"
        print(f"  float vs double C over {pairs}, RMS vs truth (deg), paired "
              f"difference and t (pass |t| <= {st['t_crit']} or |mean| <= {st['floor_deg']:g} deg):")
        for a, v in st["angles"].items():
            print(f"    {a:<5} float {v['float_mean']:7.3f}  double {v['double_mean']:7.3f} +- {v['double_sd']:.3f}"
                  f"  diff {v['diff_mean']:+.4f} +- {v['diff_sd']:.4f}  t {v['t']:+.2f}  {'ok' if v['ok'] else 'FAIL'}")
        ok = dd <= 1e-9 and d_same and st["ok"]
    # Tell an unstable configuration (the equations themselves diverge: the reference leaves the
    # truth, and C and reference part because rounding differences grow) from a code-generation
    # error (the reference follows the truth, the C does not). A configuration the model warns
    # about whose reference leaves the truth fails as unstable even where C and reference happen
    # to stay together (a diverging estimate that holds its magnetometer off, say).
    unstable = model.stability_warnings()
    ref_lost = None
    if log.q_true is not None:
        late = log.t - log.t[0] >= log.settle_time
        ref_lost = metrics.max_angle_diff_rad(r.q[late], log.q_true[late]) if late.any() else None
    diverged = ref_lost is not None and (not np.isfinite(ref_lost) or np.degrees(ref_lost) > 60.0)
    if ok and not (unstable and diverged):
        print("PASS")
        return 0
    if diverged:
        why = f"; {unstable[0]}" if unstable else ""
        print(f"FAIL: unstable configuration, not a code-generation error: the NumPy reference itself leaves "
              f"the truth (max {np.degrees(ref_lost):.0f} deg after {log.settle_time:g} s)"
              + (", C with it" if ok else ", so C and reference part as rounding grows") + why)
        print(f"ahrsgen: validate failed: {cfg.filter} is unstable with these parameters"
              + (f": {unstable[0]}" if unstable else " (the reference diverges from the truth)"), file=sys.stderr)
        return 1
    print("FAIL: generated C disagrees with the reference" + (
        f" (the reference follows the truth: max {np.degrees(ref_lost):.1f} deg)" if ref_lost is not None else ""))
    return 1


def cmd_new(args) -> int:
    from ahrsgen import scaffold
    folder = scaffold.write(args.name, args.output)
    print(f"wrote {folder}/: defaults.toml, model.py, reference.py, step.c.j2, test_{args.name}.py")
    print(f"next: ahrsgen validate {folder}   (then edit model.py and reference.py: docs/your_own_filter.md)")
    return 0


def scenario_site_params(cfg, log) -> dict:
    """Site parameters a scenario knows (declination, inclination) that the user did not set,
    as the bench sets them (ahrsgen.bench.site_values): numbers, not text."""
    from ahrsgen.bench import site_values
    return site_values(cfg.filter, log.meta, set(cfg.overrides))[0]


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="ahrsgen", epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Generate fixed-size C for UAV attitude filters from CasADi equations, and check it.")
    from ahrsgen import __version__
    parser.add_argument("--version", action="version", version=f"ahrsgen {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("list", help="filters, their parameters (defaults, allowed ranges, meaning) and scenarios")
    p.add_argument("filter", nargs="?", help="only this filter (a name or a filter folder's path)")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("generate", help="write <prefix>.h, <prefix>.c and manifest.json for a filter",
                       description="Generate C for a filter with its parameters baked in.")
    _add_build_options(p)
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="output directory (created if needed); files in it are replaced only if ahrsgen wrote "
                        "them (docs/output-files.md)")
    add_force_option(p)
    p.set_defaults(func=cmd_generate)

    p = sub.add_parser("validate", help="generate, compile, run C and the NumPy reference on a scenario, compare",
                       description="Generate and compile a filter for the host, run it and its independent NumPy "
                                   "reference over a simulated scenario, print the largest difference and the "
                                   "accuracy against the truth. Exit 1 if C and reference disagree (said as an "
                                   "unstable configuration when the reference itself leaves the truth, else a "
                                   "code-generation error) or if the filter refused most steps. A float "
                                   "build of a particle filter, or of a filter that declares [filter] "
                                   "rounding_sensitive, that misses the bound is judged as an estimator: double "
                                   "C = reference, float vs double over 10 streams or seeds (paired t test).")
    _add_build_options(p)
    p.add_argument("--scenario", help="scenario name (see 'ahrsgen list'; default: the filter's own, the "
                                       "scenario of its source experiment: [filter] scenario in defaults.toml)")
    p.add_argument("--seed", type=nonneg_int_arg, default=0, help="scenario seed, a whole number >= 0 (default 0)")
    p.add_argument("--scenario-opt", metavar="NAME=VALUE", action="append", default=[],
                   help="scenario option, e.g. rate_hz=100 or duration=60 (repeatable)")
    p.add_argument("--tolerance", type=positive_float_arg, metavar="RAD",
                   help="largest allowed attitude difference (default 1e-9 rad double, 1e-3 rad float)")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("new", help="write a new filter folder (scaffold) that generates and validates as it is",
                       description="Write DIR/NAME/ with defaults.toml, model.py (CasADi), reference.py (NumPy), "
                                   "step.c.j2 and test_NAME.py: a small working filter whose comments explain the "
                                   "contract. Every command then takes the folder's path: 'ahrsgen validate DIR/NAME'.")
    p.add_argument("name", help="filter name: a lower-case C identifier (names the folder and prefixes the C API)")
    p.add_argument("-o", "--output", default=".", metavar="DIR", help="parent directory (default: the current one)")
    p.set_defaults(func=cmd_new)

    for register in _EXTRA_COMMANDS:
        register(sub)
    return parser


# Subcommands defined beside their verdicts (run and bench, target, harden, tune), registered by
# name: a broken import is a traceback here, never a subcommand that silently vanishes.
_EXTRA_COMMANDS: list = []


def _load_extra_commands() -> None:
    from ahrsgen import calibrate, tune
    from ahrsgen.check import harden
    from ahrsgen.cli import bench, target
    for reg in (bench.register_cli, target.register_cli, harden.register_cli, tune.register_cli,
                calibrate.register_cli):
        if reg not in _EXTRA_COMMANDS:
            _EXTRA_COMMANDS.append(reg)


def _filter_names(args) -> None:
    """Every command takes a filter folder's path where it takes a filter name: resolve it once
    here (ahrsgen.filters.load), so the command sees the filter's name."""
    from ahrsgen import filters
    if isinstance(getattr(args, "filter", None), str) and filters.is_path(args.filter) \
            and not (Path(args.filter) / "manifest.json").exists():      # harden takes a generated dir
        args.filter = filters.load(args.filter).name
    if getattr(args, "filters", None):
        args.filters = [filters.load(f).name for f in args.filters]


# Options whose values start with '-' (argparse would take '-O2' for an option): '--opt -O2' is
# passed on as '--opt=-O2', so the command works as the README and --help write it.
_DASH_VALUE_OPTIONS = ("--opt",)


def _join_dash_values(argv: list[str]) -> list[str]:
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a in _DASH_VALUE_OPTIONS and i + 1 < len(argv) and argv[i + 1].startswith("-O"):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


# Ctrl-C seen during this command. A terminal's Ctrl-C reaches the whole process group: a
# compiler or a lock the command was waiting on can fail from the same signal and surface as an
# ordinary error (exit 2) before, or instead of, the KeyboardInterrupt; the flag says which it was.
_INTERRUPTED = [False]


def _on_sigint(signum, frame):
    _INTERRUPTED[0] = True
    raise KeyboardInterrupt


def main(argv=None) -> int:
    import signal
    import threading
    _INTERRUPTED[0] = False
    prev = None
    if threading.current_thread() is threading.main_thread():
        prev = signal.getsignal(signal.SIGINT)
        if prev is signal.default_int_handler:        # (an ignored SIGINT stays ignored)
            signal.signal(signal.SIGINT, _on_sigint)
    try:
        return _main(argv)
    except KeyboardInterrupt:        # Ctrl-C anywhere, also while the commands import
        print("ahrsgen: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:          # `ahrsgen list | head -1`: the reader has all it wanted
        _quiet_stdout()
        return 0
    finally:
        if prev is signal.default_int_handler:
            signal.signal(signal.SIGINT, prev)


def _user_filter_frame(exc: BaseException):
    """The innermost traceback frame in a filter folder outside the package (a user's model.py,
    reference.py, ...), or None when the error is ahrsgen's own (then the traceback stands)."""
    import traceback
    from ahrsgen import paths
    for frame in reversed(traceback.extract_tb(exc.__traceback__)):
        p = Path(frame.filename).resolve()
        if (p.parent / "defaults.toml").is_file() and paths.PACKAGE_ROOT not in p.parents:
            return frame
    return None


def _quiet_stdout() -> None:
    """After a broken pipe, point stdout at /dev/null so the interpreter's final flush does not
    raise again (the Python documentation's recipe for SIGPIPE)."""
    import os
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _main(argv=None) -> int:
    _load_extra_commands()
    parser = build_parser()
    args = parser.parse_args(_join_dash_values(sys.argv[1:] if argv is None else list(argv)))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        _filter_names(args)
        rc = args.func(args)
    except Exception as e:
        if _INTERRUPTED[0]:          # an error the same Ctrl-C caused (a compiler, a lock): interrupted
            raise KeyboardInterrupt from None
        return _report(e)
    if rc and _INTERRUPTED[0]:       # a failure the command reported itself, from the same Ctrl-C
        raise KeyboardInterrupt
    return rc


def _report(e: Exception) -> int:
    """Exit 2 and one line for an error the user can fix; anything else is raised again."""
    if isinstance(e, ConfigError):
        print(f"ahrsgen: error: {e}", file=sys.stderr)
        return 2
    if isinstance(e, BrokenPipeError):
        raise e                      # a closed pipe is a normal end (main)
    if isinstance(e, OSError):       # a path the system refused: one line, not a traceback
        where = f" {e.filename}" if e.filename else ""
        print(f"ahrsgen: error: cannot access{where}: {e.strerror or e}", file=sys.stderr)
        return 2
    frame = _user_filter_frame(e)    # an error in a user's filter folder: its file and line, one line
    if frame is None:
        raise e
    print(f"ahrsgen: error: {frame.filename}:{frame.lineno}: {type(e).__name__}: {e}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
