"""The `run` and `bench` subcommands (src/ahrsgen/cli/__init__.py calls register_cli(subparsers))."""
from __future__ import annotations

import sys
from pathlib import Path

from ahrsgen.sim import host, peers, readers
from ahrsgen.generate import config
from ahrsgen.bench.common import PEER_NAMES
from ahrsgen.bench.grid import bench
from ahrsgen.bench.harness import build_log_runner, write_harness_log
from ahrsgen.bench.run import run_on_log


# =========================================================================================
# CLI registration (src/ahrsgen/cli/__init__.py calls register_cli(subparsers))

PLOT_FORMATS = (".png", ".pdf", ".svg")


def _cmd_run(args) -> int:
    from ahrsgen.fileio import check_outputs
    from ahrsgen.cli import filter_inputs
    from ahrsgen.errors import ConfigError
    # everything that could fail after a long run is checked first
    check_outputs((("--csv", args.csv), ("--plot", args.plot), ("--export-log", args.export_log)),
                  [args.log, args.config, *filter_inputs(args.filter)], args.force)
    if args.plot:
        if not Path(args.plot).suffix.lower() in PLOT_FORMATS:
            raise ConfigError(f"--plot {args.plot}: name the image .png, .pdf or .svg")
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise ConfigError("--plot needs matplotlib: pip install 'ahrsgen[dev]'") from None
    # a CSV log longer than one chunk is read a chunk at a time (bounded memory), unless the
    # whole log is needed at once (--exe, --export-log)
    lower = str(args.log).lower()
    chunked = (lower.endswith((".csv", ".csv.gz")) and not (args.exe or args.export_log)
               and Path(args.log).is_file() and Path(args.log).stat().st_size > readers.chunks.BLOCK_BYTES)
    try:
        log = readers.CsvChunks(args.log) if chunked else readers.read_log(args.log)
    except FileNotFoundError:
        raise ConfigError(f"log file {args.log} does not exist") from None
    except (readers.LogError, OSError) as e:
        raise ConfigError(str(e) if isinstance(e, readers.LogError) else f"{args.log}: {e.strerror or e}") from None
    if not chunked:
        for w in log.meta.get("warnings", []) + readers.unit_warnings(log):
            print(f"ahrsgen: warning: {w}", file=sys.stderr)
    if log.meta.get("ignored_columns"):
        print(f"  ignored columns: {', '.join(log.meta['ignored_columns'])}")
    try:
        res = run_on_log(args.filter, args.log, args.config, args.set, args.precision or "float",
                         plot=args.plot, csv=args.csv, exe=args.exe, runtime=args.runtime, preset=args.preset,
                         log=log)
    except readers.LogError as e:         # a chunked log's bad line is found when its chunk is read
        raise ConfigError(str(e)) from None
    if chunked:                           # the reference's warnings count every row; units: the first chunk's
        for w in log.meta.get("warnings", []) + readers.unit_warnings(log.head):
            print(f"ahrsgen: warning: {w}", file=sys.stderr)
    if args.export_log:
        from ahrsgen.generate import config
        write_harness_log(log, args.export_log)
        cfg = config.resolve(args.filter, args.config, list(args.set) + res["site_sets"],
                             args.precision or "float", None, args.preset)
        exe = build_log_runner(host.build(cfg).dir)
        print(f"  wrote {args.export_log}; run it with: {exe} {args.export_log} out.csv")
    if res.get("failed"):
        print(f"ahrsgen: run failed: {res['failed']}", file=sys.stderr)
        return 1
    return 0


def parse_variants(items) -> list:
    """'LABEL=FILTER:name=value,name=value' -> (label, filter, [name=value, ...]), validated."""
    from ahrsgen.errors import ConfigError
    out = []
    for item in items or []:
        label, eq, rest = item.partition("=")
        fname, _, sets_text = rest.partition(":")
        if not eq or not label.isidentifier() or not fname:
            raise ConfigError(f"--variant {item!r}: expected LABEL=FILTER:name=value,name=value")
        sets = [s for s in sets_text.split(",") if s]
        fname = config.resolve(fname, None, sets).filter   # unknown filter/parameter/value: one clear error
        out.append((label, fname, sets))
    return out


