"""Issue 25: do `qcf` and `adukf` gain from mekf's online hard iron? An oracle bound, measured
before building anything.

    .venv/bin/python studies/hard_iron_oracle.py [DATA_DIR] [--json out.json]

For each log the mekf NumPy reference (defaults, the log's site parameters) is run and the hard
iron it holds before each step, b(t), is recorded (zero until it switches). qcf and adukf
(float C through the host build, defaults, as `ahrsgen bench` and `ahrsgen run` score them)
are then run on the same log with the magnetometer replaced by m - b(t): what they would score
with mekf's hard-iron estimate and nothing else changed (their own field checks and
references, which after the correction see the field they learned at the start). On the
attached_magnet scenario (5 seeds, heading RMS from 30 s after the magnet arrives) the true
offset (meta['magnet'], from its arrival) is a second oracle: the bound with a perfect
estimate. A third variant also drops the magnetometer samples while mekf's candidate is
"suspect" (it explains the field much better than the present model: mekf then does not use the
magnetometer for heading), as a shared hard iron would gate every filter. On the 10 BROAD trials (as recorded, 286 Hz, and averaged to 95 Hz) it tells whether
mekf's switch, corrected into the other filters, hurts any trial.
"""
from __future__ import annotations

import json
import sys

import numpy as np

import logo_cv
from ahrsgen.bench.scoring import filter_estimator, score, site_sets
from ahrsgen.filters.mekf.reference import HARD_IRON_SWITCHED, Reference
from ahrsgen.generate import config
from ahrsgen.sim.log import VALID_MAG
from ahrsgen.sim.peers import broad_score
from ahrsgen.sim.scenarios import make

SEEDS = range(5)
FILTERS = ("qcf", "adukf", "mekf")   # mekf on a corrected log: a check of the scoring only
# qcf and adukf as they were before their own hard iron (mag_bias = false: the oracle is the bound
# that decided whether to build it); mekf with its defaults
SETS = {"qcf": ["mag_bias=false"], "adukf": ["mag_bias=false"], "mekf": []}


def mekf_hard_iron(log):
    """b(t) (N, 3): the mekf reference's hard iron before each step; suspect (N,): its candidate
    explained the field better than the present model at the end of the step (mekf then does
    not use the magnetometer); and the switch times (s)."""
    extra, _ = site_sets("mekf", log.meta)
    ref = Reference(config.resolve("mekf", sets=extra).params)
    b = np.zeros((len(log), 3))
    suspect = np.zeros(len(log), dtype=bool)
    switches = []
    for k in range(len(log)):
        b[k] = ref.mag_bias
        st = ref.step(log.gyro[k], log.accel[k], log.mag[k], log.gps_vel[k], int(log.valid[k]), log.dt[k])
        suspect[k] = ref.mag_suspect
        if st & HARD_IRON_SWITCHED:
            switches.append(round(float(log.t[k]), 1))
    return b, suspect, switches


def corrected(log, b, gate=None):
    """The log with the magnetometer less b (rows without a magnetometer sample unchanged) and,
    where `gate` is set, no magnetometer sample at all (its valid bit cleared)."""
    import copy
    out = copy.copy(log)
    has = (np.asarray(log.valid) & VALID_MAG) != 0
    out.mag = np.where(has[:, None], log.mag - b, log.mag)
    if gate is not None:
        out.valid = np.where(gate, log.valid & ~np.uint32(VALID_MAG), log.valid).astype(np.uint32)
    return out


def true_offset(log):
    m = log.meta["magnet"]
    on = (log.t >= m["attach_time_s"] + 0.5)[:, None]
    return np.where(on, np.asarray(m["offset_body"])[None, :], 0.0)


def figure(name, log, kind):
    q, heading, _ = filter_estimator(name, SETS[name]).run(log)
    if kind == "broad":
        return broad_score(q, log)["total"]
    return score(q, log, heading)["heading_rms"]


def main(argv=None):
    a, broad = logo_cv.setup(__doc__, argv)
    rows = {}
    for s in SEEDS:
        log = make("attached_magnet", s)
        b, suspect, sw = mekf_hard_iron(log)
        entry = {"switches_s": sw, "attach_s": log.meta["magnet"]["attach_time_s"]}
        for f in FILTERS:
            entry[f] = figure(f, log, "scenario")
            entry[f + "+mekf_b"] = figure(f, corrected(log, b), "scenario")
            entry[f + "+mekf_b_gated"] = figure(f, corrected(log, b, suspect), "scenario")
            entry[f + "+true_b"] = figure(f, corrected(log, true_offset(log)), "scenario")
        rows[f"attached_magnet/{s}"] = entry
        print(f"attached_magnet seed {s}: " + json.dumps(entry), file=sys.stderr, flush=True)
    if broad is not None:
        for sfx, logs in zip(logo_cv.RATES, broad):
            for n, log in sorted(logs.items()):
                b, suspect, sw = mekf_hard_iron(log)
                entry = {"switches_s": sw, "max_b": float(np.max(np.linalg.norm(b, axis=1))),
                         "suspect_s": float(np.sum(log.dt[suspect]))}
                for f in FILTERS:
                    entry[f] = figure(f, log, "broad")
                    entry[f + "+mekf_b"] = figure(f, corrected(log, b), "broad") if sw else entry[f]
                    entry[f + "+mekf_b_gated"] = (figure(f, corrected(log, b, suspect), "broad")
                                                  if suspect.any() else entry[f + "+mekf_b"])
                rows[f"broad/{n}{sfx}"] = entry
                print(f"BROAD {n}{sfx}: " + json.dumps(entry), file=sys.stderr, flush=True)
    print("\nmean over entries (attached_magnet: heading RMS; BROAD: total RMS), degrees")
    for group in ("attached_magnet/", "broad/", "broad/@"):
        keys = [k for k in rows if k.startswith(group[:6]) and (("@" in k) == group.endswith("@"))
                and k.startswith(group.rstrip("@"))]
        if not keys:
            continue
        cols = [c for c in rows[keys[0]] if c.split("+")[0] in FILTERS]
        print(f"{group.rstrip('/@') + (' @95 Hz' if group.endswith('@') else ''):18s} "
              + "  ".join(f"{c} {np.mean([rows[k][c] for k in keys]):.2f}" for c in cols))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
