"""The benchmark's report: error plots and bench.md."""
from __future__ import annotations

import io
from pathlib import Path

from ahrsgen.bench.common import ANGLES, BROAD_METRICS, PEER_NAMES


def _plots(results, img_dir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from ahrsgen.fileio import write_atomic
    files = {}
    for r in results:
        if not r["series"]:
            continue
        key = r["label"] if r["kind"] != "broad" else f"broad_{r['log']}"
        fig, ax = plt.subplots(figsize=(10, 4))
        for est, (t, e) in sorted(r["series"].items()):
            ax.plot(t, e, lw=0.8, label=est, ls="-" if est not in PEER_NAMES else "--")
        ax.set_yscale("log")
        ax.set_ylim(1e-2, 180)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("total attitude error [deg]")
        ax.set_title(f"{r['label']}: {r['log']} (seed {r['seed']})")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, ncol=4, loc="upper right")
        fig.tight_layout()
        p = Path(img_dir) / f"err_{key}.png"
        buf = io.BytesIO()
        fig.savefig(buf, dpi=100, format="png", metadata={"Software": "written by ahrsgen bench"})
        write_atomic(p, buf.getvalue())
        plt.close(fig)
        files[key] = f"img/{p.name}"      # relative to the output folder
    return files


def _pm(a, digits=2):
    if a["n"] > 1:
        return f"{a['mean']:.{digits}f} ± {a['sd']:.{digits}f}"
    return f"{a['mean']:.{digits}f}"


