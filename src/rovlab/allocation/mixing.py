"""Pilot-input mixing the way an ArduSub autopilot does it, for any rovlab vehicle.

ArduSub (ArduPilot's submarine firmware) does not allocate forces: it *mixes*. Each motor i has
one factor per pilot axis (forward, lateral, throttle, yaw, ...), the normalised pilot inputs in
[-1, 1] are multiplied by those factors and summed, the motor outputs are scaled back into
[-1, 1] if any exceeds it, and an output is turned into a PWM pulse *linearly*
(neutral +- output x half range) -- the thrust then follows from the ESC and propeller, not from
the mixer. (ArduPilot, libraries/AP_Motors/AP_Motors6DOF.cpp: per-frame factor tables, e.g.
SUB_FRAME_VECTORED for the BlueROV2 and SUB_FRAME_VECTORED_6DOF for the Heavy; the thrust-to-PWM
map is linear over MOT_PWM_MIN .. MOT_PWM_MAX.)

rovlab knows its vehicle's geometry instead of a frame table, so the factors are derived from
it: the factor column of an axis is the thruster force pattern that produces a pure wrench on
that axis with the other five components zero (the least-effort solution through the
configuration matrix, rovlab.allocation.weighted_pinv), scaled so that its largest entry is
+-1. For the BlueROV2 Heavy this reproduces the +-1 pattern of ArduSub's VECTORED_6DOF table
up to each motor's sign (which on a real vehicle also depends on MOT_n_DIRECTION and the
propeller fitted; the vehicle file's thrust directions decide it here), plus small
forward/lateral factors on the vertical motors that cancel the roll and pitch moments of the
horizontal thrusters (ArduSub leaves those to its attitude controller). Axes follow the pilot:
forward = +X (surge), lateral = +Y (starboard), throttle = up (-Z in the NED body frame),
yaw = +N (clockwise seen from above).

The inverse (:func:`inputs_for_outputs`) is what a companion computer needs: given the motor
outputs it wants (from a force allocation and the thruster curves), the pilot inputs whose mix
comes closest in least squares.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovlab.allocation.geometry import configuration_matrix
from rovlab.allocation.solvers import weighted_pinv
from rovlab.params.vehicle import Vehicle

AXES = ("forward", "lateral", "throttle", "yaw")
# wrench row (X, Y, Z, K, M, N) and sign of each pilot axis: throttle up is -Z (z points down)
_AXIS_ROW = {"forward": (0, 1.0), "lateral": (1, 1.0), "throttle": (2, -1.0), "yaw": (5, 1.0)}


@dataclass(frozen=True, eq=False)
class Mixer:
    """Per-motor factors (n x 4, columns AXES) and each motor's PWM range."""

    thruster_names: tuple[str, ...]
    factors: np.ndarray  # (n, 4): motor output per unit pilot input on each axis
    pwm_neutral_us: np.ndarray  # (n,)
    pwm_min_us: np.ndarray  # (n,)
    pwm_max_us: np.ndarray  # (n,)

    @classmethod
    def from_vehicle(cls, vehicle: Vehicle) -> Mixer:
        T = weighted_pinv(configuration_matrix(vehicle))  # n x 6
        n = len(vehicle.thrusters)
        factors = np.zeros((n, len(AXES)))
        for j, axis in enumerate(AXES):
            row, sign = _AXIS_ROW[axis]
            col = sign * T[:, row]
            peak = float(np.max(np.abs(col)))
            if peak > 1e-12:  # an axis the thrusters cannot act on keeps zero factors
                factors[:, j] = col / peak
        factors[np.abs(factors) < 1e-9] = 0.0
        factors.setflags(write=False)

        def arr(key: str) -> np.ndarray:
            a = np.array([getattr(t, key) for t in vehicle.thrusters], dtype=float)
            a.setflags(write=False)
            return a

        return cls(vehicle.thruster_names, factors, arr("pwm_neutral_us"), arr("pwm_min_us"), arr("pwm_max_us"))

    def outputs(self, inputs: np.ndarray) -> np.ndarray:
        """Motor outputs in [-1, 1] for pilot inputs [forward, lateral, throttle, yaw] in [-1, 1]
        (clipped to that range first); all outputs are scaled down together if one exceeds 1,
        which keeps the direction of the mix."""
        u = np.clip(np.asarray(inputs, dtype=float), -1.0, 1.0)
        out = self.factors @ u
        peak = float(np.max(np.abs(out))) if out.size else 0.0
        return out / peak if peak > 1.0 else out

    def pwm_us(self, outputs: np.ndarray) -> np.ndarray:
        """PWM pulse per motor for outputs in [-1, 1]: linear on each side of neutral."""
        out = np.clip(np.asarray(outputs, dtype=float), -1.0, 1.0)
        up = self.pwm_max_us - self.pwm_neutral_us
        down = self.pwm_neutral_us - self.pwm_min_us
        return self.pwm_neutral_us + np.where(out >= 0.0, out * up, out * down)

    def outputs_from_pwm(self, pwm_us: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`pwm_us` (clipped to [-1, 1])."""
        p = np.asarray(pwm_us, dtype=float)
        up = self.pwm_max_us - self.pwm_neutral_us
        down = self.pwm_neutral_us - self.pwm_min_us
        off = p - self.pwm_neutral_us
        return np.clip(np.where(off >= 0.0, off / up, off / down), -1.0, 1.0)

    def inputs_for_outputs(self, outputs: np.ndarray) -> np.ndarray:
        """Pilot inputs [forward, lateral, throttle, yaw] (clipped to [-1, 1]) whose mix comes
        closest to the wanted motor outputs in least squares."""
        u, *_ = np.linalg.lstsq(self.factors, np.asarray(outputs, dtype=float), rcond=None)
        return np.clip(u, -1.0, 1.0)
