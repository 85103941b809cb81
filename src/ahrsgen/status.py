"""Status bits returned by every generated `<prefix>_step` (and by every reference).

A status is a bit mask; 0 is OK. Refusals leave the state untouched. Skips mean one aiding
correction was not applied (the gyro propagation still ran). Filters may add their own bits
from FILTER_BASE upward (listed in their model and manifest).
"""
from __future__ import annotations

OK = 0
# step refused, state unchanged
DT_INVALID = 1 << 0        # dt not finite or <= 0
DT_TOO_LARGE = 1 << 1      # dt above the configured maximum
GYRO_MISSING = 1 << 2      # gyro valid bit clear
GYRO_NONFINITE = 1 << 3    # NaN/Inf in the gyro sample
# aiding correction skipped, state propagated
ACCEL_NONFINITE = 1 << 4
ACCEL_ZERO = 1 << 5        # |accel| below the configured minimum
MAG_NONFINITE = 1 << 6
MAG_ZERO = 1 << 7          # |mag| below the configured minimum
GPS_NONFINITE = 1 << 8
GYRO_RANGE = 1 << 9        # refused: a gyro component beyond gyro_max
ACCEL_RANGE = 1 << 10      # a component beyond accel_max: correction skipped
MAG_RANGE = 1 << 11        # a component beyond mag_max: correction skipped
GPS_RANGE = 1 << 12        # a GPS velocity component beyond gps_vel_max: sample ignored
FILTER_BASE = 1 << 16      # first bit a filter may define for itself

REFUSED_MASK = DT_INVALID | DT_TOO_LARGE | GYRO_MISSING | GYRO_NONFINITE | GYRO_RANGE

# Every common bit says something went wrong: a refused step or a bad sample. A filter's own
# bits are faults too unless the filter marks them "info" (AT_REST, MAG_DISTURBED: what the
# filter noticed about the world, a normal part of flight). <PREFIX>_STATUS_FAULT_MASK in the
# header is the union of the faults, so firmware tests (status & FAULT_MASK) != 0, not status != 0.
INFO = "info"


def extra_bits(extra_status) -> list[tuple[str, int, str, bool]]:
    """(name, value, doc, is_fault) of a filter's own bits, from FILTER_BASE up; entries are
    (NAME, doc) or (NAME, doc, "info")."""
    out = []
    for i, entry in enumerate(extra_status):
        name, doc = entry[0], entry[1]
        kind = entry[2] if len(entry) > 2 else "fault"
        if kind not in ("fault", INFO):
            raise ValueError(f"status bit {name}: kind must be 'fault' or 'info', not {kind!r}")
        out.append((name, FILTER_BASE << i, doc, kind != INFO))
    return out


def fault_mask(extra_status) -> int:
    """The bits of a filter's status that mean trouble: every common bit, and its own unless 'info'."""
    mask = 0
    for _, v, _ in COMMON:
        mask |= v
    for _, v, _, fault in extra_bits(extra_status):
        if fault:
            mask |= v
    return mask

COMMON = [
    ("OK", OK, "step completed with every available correction"),
    ("DT_INVALID", DT_INVALID, "refused: dt is not finite or not positive; state unchanged"),
    ("DT_TOO_LARGE", DT_TOO_LARGE, "refused: dt above the configured maximum; state unchanged"),
    ("GYRO_MISSING", GYRO_MISSING, "refused: gyro valid bit clear; state unchanged"),
    ("GYRO_NONFINITE", GYRO_NONFINITE, "refused: gyro sample not finite; state unchanged"),
    ("ACCEL_NONFINITE", ACCEL_NONFINITE, "accelerometer sample not finite; its correction skipped"),
    ("ACCEL_ZERO", ACCEL_ZERO, "accelerometer norm below minimum; its correction skipped"),
    ("MAG_NONFINITE", MAG_NONFINITE, "magnetometer sample not finite; its correction skipped"),
    ("MAG_ZERO", MAG_ZERO, "magnetometer norm below minimum; its correction skipped"),
    ("GPS_NONFINITE", GPS_NONFINITE, "GPS velocity not finite; its correction skipped"),
    ("GYRO_RANGE", GYRO_RANGE, "refused: a gyro component beyond gyro_max; state unchanged"),
    ("ACCEL_RANGE", ACCEL_RANGE, "an accelerometer component beyond accel_max; its correction skipped"),
    ("MAG_RANGE", MAG_RANGE, "a magnetometer component beyond mag_max; its correction skipped"),
    ("GPS_RANGE", GPS_RANGE, "a GPS velocity component beyond gps_vel_max; the sample is ignored"),
]
