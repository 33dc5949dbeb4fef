"""A simulated vehicle driven by thruster PWM commands, advanced on demand: what a vehicle
simulator behind a middleware (e.g. the MAVLink one, rovlab.interfaces.mavlink) runs.

No controller and no estimator: PWM pulses in, the process-model plant of rovlab.sim.plant
(nonlinear 4-DOF model, RK4 at ``plant_step_s``, white force noise of power spectral density W)
moved forward, and sensor samples out in SI units -- the depth of the pressure sensor (its lever
arm included), the heading and the yaw rate, each with the noise its vehicle file gives. The
thrust follows from the vehicle's thruster curves (rovlab.models.thrusters) and acts through its
configuration matrix, so the same file that the estimator and the allocation use is the truth.

Random draws come from one numpy Generator seeded at construction (reproducible runs).
"""

from __future__ import annotations

import math

import numpy as np

from rovlab.allocation.geometry import configuration_matrix
from rovlab.core.angles import wrap_angle
from rovlab.models.kinetics import pack
from rovlab.models.thrusters import K_PMAX, K_PMIN, ThrusterBank
from rovlab.params.vehicle import Vehicle
from rovlab.sim.plant import process_advance

_DOF4_ROWS = (0, 1, 2, 5)  # X, Y, Z, N in the 6-DOF wrench
DEFAULT_W = (1e-2, 1e-2, 1e-2, 1e-4)  # white force noise PSD [N^2 s | N^2 m^2 s], as the packaged scenarios


class VehicleSimulation:
    """The plant of one vehicle with PWM held between calls to :meth:`advance`. Not thread-safe."""

    def __init__(self, vehicle: Vehicle, *, depth_m: float = 0.0, heading_rad: float = 0.0, seed: int = 0,
                 plant_step_s: float = 0.01, process_noise_psd: tuple[float, ...] | None = DEFAULT_W,
                 sensor_noise: bool = True) -> None:
        for name, v in (("depth_m", depth_m), ("heading_rad", heading_rad), ("plant_step_s", plant_step_s)):
            if not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v!r}")
        if not 1e-4 <= plant_step_s <= 0.1:
            raise ValueError(f"plant_step_s must be within 1e-4 .. 0.1 s, got {plant_step_s}")
        self.vehicle = vehicle
        self.h = float(plant_step_s)
        self.p = pack(vehicle)
        self.x = np.zeros(8)
        self.x[2] = depth_m
        self.x[3] = heading_rad
        self.bank = ThrusterBank.from_vehicle(vehicle)
        self.B = configuration_matrix(vehicle)
        self.pwm_us = np.array([t.pwm_neutral_us for t in vehicle.thrusters], dtype=float)
        self.thrust = np.zeros(len(vehicle.thrusters))
        self.tau = np.zeros(4)  # real thruster wrench [X, Y, Z, N]
        psd = np.zeros(4) if process_noise_psd is None else np.asarray(process_noise_psd, dtype=float)
        self._noise_std = np.sqrt(psd / self.h)
        self._rng = np.random.default_rng(seed)
        self.time = 0.0
        self._sensor_noise = sensor_noise
        self._pressure = _first(vehicle, "pressure")
        self._imu = _first(vehicle, "imu")

    # -- commands ----------------------------------------------------------------------------
    def set_pwm(self, pwm_us: np.ndarray) -> None:
        """PWM per thruster [us], held until the next call (saturated to each thruster's range)."""
        pwm = np.asarray(pwm_us, dtype=float)
        if pwm.shape != self.pwm_us.shape or not np.all(np.isfinite(pwm)):
            raise ValueError(f"expected {self.pwm_us.size} finite PWM values, got {pwm!r}")
        self.pwm_us = np.clip(pwm, self.bank.rows[:, K_PMIN], self.bank.rows[:, K_PMAX])
        self.thrust = self.bank.force(self.pwm_us)
        tau6 = self.B @ self.thrust
        self.tau = tau6[list(_DOF4_ROWS)]

    def neutral(self) -> None:
        """All thrusters at neutral (no thrust)."""
        self.set_pwm(np.array([t.pwm_neutral_us for t in self.vehicle.thrusters], dtype=float))

    # -- running -----------------------------------------------------------------------------
    def advance(self, dt: float) -> int:
        """Integrate the whole plant steps that fit in dt [s] (the remainder carries over to the
        next call through ``time``); returns the number of steps taken."""
        if not dt > 0.0:
            return 0
        n = int((dt + 1e-12) / self.h)
        if n < 1:
            return 0
        normals = self._rng.standard_normal((n, 4))
        process_advance(self.p, self.x, self.tau.copy(), self.h, self._noise_std, normals)
        self.time += n * self.h
        return n

    # -- what the sensors see ----------------------------------------------------------------
    @property
    def depth(self) -> float:
        """True depth of VO [m] (z, positive down)."""
        return float(self.x[2])

    @property
    def heading(self) -> float:
        return float(wrap_angle(self.x[3]))

    def pressure_depth(self) -> float:
        """Depth of the pressure sensor [m] with its noise (lever arm l: z_sensor = z_VO + l_z at zero
        roll and pitch); negative above the surface."""
        s = self._pressure
        z = self.depth + (float(s.position[2]) if s is not None else 0.0)
        var = s.variance.get("z", 0.0) if s is not None else 0.0
        return z + self._noise(var)

    def heading_sample(self) -> float:
        var = self._imu.variance.get("psi", 0.0) if self._imu is not None else 0.0
        return float(wrap_angle(self.heading + self._noise(var)))

    def yaw_rate_sample(self) -> float:
        var = self._imu.variance.get("r", 0.0) if self._imu is not None else 0.0
        return float(self.x[7]) + self._noise(var)

    def _noise(self, variance: float) -> float:
        if not self._sensor_noise or variance <= 0.0:
            return 0.0
        return float(math.sqrt(variance) * self._rng.standard_normal())


def _first(vehicle: Vehicle, kind: str):
    return next((s for s in vehicle.sensors if s.kind == kind), None)
