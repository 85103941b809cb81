"""`ahrsgen target`: the command line of the target checks."""
from __future__ import annotations

import json
import shlex
import tempfile
from dataclasses import asdict
from pathlib import Path

from ahrsgen.target.build import APT_PACKAGES, CPUS, MATH_FLAGS, OPT_LEVELS, PIP_PACKAGES, QEMU_MACHINE, missing_tools, peer_binding, PEER_NAMES, CHECKED_PEER_NAMES
from ahrsgen.target.check import DEFAULT_TOLERANCE_DEG, _print_results, check_filter, check_generated, toolchain_versions
from ahrsgen.target.emulate import libm_survey, records_from_log
from ahrsgen.target.footprint import format_table
from ahrsgen.fileio import write_text_atomic


def cmd_target(args) -> int:
    from ahrsgen import filters
    from ahrsgen.errors import ConfigError
    from ahrsgen.fileio import check_output_dir
    check_output_dir(Path(args.json).parent, "--json")      # refuse a bad path before the builds
    if Path(args.json).is_dir():
        raise ConfigError(f"--json: {args.json} is a folder")
    from ahrsgen.fileio import check_outputs
    from ahrsgen.cli import filter_inputs
    if Path(args.json).parent.is_dir():          # else it is created: nothing there to replace
        check_outputs([("--json", args.json)], [args.config, *filter_inputs(args.filter if args.filter != "all" else None)],
                      args.force)
    try:
        cflags = tuple(shlex.split(args.cflags or ""))
    except ValueError as e:                                # an unbalanced quote
        raise ConfigError(f"--cflags: {e}") from None
    if any(f.startswith("-O") for f in cflags):
        raise ConfigError("--cflags: give the optimisation level with --opt (-O2, -Os), not in --cflags")
    missing = missing_tools()
    if missing:
        raise ConfigError("target checks need " + ", ".join(missing) + " (apt-get install "
                          + " ".join(APT_PACKAGES) + "; pip install " + " ".join(PIP_PACKAGES) + ")")
    names = filters.names() if args.filter == "all" else [args.filter]
    if args.filter == "all" and (args.config or args.set):
        raise ConfigError("--config/--set apply to one filter, not 'all'")
    for n in names:
        filters.load(n)   # unknown filter -> ConfigError
    opts = args.opt or list(OPT_LEVELS)
    from ahrsgen.sim import scenarios
    try:
        sopts = scenarios.parse_options(args.scenario, args.scenario_opt)
    except KeyError as e:
        raise ConfigError(str(e.args[0])) from None
    results = []
    with tempfile.TemporaryDirectory(prefix="ahrsgen-target-") as tmp:
        root = Path(args.workdir) if args.workdir else Path(tmp)
        for n in names:
            try:
                results += check_generated(n, opts, args.cpu, args.scenario, args.seed, sopts, args.config,
                                           args.set, args.prefix, root / n,
                                           None if args.count_steps == 0 else args.count_steps,
                                           pinned=not args.no_pinned, tolerance_deg=args.tolerance,
                                           precision=args.precision, math=args.math, fma=args.fma,
                                           profile=args.profile, cflags=cflags)
            except KeyError as e:
                raise ConfigError(str(e.args[0])) from None
    if not args.workdir:
        for r in results:
            r.pop("workdir", None)
    peer_rows = []
    if args.peers:
        from ahrsgen.sim import scenarios
        log = scenarios.make("fixedwing_gps", seed=args.seed)
        with tempfile.TemporaryDirectory(prefix="ahrsgen-peers-") as tmp:
            for pn in PEER_NAMES + CHECKED_PEER_NAMES:
                for opt in opts:
                    r = check_filter(peer_binding(pn), records_from_log(log), Path(tmp), opt=opt, cpu=args.cpu,
                                     count_steps=None if args.count_steps == 0 else args.count_steps,
                                     cflags=cflags)
                    r.footprint.variant = " ".join(cflags)
                    peer_rows.append(r.footprint)
    from ahrsgen.target.cycles import MODEL_TEXT
    print(f"target {args.cpu}: {' '.join(CPUS[args.cpu])} {' '.join(MATH_FLAGS)}; QEMU {QEMU_MACHINE}; "
          f"instructions (not cycles) per step under QEMU -icount, checked step by step against unicorn; "
          f"est. cycles per step over the steps unicorn ran [steps]: {MODEL_TEXT}")
    ok = _print_results(results)
    if args.profile:
        from ahrsgen.target.profile import format_profile
        for r in results:
            print("\n" + format_profile(r["filter"], r["opt"], r["profile"]))
    survey = None
    if args.libm_survey:
        with tempfile.TemporaryDirectory(prefix="ahrsgen-libm-") as tmp:
            survey = libm_survey(Path(tmp), cpu=args.cpu)
        print("\nnewlib (target) vs host libm, float functions on the same float32 arguments:")
        for fn, v in survey.items():
            print(f"  {fn:<7} differs in {v['differ']}/{v['arguments']} arguments, by at most {v['max_ulp']} ulp")
    beside = beside_peers(results, peer_rows)
    if peer_rows:
        print("\ncalibration peers (src/ahrsgen/target/peers, fixedwing_gps; counts only; *_checked: the same "
              "updates behind the product's input checks):")
        print(format_table(peer_rows))
        for b in beside:
            print(f"{b['filter']} {b['opt']}: generated {b['generated']:.0f} / hand-written {b['hand_written']:.0f} "
                  f"instructions per step = {b['ratio']:.2f}x (same scenario; the hand-written update checks no input)")
            if b.get("hand_written_checked"):
                print(f"{b['filter']} {b['opt']}: generated {b['generated']:.0f} / hand-written with the same input "
                      f"checks {b['hand_written_checked']:.0f} instructions per step = {b['ratio_checked']:.2f}x "
                      f"(like for like: the same status bits, zero-gyro skip and IMU-only fallback; it starts at "
                      f"the identity, so compare a build with --set initialise=false)")
            if b.get("ratio_cycles_est") is not None:
                line = (f"{b['filter']} {b['opt']}: estimated cycles per step, generated {b['generated_cycles_est']:.0f} / "
                        f"hand-written {b['hand_written_cycles_est']:.0f} = {b['ratio_cycles_est']:.2f}x")
                if b.get("ratio_checked_cycles_est") is not None:
                    line += (f"; / hand-written with the input checks {b['hand_written_checked_cycles_est']:.0f} = "
                             f"{b['ratio_checked_cycles_est']:.2f}x")
                print(line + " (over the steps unicorn ran)")
    doc = {"written_by": "ahrsgen target", "cpu": args.cpu, "cpu_flags": CPUS[args.cpu], "math_flags": MATH_FLAGS, "qemu_machine": QEMU_MACHINE,
           "tools": toolchain_versions(), "tolerance_deg": args.tolerance, "results": results,
           "peers": [asdict(r) for r in peer_rows], "beside_peers": beside, "libm_survey": survey}
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(doc, indent=2, sort_keys=True) + "\n")     # whole or none
    print(f"wrote {out}")
    return 0 if ok else 1


