"""`ahrsgen bench`: filters x scenarios x seeds, the real logs and the peers, run on local
processes or a Dask cluster; the cost per step beside the hand-written QCF."""
from __future__ import annotations

import ctypes
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from ahrsgen.sim import host, peers, readers
from ahrsgen.sim.log import SensorLog
from ahrsgen.bench.common import C_DIR, PEER_NAMES
from ahrsgen.bench.harness import baseline_filter
from ahrsgen.bench.report import _plots, markdown
from ahrsgen.bench.scoring import (Estimator, filter_estimator, peer_estimator, product_filters, score,
                                        total_error_series)


# =========================================================================================
# ahrsgen bench

def scenario_configs(quick: bool) -> list[tuple[str, str, dict]]:
    """(label, scenario, options) of the benchmark grid."""
    from ahrsgen.sim import scenarios
    known = scenarios.names()
    if quick:
        grid = [("fixedwing_gps", "fixedwing_gps", {"duration": 120.0}),
                ("multirotor", "multirotor", {"duration": 30.0}),
                ("static_accel_disturbance", "static_accel_disturbance", {"duration": 60.0}),
                ("static_mag_disturbance", "static_mag_disturbance", {"duration": 60.0}),
                ("turntable", "turntable", {})]
    else:
        grid = [("fixedwing_gps", "fixedwing_gps", {}),
                ("fixedwing_gps_100hz", "fixedwing_gps", {"rate_hz": 100.0}),
                ("multirotor", "multirotor", {}),
                ("multirotor_400hz", "multirotor", {"rate_hz": 400.0, "mag_rate": 100.0}),
                ("multirotor_400hz_repeated", "multirotor", {"rate_hz": 400.0, "mag_rate": 100.0,
                                                              "repeat_slow": True}),
                ("multirotor_1khz", "multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0}),
                ("multirotor_jitter_dropouts", "multirotor",
                 {"jitter": 0.0004, "dropout": {"gyro": 0.005, "accel": 0.01, "mag": 0.05, "gps": 0.1}}),
                ("static_accel_disturbance", "static_accel_disturbance", {}),
                ("static_mag_disturbance", "static_mag_disturbance", {}),
                ("turntable", "turntable", {}),
                ("gyro_clip", "gyro_clip", {}),
                ("attached_magnet", "attached_magnet", {}),
                ("handheld", "handheld", {}),
                ("handheld_uncalibrated_iron", "handheld", {"iron": True}),
                ("handheld_rolled_180", "handheld", {"board_rotation": "ROLL_180"})]
    return [g for g in grid if g[1] in known]


# the seed of the log a user records to calibrate the sensor (not one of the scored seeds)
CALIBRATION_SEED = 1000


def row_config(label: str, opts: dict, config_dir: Path) -> Path | None:
    """The config file a grid row writes (see row_estimators), or None."""
    if opts.get("iron") or opts.get("board_rotation", "NONE") != "NONE":
        return config_dir / f"{label}.toml"
    return None


def row_estimators(label: str, scen: str, opts: dict, filter_names, config_dir: Path) -> tuple[list, bool]:
    """Estimators a grid row adds, and whether the default estimators run on it too.

    An uncalibrated sensor (option iron): every filter with a magnetometer heading again, built
    with the [calibration] that `ahrsgen calibrate` finds on the sensor's own calibration log
    (the scenario with calibration=True), as `<filter>_calibrated`. A rotated board (option
    board_rotation): every filter built with that [mounting] sensor_rotation, as
    `<filter>_mounted`, alone (an estimator told nothing of the mounting scores nothing useful).
    The configs are written to config_dir (row_config), where a user would keep them."""
    from ahrsgen import calibrate
    from ahrsgen.fileio import MARK, write_text_atomic
    from ahrsgen.sim import scenarios
    path = row_config(label, opts, config_dir)
    if path is None:
        return [], True
    path.parent.mkdir(parents=True, exist_ok=True)
    if opts.get("iron"):
        cal_log = scenarios.make(scen, seed=CALIBRATION_SEED, **opts, calibration=True)
        write_text_atomic(path, calibrate.toml_text(calibrate.calibrate([cal_log]),
                                                    [f"{scen} calibration log, seed {CALIBRATION_SEED}"]))
        ests = [filter_estimator(f, config_file=str(path), label=f"{f}_calibrated") for f in filter_names]
        return [e for e in ests if e.heading == "mag"], True
    rot = opts["board_rotation"]
    write_text_atomic(path, f'# {MARK} bench: the {label} row\n[mounting]\nsensor_rotation = "{rot}"\n')
    return [filter_estimator(f, config_file=str(path), label=f"{f}_mounted") for f in filter_names], False


def _estimators(filter_names, peer_names, with_baseline=True):
    ests, errors = [], {}
    for f in filter_names:
        try:   # a filter named like a peer (examples/madgwick beside ahrs' Madgwick) is labelled apart
            ests.append(filter_estimator(f, label=f"{f}_gen" if f in peer_names else None))
        except Exception as e:   # a filter still being written must not stop the bench
            errors[f] = f"{type(e).__name__}: {e}"
    if with_baseline and "qcf" in filter_names:
        ests.append(Estimator("qcf_hand", "baseline", "mag", "hand-written QCF (src/ahrsgen/sim/c/baseline_qcf.c)"))
    ests += [peer_estimator(p) for p in peer_names]
    return ests, errors


def _run_task(task):
    """One log (scenario seed or real file) through every estimator. Runs in a worker."""
    kind, label, arg, opts, seed, est_specs, want_series = task
    from ahrsgen.sim import scenarios
    t0 = time.perf_counter()
    c0 = time.process_time()
    if kind == "scenario":
        log = scenarios.make(arg, seed=seed, **opts)
    else:
        log = readers.read_log(arg)
    out = {"kind": kind, "label": label, "seed": seed, "log": log.name, "steps": len(log),
           "scores": {}, "errors": {}, "series": {}, "seconds": {}}
    for spec in est_specs:
        est = Estimator(**spec)
        t1 = time.perf_counter()
        try:
            q, heading, extra = est.run(log)
            out["scores"][est.name] = score(q, log, heading)
            if extra:
                out.setdefault("site", {})[est.name] = extra
            if want_series:
                t, e = total_error_series(q, log, heading)
                out["series"][est.name] = (t.tolist(), e.tolist())
        except Exception as e:
            out["errors"][est.name] = f"{type(e).__name__}: {e}"
        out["seconds"][est.name] = time.perf_counter() - t1
    out["wall"] = time.perf_counter() - t0
    out["cpu"] = time.process_time() - c0
    return out


def _spec(e: Estimator) -> dict:
    return {"name": e.name, "kind": e.kind, "heading": e.heading, "title": e.title, "filter": e.filter,
            "sets": list(e.sets), "config": e.config, "site": e.site}


class Progress:
    def __init__(self, total, stream=None):
        self.total, self.done, self._stream, self.t0 = total, 0, stream, time.time()

    @property
    def stream(self):
        """sys.stderr as it is now (a default bound at import is a stream pytest has closed)."""
        return self._stream if self._stream is not None else sys.stderr

    def update(self, what, done=None):
        """One more done (or `done` of the total, e.g. bytes of a file read so far)."""
        self.done = self.done + 1 if done is None else done
        frac = self.done / max(self.total, 1)
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        el = time.time() - self.t0
        self.stream.write(f"\r[{bar}] {self.done}/{self.total} {el:5.0f} s  {what[:50]:<50}")
        self.stream.flush()
        if self.done == self.total:
            self.stream.write("\n")


def _agg(values):
    a = np.asarray(values, dtype=float)
    return {"mean": float(np.mean(a)), "sd": float(np.std(a, ddof=1)) if len(a) > 1 else 0.0, "n": int(len(a))}


def _aggregate(results, group_key):
    groups = {}
    for r in results:
        for est, s in r["scores"].items():
            groups.setdefault(r[group_key], {}).setdefault(est, []).append(s)
    out = {}
    for g, ests in groups.items():
        out[g] = {}
        for est, lst in ests.items():
            out[g][est] = {k: _agg([s[k] for s in lst]) for k in lst[0] if k not in ("n", "nonfinite")}
            out[g][est]["nonfinite"] = int(sum(s["nonfinite"] for s in lst))
    return out


# the hand-written baseline implements SPEC.md's QCF: eq. 29's differentiator for the motion
# acceleration; the generated QCF is timed with that option too, so the ratio compares like with like
HAND_QCF_SETS = ["motion_accel_model=differentiator", "conditioning=false", "kp=0.3"]   # its KP


def _cpu_timer(hf):
    """ahrs_bench_cpu_ns_per_step of a filter's library built with bench_timing.c."""
    lib = ctypes.CDLL(str(host.compile_shared(hf.dir, extra_sources=[C_DIR / "bench_timing.c"])))
    fn = lib.ahrs_bench_cpu_ns_per_step
    fn.restype = ctypes.c_double
    fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32]
    return fn


