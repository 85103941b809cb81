"""Writes the figure tables of docs/mekf.md, docs/adukf.md and docs/qcf.md, each between a line
`<!-- filter_doc.py: NAME -->` and `<!-- end filter_doc.py -->` (studies/doc_blocks.py):

    PYTHONPATH=src .venv/bin/python -m studies.filter_doc mekf      # every block of docs/mekf.md
    PYTHONPATH=src .venv/bin/python -m studies.filter_doc adukf     # every block of docs/adukf.md
    PYTHONPATH=src .venv/bin/python -m studies.filter_doc qcf       # every block of docs/qcf.md

- `params`: the defaults the doc discusses, from the filter's defaults.toml;
- `scenarios`: total RMS (deg, mean over seeds 0-2, float C, scored as `ahrsgen bench` scores:
  after the scenario's settle time, the site parameters set from the log) on the bench's
  scenarios (its row names, `ahrsgen.bench.grid.scenario_configs`), at the defaults and with the
  settings each row names;
- `broad`: BROAD's 10 development trials at the defaults (total / heading / inclination RMSE,
  movement phase), and the mean with the IMU averaged to a lower rate (`SensorLog.averaged`);
  written only when the BROAD files are present (../shared/data/broad or $AHRSGEN_DATA);
- `cost`: the operations of each step path in the default float build's manifest;
- `paper` (adukf): the paper's two experiments, DUKF against A-DUKF, beside its figures.

tests/filters/test_filter_docs.py re-measures every figure of these blocks with the functions below
(host C is deterministic: equal to the last digit written).
"""
from __future__ import annotations

import sys
import tomllib
from functools import cache
from pathlib import Path

import numpy as np

from studies.doc_blocks import ROOT, replace_block

WRITER = "filter_doc.py"
SEEDS = (0, 1, 2)
RATES = {"286 Hz": 1, "averaged to 143 Hz": 2, "averaged to 95 Hz": 3, "averaged to 48 Hz": 6}
FILTERS = ROOT / "src" / "ahrsgen" / "filters"

# rows of the `scenarios` block: (bench row, settings); "" = the defaults, "preset NAME" = the
# filter's presets/NAME.toml, else `--set` strings separated by ", "
SCENARIO_ROWS = {
    "mekf": [
        ("fixedwing_gps", ""), ("fixedwing_gps", "motion_comp=centripetal"),
        ("fixedwing_gps", "motion_comp=centripetal, accel_angle_noise=0.07"),
        ("fixedwing_gps", "preset faithful"), ("fixedwing_gps_100hz", ""),
        ("multirotor", ""), ("multirotor", "heading_source=gps_course"),
        ("multirotor_400hz", ""), ("multirotor_400hz", "accel_lpf_warm=false"),
        ("multirotor_400hz_repeated", ""),
        ("multirotor_1khz", ""), ("multirotor_1khz", "accel_lpf_warm=false"),
        ("multirotor_1khz", "accel_angle_noise=0.07, accel_noise_density=0"),
        ("multirotor_1khz", "accel_bias_gain=0"),
        ("multirotor_jitter_dropouts", ""), ("static_accel_disturbance", ""),
        ("static_mag_disturbance", ""), ("turntable", ""),
        ("gyro_clip", ""), ("gyro_clip", "gyro_full_scale=0"),
        ("attached_magnet", ""), ("attached_magnet", "mag_bias=false"), ("handheld", ""),
    ],
    "adukf": [
        ("fixedwing_gps_100hz", ""), ("fixedwing_gps_100hz", "motion_accel_model=none"),
        ("fixedwing_gps_100hz", "motion_accel_model=none, accel_tau_unaided=0, sigma_acc_density_unaided=0, accel_gate=0"),
        ("multirotor", ""), ("multirotor", "motion_accel_model=none"),
        ("multirotor", "motion_accel_model=none, accel_tau_unaided=0, sigma_acc_density_unaided=0, accel_gate=0"),
        ("multirotor", "k_a=0, k_m=0, accel_gate=0"),
        ("multirotor_400hz", ""), ("multirotor_400hz", "motion_accel_model=none"), ("multirotor_400hz_repeated", ""),
        ("multirotor_1khz", ""), ("multirotor_1khz", "motion_accel_model=none"),
        ("multirotor_1khz", "accel_lp_warm=false"),
        ("multirotor_1khz", "sigma_acc_density=0, sigma_mag_density=0"),
        ("multirotor_jitter_dropouts", ""),
        ("static_accel_disturbance", ""), ("static_accel_disturbance", "k_a=0, k_m=0, accel_gate=0"),
        ("static_mag_disturbance", ""), ("static_mag_disturbance", "k_a=0, k_m=0, accel_gate=0"),
        ("turntable", ""), ("turntable", "preset faithful"), ("turntable", "accel_tau_unaided=0, sigma_acc_density_unaided=0, accel_gate=0"),
        ("gyro_clip", ""), ("gyro_clip", "gyro_full_scale=0"),
        ("attached_magnet", ""), ("attached_magnet", "mag_bias=false"), ("handheld", ""),
    ],
    "qcf": [
        ("fixedwing_gps", ""), ("fixedwing_gps", "preset faithful"), ("fixedwing_gps", "rest_time=0"),
        ("fixedwing_gps", "motion_accel_model=centripetal"),
        ("fixedwing_gps_100hz", ""), ("multirotor", ""), ("multirotor", "conditioning=false"),
        ("multirotor", "motion_accel_model=centripetal"),
        ("multirotor", "kp_gps=0.25"),
        ("multirotor_400hz", ""), ("multirotor_400hz_repeated", ""), ("multirotor_1khz", ""),
        ("multirotor_1khz", "accel_lp_warm=false"),
        ("multirotor_jitter_dropouts", ""), ("static_accel_disturbance", ""),
        ("static_mag_disturbance", ""), ("static_mag_disturbance", "mag_rejection=false"),
        ("turntable", ""), ("turntable", "rest_time=0"),
        ("gyro_clip", ""), ("gyro_clip", "gyro_full_scale=0"),
        ("attached_magnet", ""), ("attached_magnet", "mag_bias=false"), ("handheld", ""),
    ],
}