def beside_peers(results: list[dict], peer_rows) -> list[dict]:
    """A checked filter that has a hand-written twin among the peers (the example user filters
    examples/madgwick and examples/mahony): instructions per step of both, same build, same
    scenario (both on fixedwing_gps unless --scenario says otherwise for the filter); against
    the plain hand-written update and against its variant with the product's input checks; the
    estimated cycles per step of both beside them (target/cycles.py, over the counted steps)."""
    peers = {(r.filter.removeprefix("peer:"), r.opt): r.instructions_mean for r in peer_rows}
    peer_cycles = {(r.filter.removeprefix("peer:"), r.opt): r.cycles_est_mean for r in peer_rows
                   if r.cycles_est_steps > 0}
    out = []
    for r in results:
        if r.get("precision", "float") != "float":
            continue
        hand = peers.get((r["filter"], r["opt"]))
        gen = r["footprint"]["instructions_mean"]
        if hand and r.get("scenario") == "fixedwing_gps":
            row = {"filter": r["filter"], "opt": r["opt"], "generated": gen, "hand_written": hand, "ratio": gen / hand}
            checked = peers.get((r["filter"] + "_checked", r["opt"]))
            if checked:
                row.update(hand_written_checked=checked, ratio_checked=gen / checked)
            gen_c = r["footprint"].get("cycles_est_mean") if r["footprint"].get("cycles_est_steps", 0) > 0 else None
            hand_c = peer_cycles.get((r["filter"], r["opt"]))
            if gen_c and hand_c:
                row.update(generated_cycles_est=gen_c, hand_written_cycles_est=hand_c, ratio_cycles_est=gen_c / hand_c)
                checked_c = peer_cycles.get((r["filter"] + "_checked", r["opt"]))
                if checked_c:
                    row.update(hand_written_checked_cycles_est=checked_c, ratio_checked_cycles_est=gen_c / checked_c)
            out.append(row)
    return out