def _cmd_bench(args) -> int:
    if args.data is not None and not Path(args.data).is_dir():
        from ahrsgen.errors import ConfigError
        what = "is not a folder" if Path(args.data).exists() else "does not exist"
        raise ConfigError(f"--data {args.data} {what} (it should hold broad/ and px4/; without --data: "
                          f"${readers.DATA_ENV}, else <repo>/../shared/data)")
    asked = [p for p in (args.peers or ()) if not peers.PEERS[p].available()]
    if asked:
        from ahrsgen.errors import ConfigError
        raise ConfigError(f"--peers {' '.join(asked)}: package {peers.PEERS[asked[0]].package} is not installed "
                          f"(pip install 'ahrsgen[dev]')")
    from ahrsgen.fileio import check_output_dir, check_outputs
    from ahrsgen.cli import filter_inputs
    from ahrsgen.errors import ConfigError
    from ahrsgen.bench.grid import row_config, scenario_configs
    if args.scenarios:
        known = sorted({label for quick in (True, False) for label, _, _ in scenario_configs(quick)})
        grid = {label for label, _, _ in scenario_configs(args.quick)}
        bad = [s for s in args.scenarios if s not in grid]
        if bad:
            raise ConfigError(f"--scenarios {bad[0]}: not a scenario row of the "
                              f"{'--quick ' if args.quick else ''}grid (rows: {', '.join(sorted(grid))})"
                              if bad[0] in known else
                              f"--scenarios {bad[0]}: unknown scenario row (rows: {', '.join(sorted(grid))})")
        if args.real_only:
            raise ConfigError("--scenarios with --real-only: the real logs have no scenario rows")
    out = check_output_dir(args.output, "-o")
    data = None if args.scenarios_only else readers.shared_data_dir(args.data)
    olds = sorted((out / "img").glob("err_*.png")) if (out / "img").is_dir() else []
    rows = [] if args.real_only else [row_config(label, opts, out / "configs")
                                      for label, _, opts in scenario_configs(args.quick)
                                      if not args.scenarios or label in args.scenarios]
    if out.is_dir():                 # else it is created: nothing there to replace
        check_outputs([("-o", out / "bench.json"), ("-o", out / "bench.md"), *(("-o", p) for p in olds),
                       *(("-o", p) for p in rows if p is not None)],
                      [data, *(x for f in (args.filters or []) for x in filter_inputs(f))], args.force)
    cmd = "ahrsgen bench " + " ".join(sys.argv[2:]) if len(sys.argv) > 1 and sys.argv[1] == "bench" else "ahrsgen bench"
    rep = bench(quick=args.quick, seeds=args.seeds, filters=args.filters or None,
                peer_names=tuple(args.peers) if args.peers is not None else PEER_NAMES,
                data_dir=args.data, out_dir=args.output, jobs=args.jobs,
                scenarios_only=args.scenarios_only, real_only=args.real_only,
                scenario_labels=args.scenarios, command=cmd, variants=parse_variants(args.variant),
                scheduler=args.scheduler)
    md = Path(args.output) / "bench.md"
    print(md.read_text().replace("\n<!-- written by ahrsgen bench -->\n", ""))
    print(f"wrote {Path(args.output) / 'bench.json'}, {md} and {len(rep['plots'])} plot(s) in "
          f"{Path(args.output) / 'img'} ({rep['seconds']:.0f} s)", file=sys.stderr)
    # a product filter that refused most steps of a log did not run there: the bench failed
    refused = [msg for errs in rep.get("run_errors", {}).values() for msg in errs.values()
               if msg.startswith("MostlyRefused")]
    if refused:
        more = f" (and {len(refused) - 1} more: bench.json, run_errors)" if len(refused) > 1 else ""
        print(f"ahrsgen: bench failed: {refused[0].partition(': ')[2]}{more}", file=sys.stderr)
        return 1
    return 0