def measure_cost(filter_names, log: SensorLog, repeats=7, passes=3) -> dict:
    """Ops per step (manifest), state bytes, host ns/step inside C, vs the hand-written QCF.

    Timed with this thread's CPU clock (src/ahrsgen/sim/c/bench_timing.c, built into the filter's
    shared library next to batch.c), so time spent descheduled on a busy machine does not
    count; the filters are timed in interleaved rounds and the median round is kept (the
    fastest round and batch.c's wall-clock median are in the JSON too).
    """
    from ahrsgen.generate import config
    cost, built = {}, {}
    entries = [(f, f, []) for f in filter_names]
    if "qcf" in filter_names:
        entries += [("qcf_eq29", "qcf", HAND_QCF_SETS), ("qcf_hand", None, [])]
    for label, f, sets in entries:
        try:
            hf = baseline_filter() if f is None else host.build(config.resolve(f, None, sets, "float", None))
            paths = hf.manifest.get("step_paths", {}) if f is not None else {}
            worst = max(paths.items(), key=lambda kv: kv[1]["total"]) if paths else None
            cost[label] = {
                "settings": sets,
                "state_bytes": int(hf.manifest["structs"]["state"]["size"]),
                "ops_worst_path": worst[0] if worst else None,
                "ops_total": int(worst[1]["total"]) if worst else None,
                "ops": worst[1]["ops"] if worst else None,
                "paths": {k: v["total"] for k, v in paths.items()},
            }
            built[label] = hf
        except Exception as e:
            cost[label] = {"error": f"{type(e).__name__}: {e}"}
    timers = {label: _cpu_timer(hf) for label, hf in built.items()}
    packed = {label: hf.pack(log) for label, hf in built.items()}
    samples = {label: [] for label in built}
    wall = {label: [] for label in built}
    for _ in range(repeats):
        for label, hf in built.items():
            inp, dt = packed[label]
            s0 = hf.new_state()
            samples[label].append(timers[label](ctypes.byref(s0), inp.ctypes.data, dt.ctypes.data, len(log), passes))
            wall[label].append(hf.time_ns_per_step(log, repeats=1, passes=passes))
    for label, v in samples.items():
        cost[label]["ns_per_step"] = float(np.median(v))
        cost[label]["ns_per_step_min"] = float(np.min(v))
        cost[label]["wall_ns_per_step_median"] = float(np.median(wall[label]))
        cost[label]["timing_rounds"] = len(v)
    hand = cost.get("qcf_hand", {}).get("ns_per_step")
    if hand:
        for label in ("qcf", "qcf_eq29"):
            if "ns_per_step" in cost.get(label, {}):
                cost[label]["ratio_to_hand_qcf"] = cost[label]["ns_per_step"] / hand
    return cost


