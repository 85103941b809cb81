"""Figures for docs/cpf.md: the paper's Table 1 on the `turntable` scenario, and cost versus N.

    .venv/bin/python -m studies.cpf_report            # Markdown on stdout

Runs the generated C in double precision (it equals the NumPy reference to ~1e-14 rad on
these runs; tests/test_cpf.py checks it), mean over scenario seeds 0-9.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
from functools import cache

import numpy as np

from ahrsgen.sim import host, scenarios
from ahrsgen.sim.metrics import euler_stats
from ahrsgen.generate import config

PAPER = {"complementary": (4.26, 3.74, 2.84), "particle": (3.68, 3.28, 3.19), "combined": (0.93, 0.41, 0.36)}
MODES = ("complementary", "particle", "combined")
# Extra white noise for the "noisy" variant, per sample (the scenario's own sensors are quiet).
EXTRA_ACCEL = 0.3      # m/s^2
EXTRA_MAG = 0.03       # gauss, on a 0.5 gauss field


def _sets(params: dict) -> list[str]:
    return [f"{k}={v!r}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items()]


@cache
def _filter(precision: str, items: tuple):
    return host.build(config.resolve("cpf", sets=_sets(dict(items)), precision=precision))


def hf(precision="double", **params):
    return _filter(precision, tuple(sorted(params.items())))


@cache
def turntable(seed: int, noisy: bool):
    log = scenarios.make("turntable", seed=seed)
    if noisy:
        rng = np.random.default_rng([seed, 4242])
        log = dataclasses.replace(log, accel=log.accel + EXTRA_ACCEL * rng.standard_normal(log.accel.shape),
                                  mag=log.mag + EXTRA_MAG * rng.standard_normal(log.mag.shape))
    return log


def rms_hpr(params: dict, seeds, noisy: bool) -> np.ndarray:
    """Mean over seeds of RMS heading, pitch, roll (degrees)."""
    out = []
    for seed in seeds:
        log = turntable(seed, noisy)
        p = {"declination": math.radians(float(log.meta["declination_deg"])), **params}
        q = hf("double", **p).run(log).q
        s = euler_stats(q, log.q_true, log.t, log.settle_time)
        out.append([s["yaw"]["rms"], s["pitch"]["rms"], s["roll"]["rms"]])
    return np.mean(out, axis=0)


def _fmt(v):
    return " / ".join(f"{x:.2f}" for x in v)


def reproduction(seeds=range(10)) -> str:
    lines = ["| variant | complementary | particle | combined |", "|---|---|---|---|",
             "| paper, Table 1 (real turntable) | " + " | ".join(_fmt(PAPER[m]) for m in MODES) + " |"]
    for noisy in (False, True):
        name = "turntable" if not noisy else f"turntable + noise (accel {EXTRA_ACCEL} m/s², mag {EXTRA_MAG} G)"
        row = [rms_hpr({"mode": m}, seeds, noisy) for m in MODES]
        lines.append(f"| {name}, defaults | " + " | ".join(_fmt(r) for r in row) + " |")
        row = [rms_hpr({"mode": m, "faithful": True}, seeds, noisy) if m != "complementary" else None for m in MODES]
        lines.append(f"| {name}, faithful (quaternion noise, resample every step) | – | " + " | ".join(_fmt(r) for r in row[1:]) + " |")
        # each stage tuned on its own (small grids; the best total RMS)
        best = {}
        grids = {"complementary": [{"tau": t} for t in (0.1, 0.3, 1.0, 3.0)],
                 "particle": [{"obs_noise": o, "process_noise": p} for o in (0.02, 0.05, 0.1, 0.2) for p in (0.02, 0.05)],
                 "combined": [{"tau": t, "obs_noise": o, "process_noise": p} for t in (0.1, 0.3, 1.0)
                              for o in (0.02, 0.05, 0.1) for p in (0.02, 0.05)]}
        for m in MODES:
            cand = [(rms_hpr({"mode": m, **g}, seeds, noisy), g) for g in grids[m]]
            best[m] = min(cand, key=lambda c: float(np.sum(c[0] ** 2)))
        lines.append(f"| {name}, each tuned | " + " | ".join(
            f"{_fmt(best[m][0])} ({', '.join(f'{k} {v}' for k, v in best[m][1].items())})" for m in MODES) + " |")
    return "\n".join(lines)


# Per-particle work written in the template (not in the kernels' op counts): three ziggurat
# normals (four in faithful mode; each a xoroshiro64** draw, a table look-up and compare, an
# int->real conversion and a multiply; the wedge's exp and the tail's log in about 1.2 % of
# draws) and the likelihood's exp; the loops add per particle the hemisphere test, the
# maximum's compare, the weight sum and the ESS square-sum; resampling is O(N) (one uniform, N
# cumulative adds and compares, at most N copies of 4 values).


def cost(ns=(50, 100, 200), time_it: bool = True) -> str:
    lines = ["| N | state B (float) | state B (double) | kernel ops, step with accel+mag | "
             "+ template per particle (ziggurat) | host ns/step double | host ns/step float |",
             "|---|---|---|---|---|---|---|"]
    log = turntable(0, False)
    for n in ns:
        f, d = hf("float", n_particles=n), hf("double", n_particles=n)
        path = f.manifest["step_paths"]["accel+mag (kernels)"]
        ops = ", ".join(f"{k} {v}" for k, v in path["ops"].items() if v)
        t_d = d.time_ns_per_step(log) if time_it else float("nan")
        t_f = f.time_ns_per_step(log) if time_it else float("nan")
        lines.append(f"| {n} | {f.manifest['structs']['state']['size']} | {d.manifest['structs']['state']['size']} | "
                     f"{path['total']} ({ops}) | {n} × (3 normals, 1 exp) | "
                     f"{t_d:.0f} | {t_f:.0f} |")
    return "\n".join(lines)


def per_particle_ops() -> str:
    m = hf("float").manifest["kernels"]
    names = ["particle_move", "normalize", "obs_dot", "log_likelihood", "accumulate"]
    tot = sum(m[k]["total"] for k in names)
    return ", ".join(f"{k} {m[k]['total']}" for k in names) + f" = {tot} kernel ops per particle"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--no-timing", action="store_true")
    a = ap.parse_args(argv)
    print("RMS heading / pitch / roll, degrees (mean over seeds 0-%d)\n" % (a.seeds - 1))
    print(reproduction(range(a.seeds)))
    print()
    print(cost(time_it=not a.no_timing))
    print()
    print(per_particle_ops())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
