"""Reproduce the paper's two experiments with the generated C (host build) and draw what the
adaptive weights do. `python -m studies.adukf_repro [--seeds 5] [--png docs/img/...]`
prints the Markdown tables used in docs/adukf.md.

DUKF = the same generated filter with k_a = k_m = 0 and accel_gate = 0 (R fixed); A-DUKF = the defaults (tuned once on
seed 0 of both scenarios). Errors: RMS over the whole 120 s run (the filter starts on the
sensors; no settling time is skipped), degrees, per Euler angle.
"""
from __future__ import annotations

import argparse

import numpy as np

from ahrsgen.sim import host, metrics
from ahrsgen.sim.scenarios import make
from ahrsgen.generate import config

PAPER = {
    "static_accel_disturbance": {"DUKF": (0.8147, 1.0256, 0.3823), "A-DUKF": (0.0570, 0.1533, 0.0435)},
    "static_mag_disturbance": {"DUKF": (0.9475, 0.9804, 3.9198), "A-DUKF": (0.0168, 0.0195, 0.2051)},
}
# DUKF: R fixed (no residual adaptation, no accelerometer gate: both adapt R to the measurement)
VARIANTS = {"DUKF": ["k_a=0", "k_m=0", "accel_gate=0"], "A-DUKF": []}
# The paper's site (Xi'an), where both experiments are simulated: the product default learns the
# dip and leaves the declination 0 (issue 27), which would score the site's declination as yaw
# error; as tests/filters/adukf/test_adukf.py, the builds are told the site.
SITE = ["mag_ref=inclination", "inclination_deg=53.0", "declination=-0.061086523819801536"]
ANGLES = ("roll", "pitch", "yaw")


def rms_table(seeds=(0,), precision="float"):
    """{scenario: {variant: (N seeds, 3) RMS array}}."""
    out = {}
    for sc in PAPER:
        out[sc] = {}
        for v, sets in VARIANTS.items():
            hf = host.build(config.resolve("adukf", sets=SITE + sets, precision=precision))
            rows = []
            for seed in seeds:
                log = make(sc, seed=seed)
                s = metrics.euler_stats(hf.run(log).q, log.q_true, log.t, 0.0)
                rows.append([s[a]["rms"] for a in ANGLES])
            out[sc][v] = np.array(rows)
    return out


def markdown(tab, seeds):
    lines = ["| case | filter | ours: roll / pitch / yaw RMS (°) | paper: roll / pitch / yaw RMS (°) |",
             "|---|---|---|---|"]
    for sc, rows in tab.items():
        case = "external acceleration" if "accel" in sc else "magnetic disturbance"
        for v, arr in rows.items():
            m = arr.mean(axis=0)
            ours = " / ".join(f"{x:.3f}" for x in m)
            if len(seeds) > 1:
                ours += " (seeds " + ", ".join(map(str, seeds)) + ": mean)"
            paper = " / ".join(f"{x:.4f}" for x in PAPER[sc][v])
            lines.append(f"| {case} (`{sc}`) | {v} | {ours} | {paper} |")
    lines += ["", "| case | improvement DUKF → A-DUKF, ours (roll / pitch / yaw) | paper |", "|---|---|---|"]
    for sc, rows in tab.items():
        f = rows["DUKF"].mean(axis=0) / rows["A-DUKF"].mean(axis=0)
        fp = np.array(PAPER[sc]["DUKF"]) / np.array(PAPER[sc]["A-DUKF"])
        lines.append(f"| `{sc}` | " + " / ".join(f"{x:.0f}×" for x in f) + " | "
                     + " / ".join(f"{x:.0f}×" for x in fp) + " |")
    return "\n".join(lines)


def trace(log, sets):
    """Step the double C build through a log: (q (N,4), R diagonal (N,6))."""
    hf = host.build(config.resolve("adukf", sets=SITE + list(sets), precision="double"))
    s = hf.new_state()
    q = np.empty((len(log), 4))
    r = np.empty((len(log), 6))
    for k in range(len(log)):
        hf.step(s, log.gyro[k], log.accel[k], log.mag[k], log.gps_vel[k], int(log.valid[k]), float(log.dt[k]))
        d = hf.state_dict(s)
        q[k], r[k] = d["q"], d["r_diag"]
    return q, r


def plot(path, seed=0):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(3, 2, figsize=(13, 9), sharex=True)
    for col, sc in enumerate(PAPER):
        log = make(sc, seed=seed)
        qa, ra = trace(log, [])
        qp, _ = trace(log, VARIANTS["DUKF"])
        ea = np.abs(metrics.euler_errors_deg(qa, log.q_true))
        ep = np.abs(metrics.euler_errors_deg(qp, log.q_true))
        sensor = "accel" if "accel" in sc else "mag"
        ivs = log.meta[f"{sensor}_offsets"]
        for ax in axes[:, col]:
            for t0, t1, off in ivs:
                ax.axvspan(t0, t1, color="0.9", zorder=0)
        for i, (a, c) in enumerate(zip(ANGLES, ("C0", "C1", "C2"))):
            axes[0, col].plot(log.t, ep[:, i], c, lw=0.8, label=f"DUKF {a}")
            axes[1, col].plot(log.t, ea[:, i], c, lw=0.8, label=f"A-DUKF {a}")
        base = ra[ra[:, 0] > 0, 0].min() if sensor == "accel" else ra[ra[:, 3] > 0, 3].min()
        off = 0 if sensor == "accel" else 3
        for i, (a, c) in enumerate(zip("xyz", ("C0", "C1", "C2"))):
            axes[2, col].semilogy(log.t, ra[:, off + i] / base, c, lw=0.8, label=f"R_{sensor},{a} / σ²")
        axes[0, col].set_title(sc)
        axes[0, col].set_ylabel("|error| DUKF (°)")
        axes[1, col].set_ylabel("|error| A-DUKF (°)")
        axes[2, col].set_ylabel(f"adaptive R / σ² ({sensor})")
        axes[2, col].set_xlabel("t (s)")
        for ax in axes[:, col]:
            ax.legend(fontsize=7, loc="upper right", ncol=3)
            ax.grid(alpha=0.3)
    fig.suptitle("A-DUKF vs DUKF (generated C, double) on the static scenarios after the paper; "
                 "grey = injected constant offset")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1, help="number of seeds (0..n-1) to average")
    ap.add_argument("--precision", default="float")
    ap.add_argument("--png", default=None, help="write the adaptive-weight plot here")
    a = ap.parse_args(argv)
    seeds = tuple(range(a.seeds))
    print(markdown(rms_table(seeds, a.precision), seeds))
    if a.png:
        plot(a.png)
        print(f"\nwrote {a.png}")


if __name__ == "__main__":
    main()