def bench(quick=False, seeds=None, filters=None, peer_names=PEER_NAMES, data_dir=None, out_dir="bench_out",
          jobs=2, scenarios_only=False, real_only=False, scenario_labels=None, command="", variants=(),
          scheduler=None) -> dict:
    """Run the whole benchmark; writes bench.json, bench.md and img/*.png under out_dir.

    variants: (label, filter, [name=value, ...]) rows benchmarked beside the defaults, to
    compare gains or options of one filter in the same run.
    """
    t_start = time.time()
    out_dir = Path(out_dir)
    (out_dir / "img").mkdir(parents=True, exist_ok=True)
    filter_names = list(filters) if filters else product_filters()
    notes = []
    missing = [p for p in peer_names if not peers.PEERS[p].available()]
    if missing:   # the peers are optional (the `dev` extra): say which were left out
        notes.append("peers left out, their packages are not installed: "
                     + ", ".join(f"{p} ({peers.PEERS[p].package})" for p in missing)
                     + ": pip install 'ahrsgen[dev]'.")
        peer_names = tuple(p for p in peer_names if p not in missing)
    ests, build_errors = _estimators(filter_names, peer_names, with_baseline=False)
    for label, fname, vsets in variants:
        ests.append(filter_estimator(fname, list(vsets), label=label))
    filter_names = [f for f in filter_names if f not in build_errors]
    # compile everything once in the main process (workers then hit the cache)
    for e in ests:
        if e.kind != "peer":
            try:
                e.host_filter()
            except Exception as ex:
                build_errors[e.name] = f"{type(ex).__name__}: {ex}"
    ests = [e for e in ests if e.name not in build_errors]
    specs = [_spec(e) for e in ests]
    n_seeds = seeds if seeds is not None else (1 if quick else 3)

    ddir = readers.shared_data_dir(data_dir)
    env_dir = os.environ.get(readers.DATA_ENV)
    if data_dir is None and env_dir and not Path(env_dir).is_dir():
        notes.append(f"${readers.DATA_ENV} = {env_dir} is not a folder: ignored"
                     + (f" (used {ddir})." if ddir else "."))
    tasks = []
    if not real_only:
        for label, scen, opts in scenario_configs(quick):
            if scenario_labels and label not in scenario_labels:
                continue
            extra, with_defaults = row_estimators(label, scen, opts, filter_names, out_dir / "configs")
            for e in extra:
                try:
                    e.host_filter()
                    ests.append(e)
                except Exception as ex:
                    build_errors[e.name] = f"{type(ex).__name__}: {ex}"
            row_specs = (specs if with_defaults else []) + [_spec(e) for e in extra if e.name not in build_errors]
            for seed in range(n_seeds):
                tasks.append(("scenario", label, scen, opts, seed, row_specs, seed == 0))
    real = {"broad": [], "px4": []}
    if not scenarios_only:
        trials = readers.broad_trials(ddir) if ddir else []
        if quick or not trials:
            if not trials:
                notes.append("BROAD subset not found (looked in --data, $AHRSGEN_DATA, <repo>/../shared/data): "
                             "used the committed excerpt src/ahrsgen/sim/data/broad_01_excerpt.csv.gz only.")
            else:
                notes.append("--quick: BROAD scored on the committed excerpt only (src/ahrsgen/sim/data/broad_01_excerpt.csv.gz).")
            trials = [readers.EXCERPTS / "broad_01_excerpt.csv.gz"]
        # BROAD: product filters with a magnetometer heading, plus MEKF with its mag option
        broad_specs = [s for s in specs if s["heading"] == "mag" or s["kind"] == "peer"]
        if "mekf" in filter_names:
            try:
                broad_specs.append(_spec(filter_estimator("mekf", ["heading_source=mag"], label="mekf_mag")))
            except Exception as ex:
                build_errors["mekf_mag"] = f"{type(ex).__name__}: {ex}"
        for i, p in enumerate(trials):
            tasks.append(("broad", "BROAD", str(p), {}, 0, broad_specs, i == 0))
        ulogs = []
        if not _have("pyulog"):
            notes.append("PX4 logs left out: reading ULog needs pyulog: pip install 'ahrsgen[dev]'.")
        else:
            if ddir and (ddir / "px4").is_dir():
                ulogs = sorted((ddir / "px4").glob("*.ulg"))
            if quick or not ulogs:
                if not ulogs:
                    notes.append("PX4 logs not found: used the committed excerpts src/ahrsgen/sim/data/*.ulg.")
                ulogs = sorted(readers.EXCERPTS.glob("*.ulg"))
        for p in ulogs:
            tasks.append(("px4", p.stem, str(p), {}, 0, broad_specs, True))
        real["broad"] = [str(p) for p in trials]
        real["px4"] = [str(p) for p in ulogs]

    prog = Progress(len(tasks))
    results = []
    from ahrsgen.sim.fleet import Fleet
    # longest first so the workers finish together; a local pool or a Dask cluster (--scheduler)
    order = sorted(tasks, key=lambda t: 0 if t[0] == "broad" else 1)
    with Fleet(jobs, scheduler) as fleet:
        for r in fleet.map_unordered(_run_task, order):
            results.append(r)
            prog.update(f"{r['label']} {r['log']} seed {r['seed']}")
    # one order whatever the order they completed in (the means are summed in it)
    results.sort(key=lambda r: (r["kind"], r["label"], r["log"], r["seed"]))

    # cost: timed on the multirotor scenario (250 Hz, every sensor), seed 0
    from ahrsgen.sim import scenarios as sc
    cost_log = sc.make("multirotor", seed=0, duration=30.0 if quick else 60.0)
    cost = measure_cost(filter_names, cost_log, repeats=5 if quick else 15)

    scen = [r for r in results if r["kind"] == "scenario"]
    broad = [r for r in results if r["kind"] == "broad"]
    px4 = [r for r in results if r["kind"] == "px4"]
    report = {
        "command": command,
        "quick": quick,
        "seeds": n_seeds,
        "date_utc": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "host": _host_info(),
        "estimators": {e.name: {"kind": e.kind, "heading": e.heading, "title": e.title, "sets": e.sets}
                       for e in ests},
        "build_errors": build_errors,
        "notes": notes,
        "scenarios": _aggregate(scen, "label"),
        "scenario_options": {lbl: {"scenario": sc_name, **opts} for lbl, sc_name, opts in scenario_configs(quick)},
        "broad": {"trials": {r["log"]: r["scores"] for r in broad},
                  "mean": _aggregate(broad, "label").get("BROAD", {}), "files": real["broad"]},
        "px4": {r["label"]: r["scores"] for r in px4},
        "run_errors": {f"{r['label']}/{r['log']}/{r['seed']}": r["errors"] for r in results if r["errors"]},
        "site_sets": {f"{r['label']}/{r['log']}": r["site"] for r in results if r.get("site") and r["seed"] == 0},
        "cost": cost,
        "cost_log": f"multirotor seed 0, {len(cost_log)} steps (250 Hz, accel+mag+GPS)",
        "seconds": time.time() - t_start,
        "task_cpu_seconds": float(sum(r.get("cpu", 0.0) for r in results)),
        "task_wall_seconds": {f"{r['label']}/{r['log']}/{r['seed']}": round(r["wall"], 1) for r in results},
    }
    if _have("matplotlib"):
        report["plots"] = _plots(results, out_dir / "img")
    else:
        report["plots"] = {}
        notes.append("no plots: they need matplotlib: pip install 'ahrsgen[dev]'.")
    from ahrsgen.fileio import write_text_atomic     # whole files or none, also on Ctrl-C
    write_text_atomic(out_dir / "bench.json", json.dumps({"written_by": "ahrsgen bench", **report}, indent=1))
    write_text_atomic(out_dir / "bench.md", markdown(report) + "\n<!-- written by ahrsgen bench -->\n")
    return report


def _have(module: str) -> bool:
    """Whether an optional package (the `dev` extra) is installed."""
    import importlib.util
    return importlib.util.find_spec(module) is not None


def _host_info():
    import platform
    info = {"machine": platform.machine(), "python": platform.python_version()}
    try:
        info["cc"] = host._compiler_id().splitlines()[0]
    except Exception:
        pass
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return info


