"""`ahrsgen tune` on the command line."""
from __future__ import annotations

import sys
from pathlib import Path

from ahrsgen.errors import ConfigError
from ahrsgen.tune.cases import collect_cases
from ahrsgen.tune.run import TuneFailed, tune
from ahrsgen.tune.score import METRICS

def _cmd_tune(args) -> int:
    from ahrsgen import filters
    filters.load(args.filter)                       # unknown filter: one line
    out = Path(args.output)
    if not out.parent.is_dir():
        raise ConfigError(f"-o {out}: folder {out.parent} does not exist")
    cases = collect_cases(args.log, args.logs, args.scenario, args.seeds, args.scenario_opt)
    from ahrsgen.fileio import check_outputs
    from ahrsgen.filters import input_folders as filter_inputs
    logs = [c.arg for c in cases if c.kind == "file"]
    check_outputs([("-o", out), ("-o (its report)", Path(str(out) + ".json"))],
                  [*logs, args.config, *filter_inputs(args.filter)], args.force)
    check_outputs([("-o (its journal)", Path(str(out) + ".journal"))], [*logs, args.config], force=True)
    params = [p for item in args.params for p in _split_params(item)]
    try:
        tune(args.filter, params, cases, budget=args.budget, folds=args.folds, metric=args.metric,
             config_file=args.config, sets=args.set, workers=args.workers, scheduler=args.scheduler,
             output=out, seed=args.seed, progress=True, engine=args.engine)
    except TuneFailed as e:
        print(f"ahrsgen: tune failed: {e}", file=sys.stderr)
        return 1
    return 0


def _split_params(text: str) -> list[str]:
    return [s.strip() for s in text.split(",") if s.strip()]


def register_cli(sub) -> None:
    from ahrsgen.argtypes import nonneg_int_arg, positive_int_arg   # loaded: it is the caller
    p = sub.add_parser("tune", help="choose parameters from logs with a reference attitude; write a TOML config",
                       description="Search the named parameters of a filter inside their declared ranges (Optuna "
                                   "TPE) to minimise the RMS attitude error of its float C over logs with a "
                                   "reference, scored as 'ahrsgen run' and 'bench' score; report the training and "
                                   "K-fold cross-validated error beside the current values; write a config that "
                                   "'ahrsgen generate --config' takes. Interrupt and re-run to resume. The "
                                   "config is written only if the tuned values beat the current ones out of "
                                   "sample (cross-validated; with --folds 0, on the training logs); else exit 1 "
                                   "with the report only. Exit 1 too if the filter refuses most steps of a log.")
    p.add_argument("filter", help="filter name (see 'ahrsgen list')")
    p.add_argument("--log", action="append", default=[], metavar="FILE", help="BROAD .csv/.csv.gz or PX4 .ulg (repeatable)")
    p.add_argument("--logs", metavar="DIR", help="every .csv, .csv.gz and .ulg file in DIR")
    p.add_argument("--scenario", help="also simulated flights of this scenario (see 'ahrsgen list')")
    p.add_argument("--seeds", type=positive_int_arg, default=1, help="scenario seeds 0..N-1 (default 1)")
    p.add_argument("--scenario-opt", action="append", default=[], metavar="NAME=VALUE", help="scenario option")
    p.add_argument("--params", action="append", required=True, metavar="NAME[=LOW:HIGH],...",
                   help="parameters to tune, comma-separated; optional search range inside the declared one")
    p.add_argument("--metric", choices=list(METRICS), default="total",
                   help="error to minimise: BROAD's total, inclination or heading RMS (default total)")
    p.add_argument("--budget", type=positive_int_arg, default=40, help="trials per study (default 40)")
    p.add_argument("--folds", type=int, help="K-fold cross-validation over logs (default min(5, logs); 0 = none)")
    p.add_argument("--config", metavar="FILE.toml", help="start from this config (its values are kept)")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], help="fix a parameter")
    p.add_argument("--workers", type=positive_int_arg, default=2, help="local worker processes (default 2)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask distributed scheduler instead")
    p.add_argument("--seed", type=nonneg_int_arg, default=0, help="sampler seed, a whole number >= 0 (default 0)")
    p.add_argument("--engine", choices=["runtime", "baked"], default="runtime",
                   help="runtime (default): build once with the tuned real parameters as runtime parameters "
                        "and set them per trial; baked: fold them in and rebuild per trial")
    p.add_argument("-o", "--output", required=True, metavar="TUNED.toml",
                   help="config file to write (with TUNED.toml.json, the report); an existing file is replaced "
                        "only if ahrsgen wrote it (docs/output-files.md)")
    from ahrsgen.fileio import add_force_option
    add_force_option(p)
    p.set_defaults(func=_cmd_tune)