# rows of the `params` block
PARAMS = {
    "mekf": ["measurement", "heading_source", "motion_comp", "gyro_noise", "gyro_rate_noise",
             "gyro_bias_rw", "accel_angle_noise", "accel_noise_density", "accel_bias_gain", "accel_lpf_tau",
             "accel_lpf_warm", "accel_adapt_cap", "accel_adapt_sigmas", "course_noise", "course_max_sideslip",
             "gps_min_speed", "gps_vel_timeout", "accel_tilt_noise", "mag_heading_noise", "mag_heading_density", "mag_norm_th",
             "mag_dip_th", "mag_learn_time", "mag_ref_tau", "mag_new_time", "mag_reject_max",
             "mag_bias", "mag_bias_rw", "mag_bias_noise", "mag_bias_min_rate", "mag_bias_settle",
             "mag_bias_th", "mag_bias_jump", "mag_bias_max", "rest_tau", "rest_min_time",
             "rest_gyro_th", "rest_accel_th", "gyro_full_scale", "gyro_plateau_rate",
             "clip_recovery_time", "p0_att", "p0_bias"],
    "adukf": ["attitude_state", "gyro_bias_state", "gyro_noise", "q_floor", "bias_rw",
              "sigma_acc", "sigma_acc_density", "sigma_mag", "sigma_mag_density", "k_a", "k_m",
              "adapt_max", "accel_tau", "accel_lp_warm", "motion_accel_model", "gps_timeout", "span_max", "mag_ref", "learn_samples", "mag_bias",
              "mag_bias_jump", "mag_bias_rw", "mag_norm_tol", "gyro_full_scale",
              "gyro_plateau_rate", "clip_recovery_time", "p0", "p0_bias"],
    "qcf": ["kp", "ki", "kp_gps", "gps_compensation", "motion_accel_model", "conditioning", "accel_tau",
            "accel_lp_warm", "bias_accel_gate", "rest_time", "rest_tau", "rest_gyro_tol", "rest_turn", "rest_accel_tol",
            "rest_bias_tau", "mag_rejection", "mag_norm_tol", "mag_dip_tol", "mag_warmup",
            "mag_ref_tau", "mag_new_time", "mag_bias", "mag_bias_jump", "mag_bias_rw",
            "centripetal_align", "span_max", "gyro_full_scale", "gyro_plateau_rate",
            "clip_recovery_time", "kp_recovery"],
}


def defaults(name: str) -> dict:
    return tomllib.loads((FILTERS / name / "defaults.toml").read_text())["params"]


def fmt_value(v) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, str):
        return f'"{v}"'
    return repr(v)


def params_table(name: str) -> list[str]:
    p = defaults(name)
    lines = ["| parameter | default | unit |", "|---|---|---|"]
    for k in PARAMS[name]:
        lines.append(f"| `{k}` | {fmt_value(p[k]['default'])} | {p[k].get('unit', '')} |")
    return lines


@cache
def grid() -> dict[str, tuple[str, dict]]:
    from ahrsgen.bench.grid import scenario_configs
    return {label: (scen, opts) for label, scen, opts in scenario_configs(quick=False)}


@cache
def estimator(name: str, settings: str):
    from ahrsgen.bench.scoring import filter_estimator
    parts = [s for s in settings.split(", ") if s]
    config = None
    if parts and parts[0].startswith("preset "):
        config = str(FILTERS / name / "presets" / f"{parts.pop(0).split()[1]}.toml")
    return filter_estimator(name, sets=parts, config_file=config)


@cache
def scenario_log(row: str, seed: int):
    from ahrsgen.sim import scenarios
    scen, opts = grid()[row]
    return scenarios.make(scen, seed=seed, **opts)


def scenario_rms(name: str, row: str, settings: str, seeds=SEEDS) -> float:
    """Mean total RMS (deg) over `seeds` of `name` with `settings` on the bench row `row`."""
    from ahrsgen.bench.scoring import score
    est = estimator(name, settings)
    totals = []
    for seed in seeds:
        log = scenario_log(row, seed)
        q, heading, _ = est.run(log)
        totals.append(score(q, log, heading)["total_rms"])
    return float(np.mean(totals))


