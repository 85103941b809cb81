"""The input-check contract of every generated filter (src/ahrsgen/codegen/templates/filter.c.j2), driven in C.

Refused steps (bad dt, missing/non-finite/out-of-range gyro) leave the state byte for byte as
it was; a bad aiding sample (non-finite, out of range, near-zero) changes the state exactly as
a step where that sensor's valid bit was clear, and sets its own status bit.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from conftest import host_build, REPO
from ahrsgen import filters
from ahrsgen import status as st

NAN, INF = float("nan"), float("inf")
GOOD = dict(gyro=(0.01, -0.02, 0.03), accel=(0.3, -0.2, -9.7), mag=(0.2, 0.05, 0.4), gps_vel=(20.0, 1.0, 0.5))
ALL = 0xF
DT = 0.02
SENSOR_BIT = {"accel": 2, "mag": 4, "gps": 8}
# the built-in filters and the example user filters (folders outside the package)
EXAMPLES = REPO / "examples"
NAMES = filters.names() + [str(p) for p in sorted(EXAMPLES.iterdir()) if filters.is_filter_folder(p)]


def _sensors(name):
    return filters.load(name).model().sensors


def _warm(hf):
    s = hf.new_state()
    for _ in range(30):
        assert hf.step(s, valid=ALL, dt=DT, **GOOD) & st.REFUSED_MASK == 0
    return s


REFUSALS = [
    ({}, 0.0, st.DT_INVALID), ({}, -DT, st.DT_INVALID), ({}, NAN, st.DT_INVALID), ({}, INF, st.DT_INVALID),
    ({}, 11.0, st.DT_TOO_LARGE),
    ({"gyro": (NAN, 0, 0)}, DT, st.GYRO_NONFINITE), ({"gyro": (0, -INF, 0)}, DT, st.GYRO_NONFINITE),
    ({"gyro": (0, 0, 3e38)}, DT, st.GYRO_RANGE), ({"valid": ALL & ~1}, DT, st.GYRO_MISSING),
]

SKIPS = [
    ("accel", {"accel": (NAN, 0, -9.8)}, st.ACCEL_NONFINITE), ("accel", {"accel": (0, 0, 0)}, st.ACCEL_ZERO),
    ("accel", {"accel": (0, 3e38, 0)}, st.ACCEL_RANGE), ("accel", {"accel": (1e-40, 0, 0)}, st.ACCEL_ZERO),
    ("mag", {"mag": (0, INF, 0)}, st.MAG_NONFINITE), ("mag", {"mag": (0, 0, 0)}, st.MAG_ZERO),
    ("mag", {"mag": (3e38, 0, 0)}, st.MAG_RANGE),
    ("gps", {"gps_vel": (NAN, 0, 0)}, st.GPS_NONFINITE), ("gps", {"gps_vel": (0, 3e38, 0)}, st.GPS_RANGE),
]


@pytest.mark.parametrize("name", NAMES, ids=lambda n: Path(n).name)
@pytest.mark.parametrize("precision", ["float", "double"])
def test_refusals_leave_the_state_untouched(name, precision):
    hf = host_build(name, precision)
    for change, dt, expected in REFUSALS:
        s = _warm(hf)
        before = hf.state_bytes(s)
        args = dict(GOOD, valid=ALL)
        args.update(change)
        if change == {} and dt == 11.0:
            dt = hf.manifest["params"]["dt_max"] * 1.5
        got = hf.step(s, dt=dt, **args)
        assert got == expected, (name, change, dt, got)
        assert hf.state_bytes(s) == before, (name, change, dt)


@pytest.mark.parametrize("name", NAMES, ids=lambda n: Path(n).name)
@pytest.mark.parametrize("precision", ["float", "double"])
def test_bad_aiding_sample_equals_a_missing_one(name, precision):
    hf = host_build(name, precision)
    sensors = _sensors(name)
    checked = 0
    for sensor, change, bit in SKIPS:
        if sensor not in sensors:
            continue
        s1 = _warm(hf)
        s2 = hf.copy_state(s1)
        bad = dict(GOOD, valid=ALL)
        bad.update(change)
        got = hf.step(s1, dt=DT, **bad)
        ref = hf.step(s2, dt=DT, **dict(GOOD, valid=ALL & ~SENSOR_BIT[sensor]))
        assert got == ref | bit, (name, sensor, change, hex(got), hex(ref))
        assert hf.state_bytes(s1) == hf.state_bytes(s2), (name, sensor, change)
        q = np.array(hf.state_dict(s1)["q"])
        assert np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1) < 1e-5
        checked += 1
    assert checked >= 4      # every filter reads at least accelerometer and magnetometer or GPS


@pytest.mark.parametrize("name", NAMES, ids=lambda n: Path(n).name)
def test_reference_reports_the_same_bits(name):
    from ahrsgen.generate import config
    cfg = config.resolve(name)
    sensors = _sensors(name)
    cases = [(c, dt, e) for c, dt, e in REFUSALS if dt != 11.0]
    cases += [(c, DT, b) for sensor, c, b in SKIPS if sensor in sensors]
    hf = host_build(name, "double")
    for change, dt, expected in cases:
        ref = cfg.spec.reference(cfg.params)
        for _ in range(30):
            ref.step(GOOD["gyro"], GOOD["accel"], GOOD["mag"], GOOD["gps_vel"], ALL, DT)
        s = _warm(hf)
        args = dict(GOOD, valid=ALL)
        args.update(change)
        got = ref.step(args["gyro"], args["accel"], args["mag"], args["gps_vel"], args["valid"], dt)
        assert got & expected and (got & st.REFUSED_MASK) == (expected & st.REFUSED_MASK), (name, change, hex(got))
        # the whole status, filter bits included, equals the C's for the same step
        c_got = hf.step(s, dt=dt, **args)
        assert got == c_got, (name, change, hex(got), hex(c_got))


SKIP_BITS = {"accel": st.ACCEL_NONFINITE | st.ACCEL_RANGE | st.ACCEL_ZERO,
             "mag": st.MAG_NONFINITE | st.MAG_RANGE | st.MAG_ZERO, "gps": st.GPS_NONFINITE | st.GPS_RANGE}
LIMIT = {"gyro": "gyro_max", "accel": "accel_max", "mag": "mag_max", "gps_vel": "gps_vel_max"}


@pytest.mark.parametrize("name", NAMES, ids=lambda n: Path(n).name)
def test_the_range_is_a_box_per_component(name):
    """The limits bound each component (input_checks.py), not the norm: a sample with every
    component at 0.95 of its limit (norm 1.65 times the limit) is used, one component just
    past it is not. The common path tests the norm first; it must not narrow the box."""
    hf = host_build(name, "float")
    sensors = _sensors(name)
    for field, limit in LIMIT.items():
        sensor = {"gps_vel": "gps"}.get(field, field)
        if field != "gyro" and sensor not in sensors:
            continue
        m = hf.manifest["params"][limit]
        for scale, ok in ((0.95, True), (1.0001, False)):
            s = _warm(hf)
            args = dict(GOOD, valid=ALL)
            args[field] = (0.95 * m, -0.95 * m, scale * m)
            got = hf.step(s, dt=DT, **args)
            if field == "gyro":
                assert (got & st.REFUSED_MASK == 0) == ok, (name, field, scale, hex(got))
            else:
                assert (got & SKIP_BITS[sensor] == 0) == ok, (name, field, scale, hex(got))


@pytest.mark.parametrize("name", ["qcf", "mekf"])
def test_at_rest_is_information_and_a_bad_sample_a_fault(name):
    """A level sensor at rest with clean samples: the filter says AT_REST (a non-zero status),
    and nothing in the fault mask; a NaN accelerometer sample then sets a fault bit."""
    hf = host_build(name, "float")
    bits, fault = hf.manifest["status"], hf.manifest["status_fault_mask"]
    s = hf.new_state()
    still = dict(gyro=(0.0, 0.0, 0.0), accel=(0.0, 0.0, -9.81), mag=(0.2, 0.0, 0.4), gps_vel=(0.0, 0.0, 0.0))
    seen = 0
    for _ in range(600):
        status = hf.step(s, valid=ALL & ~8, dt=DT, **still)
        assert status & fault == 0, status
        seen |= status
    assert seen & bits["AT_REST"]
    bad = dict(still, accel=(NAN, 0.0, -9.81))
    assert hf.step(s, valid=ALL & ~8, dt=DT, **bad) & fault == st.ACCEL_NONFINITE


@pytest.mark.parametrize("name", ["qcf", "mekf", "adukf"])
def test_a_stall_stops_the_filter_once_not_for_ever(name):
    """The header's dt rule: dt is timed from the previous call, whatever it returned. A 0.8 s
    stall of the caller's task (dt_max 0.5 s) in a simulated multirotor flight is one refused
    step; every later step runs, and the estimate stays finite and normalised."""
    from conftest import scenario
    hf = host_build(name, "float")
    log = scenario("multirotor", 0, duration=30)
    keep = ~((log.t >= 20.0) & (log.t < 20.8))
    idx = np.flatnonzero(keep)
    j = int(np.searchsorted(log.t[idx], 20.8))
    dt = log.dt[idx].copy()
    dt[j] = log.t[idx][j] - log.t[idx][j - 1]            # the stall, as the caller measures it
    assert dt[j] > hf.manifest["params"]["dt_max"]
    s = hf.new_state()
    for k, i in enumerate(idx):
        status = hf.step(s, gyro=log.gyro[i], accel=log.accel[i], mag=log.mag[i], gps_vel=log.gps_vel[i],
                         valid=int(log.valid[i]), dt=float(dt[k]))
        if k == j:
            assert status & st.DT_TOO_LARGE
        else:
            assert status & st.REFUSED_MASK == 0, (k, status)
    q = np.array(hf.state_dict(s)["q"])
    assert np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1) < 1e-5


def _f32_above(x: float) -> float:
    return float(np.nextafter(np.float32(x), np.float32(np.inf)))


@pytest.mark.parametrize("name", NAMES, ids=lambda n: Path(n).name)
@pytest.mark.parametrize("precision", ["float", "double"])
def test_input_limits_at_their_edges(name, precision):
    """Each component limit (gyro_max, accel_max, mag_max, gps_vel_max) at the limit itself is
    accepted and the next float beyond refused or skipped, per component: a vector whose
    components are all inside but whose norm is beyond the limit is accepted (a check on the
    norm would refuse it). The minimum norms (accel_min_norm, mag_min_norm) likewise at their
    edge. The same answers from the reference's checks (input_checks.check)."""
    from ahrsgen.codegen import input_checks
    hf = host_build(name, precision)
    p = hf.manifest["params"]
    sensors = _sensors(name)
    cases = [("gyro", "gyro_max", st.GYRO_RANGE, "gyro")]
    cases += [(s, f"{s}_max" if s != "gps" else "gps_vel_max", {"accel": st.ACCEL_RANGE, "mag": st.MAG_RANGE,
              "gps": st.GPS_RANGE}[s], {"gps": "gps_vel"}.get(s, s)) for s in ("accel", "mag", "gps") if s in sensors]
    for sensor, limit, bit, field in cases:
        lim = p[limit]
        base = dict(GOOD)
        for comp in range(3):
            for value, flagged in ((lim, False), (-lim, False), (_f32_above(lim), True), (-_f32_above(lim), True)):
                v = list(base[field]) if sensor != "gyro" else [0.0, 0.0, 0.0]
                v[comp] = value
                args = dict(base, **{field: tuple(v)})
                s = _warm(hf)
                got = hf.step(s, valid=ALL, dt=DT, **args)
                assert bool(got & bit) == flagged, (name, limit, comp, value, got)
                c = input_checks.check(p, sensors, args["gyro"], args["accel"], args["mag"], args["gps_vel"], ALL, DT)
                assert bool((c.refused | c.status) & bit) == flagged, (name, limit, comp, value, "reference")
        inside = (0.9 * lim, -0.9 * lim, 0.9 * lim)               # norm 1.56 lim, every component inside
        args = dict(base, **{field: inside})
        s = _warm(hf)
        got = hf.step(s, valid=ALL, dt=DT, **args)
        assert not got & bit, (name, limit, "a norm check would refuse this")
        c = input_checks.check(p, sensors, args["gyro"], args["accel"], args["mag"], args["gps_vel"], ALL, DT)
        assert not (c.refused | c.status) & bit
    for sensor, limit, bit in (("accel", "accel_min_norm", st.ACCEL_ZERO), ("mag", "mag_min_norm", st.MAG_ZERO)):
        if sensor not in sensors:
            continue
        lo = p[limit]
        for scale, flagged in ((1.01, False), (0.99, True)):
            v = (lo * scale / math.sqrt(3.0),) * 3
            args = dict(GOOD, **{sensor: v})
            s = _warm(hf)
            assert bool(hf.step(s, valid=ALL, dt=DT, **args) & bit) == flagged, (name, limit, scale)
            c = input_checks.check(p, sensors, args["gyro"], args["accel"], args["mag"], args["gps_vel"], ALL, DT)
            assert bool(c.status & bit) == flagged, (name, limit, scale, "reference")