def markdown(rep: dict) -> str:
    L = []
    L.append("# ahrsgen bench results\n")
    if rep.get("command"):
        L.append(f"Command: `{rep['command']}`  ")
    L.append(f"Date: {rep['date_utc']}; host: {rep['host'].get('cpu', rep['host'].get('machine'))}; "
             f"{rep['host'].get('cc', '')}; run time {rep['seconds']:.0f} s wall "
             f"({rep.get('task_cpu_seconds', 0):.0f} s CPU in the workers).\n")
    for n in rep["notes"]:
        L.append(f"> {n}\n")
    if rep["build_errors"]:
        L.append("Filters left out (did not build): " +
                 "; ".join(f"`{k}`: {v.splitlines()[0][:160]}" for k, v in rep["build_errors"].items()) + "\n")
    L.append("Errors in degrees. Generated filters run as float C through the firmware harness with their "
             "default gains; the site parameters (declination; inclination, or learning it at rest when "
             "the log gives none) are set from each log as a user would for where they fly. Peers run "
             "through their Python packages (PEERS.md conventions) and their magnetic heading is "
             "rotated by the log's declination. Filters without a heading source are scored after "
             "removing one constant heading offset. "
             "`total / heading / incl.` is BROAD's decomposition of the earth-frame error.\n")
    # cost
    L.append("## Cost per step\n")
    L.append(f"ns/step: host C (`{rep['host'].get('cc', 'cc')}`, -O2), measured inside C over "
             f"{rep['cost_log']}, thread CPU time, median of interleaved rounds. Ops: the most expensive step path in the manifest. "
             "`qcf_hand` is `src/ahrsgen/sim/c/baseline_qcf.c`, SPEC.md's QCF written by hand (eq. 29 "
             "differentiator); `qcf_eq29` is the generated QCF with the same option "
             "(`motion_accel_model=differentiator`), the like-for-like comparison; `qcf` is the "
             "generated default (centripetal model).\n")
    L.append("| filter | ns/step | vs hand-written QCF | ops/step (worst path) | add / mul / div / sqrt / trig | state bytes |")
    L.append("|---|---|---|---|---|---|")
    for f, c in rep["cost"].items():
        if "error" in c:
            L.append(f"| {f} | error: {c['error'].splitlines()[0][:80]} | | | | |")
            continue
        ratio = c.get("ratio_to_hand_qcf")
        rtxt = f"{ratio:.2f}×" if ratio else ("1 (baseline)" if f == "qcf_hand" else "")
        ops = c["ops"]
        optxt = " / ".join(str(ops.get(k, 0)) for k in ("add", "mul", "div", "sqrt", "trig")) if ops else "hand-written"
        L.append(f"| {f} | {c['ns_per_step']:.0f} | {rtxt} | {c['ops_total'] or ''}"
                 f"{' (' + c['ops_worst_path'] + ')' if c['ops_worst_path'] else ''} | {optxt} | {c['state_bytes']} |")
    L.append("")
    # scenarios
    if rep["scenarios"]:
        L.append(f"## Simulated scenarios (mean ± sd over {rep['seeds']} seed(s))\n")
        for scen, ests in rep["scenarios"].items():
            opts = rep["scenario_options"].get(scen) or {}
            L.append(f"### {scen}" + (f" ({', '.join(f'{k}={v}' for k, v in opts.items())})" if opts else "") + "\n")
            L.append("| estimator | roll RMS | pitch RMS | yaw RMS | roll mean\\|e\\| | pitch mean\\|e\\| | yaw mean\\|e\\| "
                     "| total RMS | heading RMS | incl. RMS |")
            L.append("|---|---|---|---|---|---|---|---|---|---|")
            for est, m in sorted(ests.items(), key=lambda kv: kv[1]["total_rms"]["mean"]):
                row = [est] + [_pm(m[f"{a}_rms"]) for a in ANGLES] + [_pm(m[f"{a}_mean_abs"]) for a in ANGLES]
                row += [_pm(m[f"{b}_rms"]) for b in BROAD_METRICS]
                flag = " (diverged rows)" if m.get("nonfinite") else ""
                L.append("| " + " | ".join(row) + flag + " |")
            img = rep.get("plots", {}).get(scen)
            if img:
                L.append(f"\nError over time (seed 0): ![{scen}]({img})")
            L.append("")
    # BROAD
    if rep["broad"]["mean"]:
        nt = len(rep["broad"]["trials"])
        L.append(f"## BROAD (BROAD's method, {nt} trial(s))\n")
        L.append("RMSE over the movement phase with a finite optical reference; one parameter set for all "
                 "trials (filter defaults; Madgwick β 0.12, Mahony Kp 0.74 / Ki 0.0012, Fusion and VQF "
                 "defaults). Data: Laidig et al., *Data* 2021, 6(7), 72 (CC BY 4.0).\n")
        L.append("| estimator | total RMSE | heading RMSE | inclination RMSE |")
        L.append("|---|---|---|---|")
        for est, m in sorted(rep["broad"]["mean"].items(), key=lambda kv: kv[1]["total_rms"]["mean"]):
            L.append(f"| {est} | {m['total_rms']['mean']:.2f} | {m['heading_rms']['mean']:.2f} | "
                     f"{m['inclination_rms']['mean']:.2f} |")
        L.append("")
        if nt > 1:
            ests = sorted(rep["broad"]["mean"])
            L.append("Total RMSE per trial:\n")
            L.append("| trial | " + " | ".join(ests) + " |")
            L.append("|---|" + "---|" * len(ests))
            for trial, sc in sorted(rep["broad"]["trials"].items()):
                L.append(f"| {trial} | " + " | ".join(
                    f"{sc[e]['total_rms']:.2f}" if e in sc else "–" for e in ests) + " |")
            L.append("")
    # PX4
    if rep["px4"]:
        L.append("## PX4 logs (reference: PX4's onboard estimate `vehicle_attitude`, not ground truth)\n")
        for logname, sc in rep["px4"].items():
            L.append(f"### {logname}\n")
            L.append("| estimator | roll RMS | pitch RMS | yaw RMS | total RMS |")
            L.append("|---|---|---|---|---|")
            for est, m in sorted(sc.items(), key=lambda kv: kv[1]["total_rms"]):
                L.append(f"| {est} | {m['roll_rms']:.2f} | {m['pitch_rms']:.2f} | {m['yaw_rms']:.2f} | "
                         f"{m['total_rms']:.2f} |")
            L.append("")
    if rep["run_errors"]:
        L.append("## Failures (full messages in bench.json)\n")
        for k, v in rep["run_errors"].items():
            for est, msg in v.items():
                lines = msg.splitlines()
                first_err = next((ln.strip() for ln in lines if "error:" in ln), "")
                L.append(f"- {k} {est}: {lines[0][:120]}" + (f" … `{first_err[:160]}`" if first_err else ""))
        L.append("")
    return "\n".join(L) + "\n"


