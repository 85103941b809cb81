"""Figures and numbers for docs/mekf.md (run: .venv/bin/python docs/mekf_figures.py).

Runs the generated float C (host build) of several MEKF configurations and of the QCF on
fixedwing_gps (seed 0, 80 ms), prints the RMS table and writes docs/mekf_fixedwing.png.
"""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from ahrsgen.sim import host
from ahrsgen.sim.log import VALID_GPS
from ahrsgen.sim.metrics import euler_errors_deg, euler_stats
from ahrsgen.sim.scenarios import make
from ahrsgen.generate import config

OUT = Path(__file__).resolve().parent

CONFIGS = [
    ("MEKF defaults (GPS course, centripetal comp.)", "mekf", []),
    ("MEKF as the patent (no motion compensation)", "mekf", ["motion_comp=none"]),
    ("MEKF, motion_comp = gps_accel", "mekf", ["motion_comp=gps_accel"]),
    ("MEKF, magnetometer heading (decl. -4 deg)", "mekf", ["heading_source=mag", "declination=-0.06981317007977318"]),
    ("QCF defaults (FQA acc+mag, GPS accel comp., decl. -4 deg)", "qcf", ["declination=-0.06981317007977318"]),
]


def run(filt, sets, log):
    return host.build(config.resolve(filt, sets=sets, precision="float")).run(log)


def main():
    log = make("fixedwing_gps", 0)
    rows, errs = [], {}
    for name, filt, sets in CONFIGS:
        r = run(filt, sets, log)
        s = euler_stats(r.q, log.q_true, log.t, log.settle_time)
        rows.append((name, s))
        errs[name] = euler_errors_deg(r.q, log.q_true)
    print("| filter (float C, fixedwing_gps seed 0, 80 ms, after 10 s) | roll RMS | pitch RMS | yaw RMS | roll / pitch / yaw max |")
    print("|---|---|---|---|---|")
    for name, s in rows:
        print(f"| {name} | {s['roll']['rms']:.2f} | {s['pitch']['rms']:.2f} | {s['yaw']['rms']:.2f} | "
              f"{s['roll']['max_abs']:.2f} / {s['pitch']['max_abs']:.2f} / {s['yaw']['max_abs']:.2f} |")

    # GPS outage 200-260 s
    lo = copy.deepcopy(log)
    out = (lo.t >= 200) & (lo.t < 260)
    lo.valid[out] &= ~np.uint32(VALID_GPS)
    e_out = euler_errors_deg(run("mekf", [], lo).q, lo.q_true)
    print("outage 200-260 s: max |error| during (roll, pitch, yaw):", np.abs(e_out[out]).max(0).round(2),
          " 290-320 s:", np.abs(e_out[(lo.t >= 290) & (lo.t < 320)]).max(0).round(2))

    # multirotor (250 Hz, hover + aggressive manoeuvres): the GPS course is no heading there
    ml = make("multirotor", 0)
    print("| multirotor (float C, seed 0, after settle) | roll RMS | pitch RMS | yaw RMS |")
    print("|---|---|---|---|")
    for name, filt, sets in [
            ("MEKF, mag heading, centripetal", "mekf", ["heading_source=mag"]),
            ("MEKF, mag heading, gps_accel", "mekf", ["heading_source=mag", "motion_comp=gps_accel"]),
            ("MEKF defaults (GPS course)", "mekf", []),
            ("QCF defaults", "qcf", [])]:
        s = euler_stats(run(filt, sets, ml).q, ml.q_true, ml.t, ml.settle_time)
        print(f"| {name} | {s['roll']['rms']:.2f} | {s['pitch']['rms']:.2f} | {s['yaw']['rms']:.2f} |")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(4, 1, figsize=(10, 10), sharex=True)
    t = log.t
    truth = np.degrees(np.unwrap(np.stack([np.arctan2(2 * (log.q_true[:, 0] * log.q_true[:, 1] + log.q_true[:, 2] * log.q_true[:, 3]),
                                                      1 - 2 * (log.q_true[:, 1] ** 2 + log.q_true[:, 2] ** 2))], 1), axis=0))
    axes[0].plot(t, truth[:, 0], "k", lw=0.8)
    axes[0].set_ylabel("true roll, deg")
    for i, ang in enumerate(("roll", "pitch", "yaw")):
        ax = axes[i + 1]
        for name, _, _ in CONFIGS[:2] + CONFIGS[4:]:
            ax.plot(t, errs[name][:, i], lw=0.7, label=name)
        ax.plot(t, e_out[:, i], lw=0.7, ls="--", label="MEKF defaults, GPS lost 200-260 s")
        ax.set_ylabel(f"{ang} error, deg")
        ax.set_ylim(-15, 15)
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("t, s")
    fig.suptitle("fixedwing_gps (seed 0, 80 ms): attitude error of the generated float C")
    fig.tight_layout()
    fig.savefig(OUT / "mekf_fixedwing.png", dpi=80)
    print("wrote", OUT / "mekf_fixedwing.png")


if __name__ == "__main__":
    main()