def register_cli(sub) -> None:
    from ahrsgen.argtypes import positive_int_arg   # loaded: it is the caller
    from ahrsgen.fileio import add_force_option
    p = sub.add_parser("run", help="run a generated filter over a real log (BROAD CSV or PX4 ULog) and score it",
                       description="Generate and compile a filter for the host, run it over a log file through "
                                   "the firmware harness, and where the log has a reference attitude score it "
                                   "(BROAD's method for BROAD data; PX4's vehicle_attitude for ULog). A gyro in "
                                   "deg/s or an accelerometer in g is recognised from the data and said in one "
                                   "warning line. Exit 1, with no score, if the filter refused most steps (a "
                                   "time column in ms or us, a gyro of NaN): one line on stderr says why.")
    p.add_argument("filter", help="filter name (see 'ahrsgen list') or a filter folder's path")
    p.add_argument("--log", required=True, metavar="FILE",
                   help="a CSV log (.csv/.csv.gz: t,gx,gy,gz,ax,ay,az and optional mx,my,mz, gps_vn,gps_ve,gps_vd, "
                        "qw,qx,qy,qz, movement; see docs/log-format.md; BROAD's files are in it) or a PX4 .ulg. "
                        f"Examples installed with ahrsgen: {readers.EXCERPTS / 'broad_01_excerpt.csv.gz'} (BROAD, "
                        f"optical reference), {readers.EXCERPTS / 'px4_handheld_excerpt.ulg'} (PX4, needs pyulog)")
    p.add_argument("--config", metavar="FILE.toml", help="TOML config (prefix, precision, [params])")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], help="override a parameter")
    p.add_argument("--preset", help="start from a named parameter set of the filter, e.g. 'faithful' "
                                    "(see 'ahrsgen list FILTER')")
    p.add_argument("--precision", choices=["float", "double"], help="C floating-point type (default float)")
    p.add_argument("--runtime", metavar="NAME,NAME", help="build these parameters as runtime parameters "
                                                          "(same figures; see 'generate --runtime')")
    p.add_argument("--plot", metavar="OUT.png",
                   help="plot roll/pitch/yaw beside the log's reference and the error over time; steps "
                        "with a fault bit (STATUS_FAULT_MASK) marked in red, with information bits "
                        "only (AT_REST, ...) in grey")
    p.add_argument("--csv", metavar="OUT.csv", help="write t, q, Euler angles (deg), status (and the reference)")
    p.add_argument("--exe", action="store_true",
                   help="run through the standalone executable (src/ahrsgen/sim/c/main_log.c) instead of ctypes")
    p.add_argument("--export-log", metavar="OUT.csv",
                   help="also write the log in the standalone executable's text format (main_log.c) and "
                        "print the executable's path, to run it outside Python")
    add_force_option(p)
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("bench", help="filters x scenarios x seeds, real logs and peers: accuracy and cost tables",
                       description="Benchmark every product filter (float C through the firmware harness) and "
                                   "the peers (VQF, Fusion, Madgwick, Mahony) on the simulated scenarios, the "
                                   "BROAD subset and the PX4 logs; measure ns/step against a hand-written QCF. "
                                   "Writes bench.json, bench.md and plots. Exit 1 if a generated filter refused "
                                   "most steps of a log (listed under Failures, no score).")
    p.add_argument("--quick", action="store_true", help="short CI run (1 seed, shorter scenarios, data excerpts)")
    p.add_argument("--seeds", type=positive_int_arg, help="seeds per scenario (default 3, --quick 1)")
    p.add_argument("--filters", nargs="*", help="only these filters, names or folder paths (default: all known)")
    p.add_argument("--scenarios", nargs="*", metavar="LABEL",
                   help="only these scenario rows of the grid (e.g. multirotor turntable; default: all)")
    p.add_argument("--peers", nargs="*", choices=list(peers.PEERS), help=f"peers to include (default: {' '.join(PEER_NAMES)})")
    p.add_argument("--data", metavar="DIR", help="folder holding broad/ and px4/ (default: $AHRSGEN_DATA, "
                                                 "else <repo>/../shared/data)")
    p.add_argument("-o", "--output", default="bench_out", metavar="DIR", help="output folder (default bench_out)")
    p.add_argument("-j", "--jobs", "--workers", dest="jobs", type=positive_int_arg, default=2,
                   help="local worker processes (default 2)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the logs on this Dask distributed scheduler instead of local processes "
                        "(workers must see the same data paths)")
    p.add_argument("--variant", action="append", default=[], metavar="LABEL=FILTER:k=v,k=v",
                   help="also bench FILTER with these settings under LABEL, e.g. "
                        "qcf_soft=qcf:kp=0.05,ki=0.001 (repeatable)")
    add_force_option(p)
    g = p.add_mutually_exclusive_group()
    g.add_argument("--scenarios-only", action="store_true", help="skip the real logs")
    g.add_argument("--real-only", action="store_true", help="only the real logs (BROAD, PX4)")
    p.set_defaults(func=_cmd_bench)