def scenarios_table(name: str) -> list[str]:
    lines = ["| scenario (bench row) | settings | total RMS, deg |", "|---|---|---|"]
    for row, settings in SCENARIO_ROWS[name]:
        lines.append(f"| `{row}` | {settings or 'defaults'} | {scenario_rms(name, row, settings):.2f} |")
    return lines


@cache
def broad_logs() -> dict[str, object]:
    from ahrsgen.sim import readers
    return {p.name.split("_")[0]: readers.read_log(p) for p in readers.broad_trials()}


def broad_scores(name: str, k: int = 1) -> dict[str, dict]:
    """Trial number -> BROAD's figures of `name`'s defaults, the IMU averaged over k rows."""
    from ahrsgen.bench.scoring import score
    est = estimator(name, "")
    out = {}
    for trial, log in broad_logs().items():
        lg = log.averaged(k) if k > 1 else log
        q, heading, _ = est.run(lg)
        out[trial] = score(q, lg, heading)
    return out


def broad_tables(name: str) -> list[str]:
    s = broad_scores(name)
    lines = ["| trial | total | heading | inclination |", "|---|---|---|---|"]
    for trial, log in broad_logs().items():
        label = log.name.split(".")[0].removeprefix(trial + "_").replace("_", " ")
        f = s[trial]
        lines.append(f"| {trial} {label} | {f['total_rms']:.2f} | {f['heading_rms']:.2f} | {f['inclination_rms']:.2f} |")
    mean = {k: np.mean([f[k] for f in s.values()]) for k in ("total_rms", "heading_rms", "inclination_rms")}
    lines.append(f"| mean of {len(s)} | {mean['total_rms']:.2f} | {mean['heading_rms']:.2f} | {mean['inclination_rms']:.2f} |")
    lines += ["", "Mean total RMSE with the IMU at a lower rate (every k rows averaged into one, as an "
              "integrating IMU reports them):", "", "| BROAD | mean total RMSE, deg |", "|---|---|"]
    for label, k in RATES.items():
        lines.append(f"| {label} | {np.mean([f['total_rms'] for f in broad_scores(name, k).values()]):.2f} |")
    return lines


@cache
def manifest(name: str) -> dict:
    from ahrsgen.generate import config
    from ahrsgen.sim import host
    return host.build(config.resolve(name, precision="float")).manifest


OPS = ("add", "mul", "div", "sqrt", "trig", "cmp")


def cost_table(name: str) -> list[str]:
    lines = ["| step path | " + " | ".join(OPS) + " | total |", "|---|" + "---|" * (len(OPS) + 1)]
    for path, p in manifest(name)["step_paths"].items():
        lines.append(f"| {path} | " + " | ".join(str(p["ops"].get(o, 0)) for o in OPS) + f" | {p['total']} |")
    return lines


PAPER_SEEDS = tuple(range(5))


def paper_tables() -> list[str]:
    """adukf: the paper's two experiments, DUKF (k_a = k_m = 0) and A-DUKF (the defaults), RMS
    over the whole run (studies/adukf_repro.py's measurement) beside the paper's figures."""
    from studies import adukf_repro as repro
    tab = repro.rms_table(seeds=PAPER_SEEDS)
    lines = ["| scenario | filter | ours: roll / pitch / yaw RMS, deg | paper |", "|---|---|---|---|"]
    for sc, rows in tab.items():
        for v, arr in rows.items():
            ours = " / ".join(f"{x:.3f}" for x in arr.mean(axis=0))
            lines.append(f"| `{sc}` | {v} | {ours} | " + " / ".join(f"{x:.4f}" for x in repro.PAPER[sc][v]) + " |")
    lines += ["", "| scenario | DUKF / A-DUKF, ours: roll / pitch / yaw | paper |", "|---|---|---|"]
    for sc, rows in tab.items():
        f = rows["DUKF"].mean(axis=0) / rows["A-DUKF"].mean(axis=0)
        fp = np.array(repro.PAPER[sc]["DUKF"]) / np.array(repro.PAPER[sc]["A-DUKF"])
        lines.append(f"| `{sc}` | " + " / ".join(f"{x:.0f}×" for x in f) + " | " + " / ".join(f"{x:.0f}×" for x in fp) + " |")
    return lines


def main(argv: list[str]) -> int:
    if len(argv) != 1 or argv[0] not in SCENARIO_ROWS:
        sys.exit(__doc__)
    name = argv[0]
    doc = ROOT / "docs" / f"{name}.md"
    replace_block(doc, WRITER, "params", params_table(name))
    replace_block(doc, WRITER, "cost", cost_table(name))
    replace_block(doc, WRITER, "scenarios", scenarios_table(name))
    if name == "adukf":
        replace_block(doc, WRITER, "paper", paper_tables())
    if broad_logs():
        replace_block(doc, WRITER, "broad", broad_tables(name))
    else:
        print("BROAD files not found: the broad block is left as it is", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
