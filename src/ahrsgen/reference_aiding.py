"""NumPy mirrors, for the filters' references, of aiding steps that every filter's reference
runs alike. Written from the equations in the docstrings of symbolic/aiding.py, not from the
CasADi code, so that validate compares two implementations."""
from __future__ import annotations

import numpy as np

# the rule's constants, as symbolic/aiding states them (this layer cannot import it; a test
# checks they agree): equal samples in a row of one fast component, "equal" within (rad/s)
PLATEAU_SAMPLES = 4
PLATEAU_TOL = 1e-6


class GyroClip:
    """A gyro sample is clipped when a component is at or beyond full_scale, or when one at or
    above plateau_rate has held its value (within PLATEAU_TOL) for PLATEAU_SAMPLES samples while
    the others changed (a sample equal to the previous one in every component is a duplicate: it neither
    counts nor resets). full_scale = 0 turns both off. Each clipped sample restarts
    recovery_time of recovery; a step recovers while more than half a step of it is left."""

    def __init__(self, full_scale: float, plateau_rate: float, recovery_time: float):
        self.full_scale, self.plateau_rate, self.recovery_time = full_scale, plateau_rate, recovery_time
        self.prev = np.zeros(3)
        self.repeats = np.zeros(3)
        self.recover_time = 0.0

    def step(self, gyro, dt: float) -> tuple[bool, bool]:
        """(clipped, recovering) for this sample; updates the state."""
        gyro = np.asarray(gyro, dtype=float)
        plateau = False
        if self.plateau_rate > 0:
            same = np.abs(gyro - self.prev) < PLATEAU_TOL
            if not same.all():
                self.repeats = np.where(same & (np.abs(gyro) >= self.plateau_rate),
                                        np.minimum(self.repeats + 1, PLATEAU_SAMPLES - 1), 0.0)
            plateau = bool(np.any(self.repeats >= PLATEAU_SAMPLES - 1))
        self.prev = gyro.copy()
        clipped = self.full_scale > 0 and (plateau or bool(np.max(np.abs(gyro)) >= self.full_scale))
        if clipped:
            self.recover_time = self.recovery_time
        elif self.recover_time > 0:
            self.recover_time = max(self.recover_time - dt, 0.0)
        return clipped, self.recover_time > 0.5 * dt
