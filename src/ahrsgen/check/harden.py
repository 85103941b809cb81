"""Hardening of the generated C: what happens when a sensor glitches.

Three checks per generated filter directory (generated/<name>/ or any `ahrsgen generate` output):

- **fuzz**: `src/ahrsgen/sim/fuzz/fuzz_step.c` is compiled with the filter under libFuzzer,
  AddressSanitizer and UndefinedBehaviorSanitizer (clang). It feeds arbitrary bit patterns to
  every input field and dt, steps a fresh state a few hundred times per input and aborts when
  an invariant breaks (src/ahrsgen/sim/fuzz/ahrs_invariants.h).
- **soak**: `src/ahrsgen/sim/c/soak.c` steps the float build millions of times over synthesised
  varied motion with occasional glitches and reports the invariants (max | |q| - 1 |, covariance
  asymmetry, smallest LDL^T pivot, ...) as JSON, per tenth of the run so drift would show.
- **cppcheck**: static analysis of the generated source and header.

Both C harnesses are generic: the per-filter facts (which state fields are quaternions, which
is a covariance, the status bits) come from the filter's manifest.json through a small
`ahrs_layout.h` written here. Conventions read from the manifest:
  real state field named `q`, `q_*` (4 reals) or documented as quaternion(s) -> unit quaternions
  (an array of several, e.g. particles, only once the `initialised` flag is set);
  a real field named `P` (or documented as a covariance) with n*n reals -> symmetric positive
  definite; a field named `weights` -> non-negative, summing to 1 (to the real field
  `weight_sum`, if there is one: weights kept unnormalised with their sum).

Entry points: `harden(gen_dir, ...)` (all three), `run_fuzz`, `run_soak`, `run_cppcheck`, and
`ahrsgen harden FILTER|all` (register_cli). One module per check beside this one: layout
(manifest -> ahrs_layout.h, where builds are), tools (compilers, the cached harness build),
fuzz, soak, static (cppcheck and the kernels' structural check); their names are importable
from here as well.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from ahrsgen.check import static, tools
from ahrsgen.check.fuzz import (FUZZ_STEPS, KNOWN_ISSUES, MAX_RECORDS, REGRESSIONS, build_fuzzer,  # noqa: F401
                                decode_input, describe_input, fuzz_dictionary, known_issues, make_record,
                                record_size, regressions_for, replay, run_fuzz, seed_inputs)
from ahrsgen.check.layout import (BUILD, GENERATED, HardenError, generated_dirs, invariant_plan,  # noqa: F401
                                  layout_header, load_manifest, resolve_dir)
from ahrsgen.check.soak import build_soak, run_soak, site_field  # noqa: F401
from ahrsgen.check.static import (build_kernels, emitted_functions, kernel_issues,  # noqa: F401
                                  kernel_structure_issues, run_cppcheck)
from ahrsgen.check.tools import clang_fuzzer_works, have_tool  # noqa: F401

def harden(gen_dir: str | Path, fuzz_seconds: float | None = 60, fuzz_runs: int | None = None,
           soak_steps: int | None = 10_000_000, seed: int = 1, glitch_rate: float = 1e-3,
           do_cppcheck: bool = True, cppcheck_max_kernel_lines: int | None = None,
           cppcheck_timeout: float | None = 3600) -> dict:
    gen_dir = Path(gen_dir)
    man = load_manifest(gen_dir)
    res: dict = {"filter": man["filter"], "dir": str(gen_dir), "precision": man["precision"]}
    if do_cppcheck:
        res["cppcheck"] = (run_cppcheck(gen_dir, cppcheck_max_kernel_lines, cppcheck_timeout) if have_tool(static.CPPCHECK)
                           else {"skipped": f"{static.CPPCHECK} not found"})
    if fuzz_seconds or fuzz_runs:
        res["fuzz"] = (run_fuzz(gen_dir, seconds=fuzz_seconds, runs=fuzz_runs, seed=seed)
                       if clang_fuzzer_works() else {"skipped": f"{tools.CLANG} with -fsanitize=fuzzer not available"})
    if soak_steps:
        res["soak"] = run_soak(gen_dir, steps=soak_steps, seed=seed, glitch_rate=glitch_rate)
    res["ok"] = (res.get("cppcheck", {}).get("ok", True) is not False
                 and not res.get("fuzz", {}).get("crashes")
                 and not any(k["still_present"] for k in res.get("fuzz", {}).get("known_issues", []))
                 and all(g["ok"] for g in res.get("fuzz", {}).get("regressions", []))
                 and res.get("soak", {}).get("violations", 0) == 0)
    return res


def _fmt(v, spec=".3g"):
    return "-" if v is None else format(v, spec)


def print_table(results: list[dict]) -> None:
    # no cppcheck column when it was not run (--no-cppcheck): nothing about it to say
    show_cc = any("skipped" not in r.get("cppcheck", {"skipped": True}) for r in results)
    print(f"{'filter':<8} {'cppcheck' if show_cc else '':<9} {'fuzz execs':>11} {'exec/s':>7} {'cov':>5} {'crashes':>7} "
          f"{'soak steps':>11} {'viol':>5} {'max||q|-1|':>10} {'max|P-PT|rel':>12} {'min pivot':>10} "
          f"{'min piv rel':>11} {'ns/step':>8} {'att rms deg':>11}")
    for r in results:
        c, f, s = r.get("cppcheck", {}), r.get("fuzz", {}), r.get("soak", {})
        cc = ("" if not show_cc else "skipped" if "skipped" in c else "-" if not c else "timeout" if c["timed_out"] else "clean" if c["ok"]
              else f"{len(c['issues']) + len(c['structural_issues'])} issues")
        print(f"{r['filter']:<8} {cc:<9} {_fmt(f.get('executions'), 'd'):>11} {_fmt(f.get('exec_per_s'), 'd'):>7} "
              f"{_fmt(f.get('coverage'), 'd'):>5} {len(f.get('crashes', [])) if 'executions' in f else '-':>7} "
              f"{_fmt(s.get('steps'), 'd'):>11} {_fmt(s.get('violations'), 'd'):>5} {_fmt(s.get('max_qnorm_err')):>10} "
              f"{_fmt(s.get('max_asym_rel')):>12} {_fmt(s.get('min_pivot')):>10} {_fmt(s.get('min_pivot_rel')):>11} "
              f"{_fmt(s.get('ns_per_step'), '.0f'):>8} {_fmt(s.get('att_err_rms_deg')):>11}")
    for r in results:
        for cr in r.get("fuzz", {}).get("crashes", []):
            print(f"\n{r['filter']}: fuzz {cr['kind']}: {cr['message']}")
            for ln in cr.get("input", []):
                print(f"    {ln}")
            if "artifact" in cr:
                print(f"    input file {cr['artifact']}")
        for g in r.get("fuzz", {}).get("regressions", []):
            if not g["ok"]:
                print(f"\n{r['filter']}: REGRESSION {g['id']} is back: " + g["replay"].replace("\n", "\n    "))
        for k in r.get("fuzz", {}).get("known_issues", []):
            state = "STILL PRESENT" if k["still_present"] else "fixed (remove it from KNOWN_ISSUES)"
            print(f"\n{r['filter']}: known issue {k['id']}: {state}; fuzzed with {k['excluded_by'] or 'no exclusion'}")
            print(f"    {k['what']}")
            if k["still_present"]:
                print("    replay: " + k["replay"].replace("\n", "\n    "))
        c = r.get("cppcheck", {})
        for iss in c.get("issues", []) + c.get("structural_issues", []):
            print(f"{r['filter']}: cppcheck: {iss}")
        if c.get("structurally_checked"):
            print(f"{r['filter']}: cppcheck: long emitted kernels checked structurally instead: "
                  + ", ".join(c["structurally_checked"]))
        if c.get("timed_out"):
            print(f"{r['filter']}: cppcheck did not finish in {c['timeout_s']} s")
        s = r.get("soak", {})
        if s.get("violations"):
            print(f"{r['filter']}: soak: {s['violations']} violations, first at step {s['first_violation_step']}: "
                  f"{s['first_violation']}")


def unavailable_checks(fuzz: bool, soak: bool, cppcheck: bool) -> list[str]:
    """The asked-for checks that cannot run on this machine, each with what is missing."""
    out = []
    if cppcheck and not have_tool(static.CPPCHECK):
        out.append(f"cppcheck ({static.CPPCHECK} not found; install cppcheck, or pass --no-cppcheck)")
    if fuzz and not clang_fuzzer_works():
        out.append(f"fuzzing ({tools.CLANG} -fsanitize=fuzzer,address,undefined does not link; install clang and "
                   f"libclang-rt-14-dev as .ci/setup does, or pass --fuzz-seconds 0)")
    if soak and not have_tool(os.environ.get("CC", "cc")):
        out.append(f"soak (no C compiler '{os.environ.get('CC', 'cc')}'; or pass --soak-steps 0)")
    return out


def cmd_harden(args) -> int:
    from ahrsgen.errors import ConfigError
    try:
        dirs = generated_dirs() if args.filter == "all" else [resolve_dir(args.filter)]
    except HardenError as e:
        raise ConfigError(str(e)) from None
    # A check that was asked for and cannot run is an error, not a '-' in the table.
    cannot = unavailable_checks(bool(args.fuzz_seconds or args.fuzz_runs), bool(args.soak_steps),
                                not args.no_cppcheck)
    if cannot:
        raise ConfigError("cannot run " + "; ".join(cannot))
    out = Path(args.json) if args.json else BUILD / "harden.json"
    from ahrsgen.fileio import check_outputs
    if out.is_dir():
        raise ConfigError(f"--json: {out} is a folder")
    if out.parent.is_dir() or args.json:
        check_outputs([("--json", out)], dirs, args.force)
    results = []
    for d in dirs:
        print(f"harden {d.name}: {'' if args.no_cppcheck else 'cppcheck, '}fuzz {args.fuzz_seconds or 0:g} s"
              f"{f' / {args.fuzz_runs} runs' if args.fuzz_runs else ''}, soak {args.soak_steps} steps ...", flush=True)
        results.append(harden(d, fuzz_seconds=args.fuzz_seconds, fuzz_runs=args.fuzz_runs,
                              soak_steps=args.soak_steps, seed=args.seed, glitch_rate=args.glitch_rate,
                              do_cppcheck=not args.no_cppcheck,
                              cppcheck_max_kernel_lines=args.cppcheck_max_kernel_lines,
                              cppcheck_timeout=args.cppcheck_timeout))
    print()
    print_table(results)
    out.parent.mkdir(parents=True, exist_ok=True)
    from ahrsgen.fileio import write_text_atomic
    write_text_atomic(out, json.dumps({"written_by": "ahrsgen harden", "results": results}, indent=2))
    print(f"\nJSON: {out}")
    return 0 if all(r["ok"] for r in results) else 1


def register_cli(sub) -> None:
    p = sub.add_parser(
        "harden", help="fuzz the step (libFuzzer+ASan+UBSan), soak it, cppcheck the generated C",
        description="For a filter (a name or folder: its committed generated/ build, else its defaults; a "
                    "directory with manifest.json; or 'all'): cppcheck the "
                    "source; fuzz its step with arbitrary float bit patterns under AddressSanitizer and "
                    "UndefinedBehaviorSanitizer, checking the state invariants after every step; soak it "
                    "over synthesised varied motion with glitches. Prints a table, writes JSON. Exit 1 "
                    "on any finding.")
    p.add_argument("filter", help="a filter (name or folder; its committed generated/NAME if there is one, else "
                                  "its defaults), a directory with manifest.json, or 'all'")
    from ahrsgen.argtypes import count_arg, nonneg_float_arg, nonneg_int_arg, positive_int_arg, positive_float_arg
    from ahrsgen.fileio import add_force_option
    p.add_argument("--fuzz-seconds", type=nonneg_float_arg, default=60, metavar="N", help="fuzzing time per filter (default 60; 0 = no fuzzing)")
    p.add_argument("--fuzz-runs", type=count_arg, metavar="N", help="stop fuzzing after N inputs")
    p.add_argument("--soak-steps", type=count_arg, default=10_000_000, metavar="N",
                   help="soak steps, a whole number >= 0 such as 100000 or 1e7 (default 1e7; 0 = no soak)")
    p.add_argument("--seed", type=nonneg_int_arg, default=1, help="fuzzer and soak seed, a whole number >= 0 (default 1)")
    p.add_argument("--glitch-rate", type=probability_arg, default=1e-3,
                   help="soak: probability of a glitch per step, 0 to 1 (default 1e-3)")
    p.add_argument("--no-cppcheck", action="store_true", help="skip cppcheck")
    p.add_argument("--cppcheck-max-kernel-lines", type=positive_int_arg, metavar="N",
                   help="emitted kernels longer than N lines are checked structurally (bounds, definitions, "
                        "outputs) instead of by cppcheck, whose analysis of a 3000-line kernel takes minutes "
                        "(default: cppcheck everything)")
    p.add_argument("--cppcheck-timeout", type=positive_float_arg, default=3600, metavar="S", help="cppcheck time limit per filter")
    p.add_argument("--json", metavar="FILE", help="write the results here (default build/harden/harden.json)")
    add_force_option(p)
    p.set_defaults(func=cmd_harden)


def probability_arg(text: str) -> float:
    """A probability: a finite number from 0 to 1."""
    import argparse
    import math
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (math.isfinite(v) and 0.0 <= v <= 1.0):
        raise argparse.ArgumentTypeError(f"expected a probability from 0 to 1, got {text!r}")
    return v
