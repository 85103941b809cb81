"""BROAD figure for docs/mekf.md (run: .venv/bin/python docs/mekf_broad_figure.py [DATA_DIR]).

Runs the generated float C of the MEKF defaults (site parameter declination = 0, as
`ahrsgen run` sets for BROAD) over the BROAD trials, scores them with BROAD's method, prints
the per-trial table and writes docs/mekf_broad.png: total error over time on trial 32 (magnet
attached) with and without the magnetic disturbance rejection, and on trial 15 (fast
translation) with and without the earth-frame low-pass.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ahrsgen import bench
from ahrsgen.sim import host, readers
from ahrsgen.generate import config

OUT = Path(__file__).resolve().parent


def build(sets=()):
    return host.build(config.resolve("mekf", sets=["declination=0.0", *sets], precision="float"))


def main():
    ddir = readers.shared_data_dir(sys.argv[1] if len(sys.argv) > 1 else None)
    trials = readers.broad_trials(ddir) if ddir else []
    if not trials:
        sys.exit("BROAD trials not found (give the data directory)")
    hf = build()
    print("| trial | total | heading | inclination |\n|---|---|---|---|")
    tot = []
    for p in trials:
        log = readers.read_log(p)
        s = bench.score(hf.run(log).q, log, "mag")
        tot.append(s["total_rms"])
        print(f"| {p.name.split('.')[0]} | {s['total_rms']:.2f} | {s['heading_rms']:.2f} | {s['inclination_rms']:.2f} |")
    print(f"mean of {len(tot)}: {np.mean(tot):.2f}")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=False)
    panels = [("32_", "trial 32, magnet attached", [("defaults", []), ("no rejection (mag_norm_th = 0)", ["mag_norm_th=0"])]),
              ("15_", "trial 15, fast translation", [("defaults", []), ("no low-pass (accel_lpf_tau = 0)", ["accel_lpf_tau=0"])])]
    for ax, (prefix, title, cfgs) in zip(axes, panels):
        p = next(t for t in trials if t.name.startswith(prefix))
        log = readers.read_log(p)
        for label, sets in cfgs:
            t, e = bench.total_error_series(build(sets).run(log).q, log, "mag")
            ax.plot(t, e, lw=0.8, label=label)
        ax.set_title(title)
        ax.set_ylabel("total error (deg)")
        ax.set_ylim(bottom=0)
        ax.legend(loc="upper left")
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(OUT / "mekf_broad.png", dpi=90)
    print(f"wrote {OUT / 'mekf_broad.png'}")


if __name__ == "__main__":
    main()
