"""How the filters' BROAD scores move with the sensor rates (docs/mekf.md, "Known limitations").

Run: .venv/bin/python docs/rate_sensitivity.py [FILTER or LABEL=FILTER:name=value,... ...]
(default: mekf qcf adukf). Every BROAD trial in ../shared/data/broad (or $AHRSGEN_DATA) three
ways: as recorded (286 Hz), the IMU at 95 Hz (every third row, carrying the mean gyro and
accelerometer of its three rows, as an IMU that integrates over its interval), and
the magnetometer's valid bit on every third row only (the magnetometer at 95 Hz, the IMU at 286
Hz). Each filter is its generated float C through the harness, as `ahrsgen run` runs it; VQF
(the peer) runs beside them. Prints BROAD's mean total RMS per variant, then per trial.
"""
from __future__ import annotations

import io
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from ahrsgen import bench
from ahrsgen.sim import peers, readers
from ahrsgen.sim.log import VALID_MAG, SensorLog

VARIANTS = ("as recorded", "IMU / 3", "mag / 3")


def estimators(args: list[str]) -> list[tuple[str, str, list[str]]]:
    """(label, filter, sets) from FILTER or LABEL=FILTER:name=value,..."""
    out = []
    for a in args or ["mekf", "qcf", "adukf"]:
        if "=" in a.split(":")[0]:
            label, rest = a.split("=", 1)
            name, _, kv = rest.partition(":")
            out.append((label, name, [s for s in kv.split(",") if s]))
        else:
            out.append((a, a, []))
    return out


def variant(log: SensorLog, kind: str) -> SensorLog:
    if kind == "as recorded":
        return log
    if kind == "IMU / 3":
        # a 95 Hz IMU that integrates: each kept row carries the mean gyro and accelerometer of its
        # three rows (SensorLog.averaged)
        return log.averaged(3)
    valid = log.valid.copy()
    valid[np.arange(len(log)) % 3 != 0] &= ~np.uint32(VALID_MAG)
    return SensorLog(log.name, log.t, log.dt, log.gyro, log.accel, log.mag, log.gps_vel, valid, log.q_true,
                     dict(log.meta))


def _job(args):
    path, kind, ests = args
    log = variant(readers.read_log(path), kind)
    out = {label: bench.run_on_log(name, path, sets=sets, log=log, out=io.StringIO())["score"]["total_rms"]
           for label, name, sets in ests}
    out["vqf"] = bench.score(peers.PEERS["vqf"]().run(log), log, "mag")["total_rms"]
    return path, kind, out


def main(argv: list[str]) -> None:
    ddir = readers.shared_data_dir()
    if ddir is None:
        sys.exit("BROAD subset not found (../shared/data/broad or $AHRSGEN_DATA)")
    ests = estimators(argv)
    jobs = [(str(p), k, ests) for p in readers.broad_trials(ddir) for k in VARIANTS]
    res: dict[str, dict[str, dict]] = {}
    with ProcessPoolExecutor(2) as ex:
        for path, kind, out in ex.map(_job, jobs):
            res.setdefault(kind, {})[path] = out
    names = [label for label, _, _ in ests] + ["vqf"]
    print("| variant | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for k in VARIANTS:
        print(f"| {k} | " + " | ".join(f"{np.mean([v[n] for v in res[k].values()]):.2f}" for n in names) + " |")
    print()
    for k in VARIANTS:
        print(f"{k}:")
        for p, v in res[k].items():
            print(f"  {p.rsplit('/', 1)[-1][:40]:40} " + "  ".join(f"{n} {v[n]:5.2f}" for n in names))


if __name__ == "__main__":
    main(sys.argv[1:])