def register_cli(sub) -> None:
    from ahrsgen.argtypes import nonneg_float_arg, nonneg_int_arg   # loaded: it is the caller
    p = sub.add_parser(
        "target", help="cross-build for a Cortex-M4F, run in QEMU, compare with the host, report footprint",
        description="Generate the float C of a filter, build it with arm-none-eabi-gcc at -O2 and -Os, run a "
                    "scenario through it on an emulated Cortex-M4F (QEMU mps2-an386), check the outputs against "
                    "the host float build, and report flash, static RAM, worst-case stack and instructions per "
                    "step (table on stdout, JSON file). Exit 1 if a check fails: the pinned-libm build not "
                    "bit-identical with the host, the real-libm build beyond its bound, or the status codes "
                    "differ; each FAIL line names the check.")
    p.add_argument("filter", help="filter name (see 'ahrsgen list'), a filter folder's path, or 'all'")
    p.add_argument("--config", metavar="FILE.toml", help="TOML config (its precision is ignored: see --precision)")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], help="override one parameter (repeatable)")
    p.add_argument("--prefix", help="C identifier prefix (default: the filter name)")
    p.add_argument("--cpu", choices=sorted(CPUS), default="cortex-m4f", help="target CPU (default cortex-m4f)")
    p.add_argument("--precision", choices=["float", "double"], default="float",
                   help="float (default; the M4F FPU) or double (soft-float: shows what a double build costs, "
                        "compared with the host double build)")
    p.add_argument("--math", choices=["fast", "libm"], help="float trigonometry (default: the generator's, fast)")
    p.add_argument("--fma", action="store_true", default=None, help="emitter-written fused multiply-adds")
    p.add_argument("--opt", action="append", choices=list(OPT_LEVELS),
                   help="optimisation level, written --opt -O2 or --opt=-O2 (repeatable; default both -O2 and -Os)")
    p.add_argument("--cflags", metavar="'FLAGS'",
                   help="your project's own compiler flags, added after ours to every target build, e.g. "
                        "--cflags='-fno-gcse-lm' (the report's build column shows them; target vs host still "
                        "checked, so a flag that changes the arithmetic, such as -ffast-math, shows there)")
    p.add_argument("--scenario", help="scenario (default: the filter's source experiment, e.g. fixedwing_gps for qcf)")
    p.add_argument("--seed", type=nonneg_int_arg, default=0, help="scenario seed, a whole number >= 0 (default 0)")
    p.add_argument("--scenario-opt", metavar="NAME=VALUE", action="append", default=[],
                   help="scenario option, e.g. duration=30 (repeatable)")
    p.add_argument("--count-steps", type=nonneg_int_arg, default=50, metavar="N",
                   help="steps also run in unicorn (exact instruction count cross-check); 0 = all; "
                        "default 50. QEMU counts instructions and paints the stack over every step.")
    p.add_argument("--tolerance", type=nonneg_float_arg, default=DEFAULT_TOLERANCE_DEG, metavar="DEG",
                   help=f"largest allowed target-vs-host attitude difference (default {DEFAULT_TOLERANCE_DEG:g} deg)")
    p.add_argument("--peers", action="store_true",
                   help="also measure the calibration peers (hand-written Madgwick, Mahony with integral) for scale, and "
                        "their variants with the product's input checks; a filter named like one (examples/madgwick, "
                        "examples/mahony) is set beside both (ratios; like for like with --set initialise=false)")
    p.add_argument("--profile", action="store_true",
                   help="also show where the step's instructions and estimated cycles go: per kernel and helper function, over the "
                        "--count-steps steps (a -g build of the same code, every instruction counted in unicorn "
                        "and mapped to its source function)")
    p.add_argument("--libm-survey", action="store_true",
                   help="also compare newlib's float sinf/cosf/asinf/atanf/expf/logf/atan2f with the host's, in ulps")
    p.add_argument("--no-pinned", action="store_true",
                   help="skip the pinned-libm identity run (float libm evaluated through double on both sides)")
    p.add_argument("--json", default="build/target/target.json", metavar="FILE",
                   help="where to write the JSON report (default build/target/target.json)")
    p.add_argument("--workdir", metavar="DIR", help="keep build products here (default: a temporary directory)")
    from ahrsgen.fileio import add_force_option
    add_force_option(p)
    p.set_defaults(func=cmd_target)
