"""Thrust allocation: from a demanded 6-DOF wrench to thruster forces and PWM commands.

* Unconstrained: the weighted pseudo-inverse T = W^-1/2 pinv(B W^-1/2) (for a square,
  invertible B this is B^-1, so a 4-DOF demand is met exactly with K = M = 0; Fossen 2011,
  sec. 12.3.2). The forces may exceed the thrusters' limits; the result says which do.
* Saturation-aware (the default): the demand is split into priority levels (DOF groups) and
  each level is scaled along its own direction by a fraction alpha in [0, 1]: the highest level
  gets the largest fraction any force vector within the asymmetric limits [f_min_i, f_max_i] can
  give, the next the largest with that one held, and so on (the exact lexicographic optimum,
  solved by small compiled LPs in rovlab.allocation.lexicographic). DOFs demanded zero stay zero,
  nothing is bent, a feasible demand is met exactly, and among the force vectors giving the
  optimal wrench the least weighted effort f^T W f is used (redundant sets use their null
  space). With one level holding all DOFs this is direction-preserving scaling of the whole
  wrench. No thruster force is ever clipped on its own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rovlab._jit import WITH_NRT, LazyKernels
from rovlab.allocation import kernels as _plain
from rovlab.allocation.geometry import configuration_matrix
from rovlab.models import thruster_kernels as _plain_thrusters
from rovlab.models import thrusters as _thrusters
from rovlab.models.thrusters import ThrusterBank
from rovlab.params.vehicle import WRENCH6, Vehicle

DEFAULT_PRIORITY: tuple[tuple[str, ...], ...] = (("K", "M"), ("Z",), ("N",), ("X", "Y"))
SCALE_ALL: tuple[tuple[str, ...], ...] = (WRENCH6,)
_TOL = _plain._TOL


def weighted_pinv(B: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """T (n x 6) minimising f^T W f subject to B f = tau (least squares if B lacks rank)."""
    n = B.shape[1]
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (n,) or np.any(~np.isfinite(w)) or np.any(w <= 0):
        raise ValueError(f"thruster weights must be {n} positive numbers, got {w.tolist()}")
    s = 1.0 / np.sqrt(w)
    return s[:, None] * np.linalg.pinv(B * s[None, :])


# WITH_NRT (reference counting on): some allocate, and the closed loop that calls them is compiled without reference
# counting, which they would otherwise inherit (rovlab.sim.loop)
_kernels = LazyKernels(_plain, _plain.KERNELS, cache=True, **WITH_NRT)
__getattr__ = _kernels.module_getattr(__name__)  # allocate_kernel, matvec: numba dispatchers (on first use)


@dataclass(frozen=True)
class AllocationResult:
    forces: np.ndarray  # per thruster [N]
    pwm_us: np.ndarray  # per thruster [us]
    demanded: np.ndarray  # 6-DOF wrench asked for [X, Y, Z, K, M, N]
    achieved: np.ndarray  # 6-DOF wrench the forces produce
    fraction: np.ndarray  # per DOF: achieved share of the demand (1 = met)
    saturated: bool  # some DOF could not be met in full (unconstrained: some force is beyond its limits)
    thruster_names: tuple[str, ...]
    over_limit: tuple[str, ...] = ()  # unconstrained only: thrusters whose force is beyond their limits

    def limited_dofs(self) -> list[str]:
        return [name for name, fr in zip(WRENCH6, self.fraction) if fr < 1.0 - 1e-6]

    def as_dict(self) -> dict:
        return {
            "thrusters": list(self.thruster_names),
            "forces": self.forces.tolist(),
            "pwm_us": self.pwm_us.tolist(),
            "demanded": self.demanded.tolist(),
            "achieved": self.achieved.tolist(),
            "fraction": self.fraction.tolist(),
            "saturated": bool(self.saturated),
            "limited_dofs": self.limited_dofs(),
            "over_limit": list(self.over_limit),
        }


class Allocator:
    """Allocation for one vehicle: precomputes B, its weighted pseudo-inverse and the limits.

    ``priority`` lists DOF groups from most to least important (a DOF not listed goes last);
    ``SCALE_ALL`` keeps the whole wrench direction instead. ``saturation=False`` gives the
    plain unconstrained pseudo-inverse: the forces are T tau as they are, possibly beyond the
    thrusters' limits (listed in ``over_limit``; their PWM commands saturate, so the real
    wrench then differs from ``achieved``, which is what the unconstrained forces would give).
    ``compiled=False`` runs the kernels as plain Python: the same numbers, slower per call, but
    without importing numba or compiling (for a one-off allocation such as ``rovlab allocate``).
    ``pwm_hysteresis_us``: the dead band's hysteresis the PWM commands of a closed loop get from a
    design file (rovlab.sim.actuators, which keeps its state); ``allocate`` is one-off and ignores it.
    """

    def __init__(self, vehicle: Vehicle, *, priority: Sequence[Sequence[str]] = DEFAULT_PRIORITY,
                 weights: np.ndarray | None = None, saturation: bool = True, compiled: bool = True,
                 pwm_hysteresis_us: float = 0.0) -> None:
        self.vehicle = vehicle
        self.pwm_hysteresis_us = float(pwm_hysteresis_us)
        self.B = np.ascontiguousarray(configuration_matrix(vehicle))
        self.T = np.ascontiguousarray(weighted_pinv(self.B, weights))
        n = self.B.shape[1]
        w = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
        self._s = 1.0 / np.sqrt(w)
        self.bank = ThrusterBank.from_vehicle(vehicle)
        self.saturation = saturation
        self.level = _levels(priority)
        self.n_levels = int(self.level.max()) + 1
        self.rank = int(np.linalg.matrix_rank(self.B))
        self.compiled = compiled
        self._kernels: tuple | None = None  # (allocate_kernel, bank_pwm), resolved on first use

    def __getstate__(self) -> dict:
        """Pickled without the resolved kernels (numba dispatchers are resolved again where the
        allocator is unpickled: a Monte Carlo worker, a stored design)."""
        state = dict(self.__dict__)
        state["_kernels"] = None
        return state

    def _resolve(self) -> tuple:
        if self._kernels is None:
            if self.compiled:
                self._kernels = (_kernels.compiled()["allocate_kernel"], _thrusters.bank_pwm)
            else:
                self._kernels = (_plain.allocate_kernel, _plain_thrusters.bank_pwm)
        return self._kernels

    @property
    def f_min(self) -> np.ndarray:
        return self.bank.f_min

    @property
    def f_max(self) -> np.ndarray:
        return self.bank.f_max

    def forces(self, tau6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(thruster forces, fraction per DOF) for a 6-DOF wrench (no validation)."""
        if not self.saturation:
            return self.T @ tau6, np.ones(6)
        kernel = (self._kernels or self._resolve())[0]
        return kernel(self.B, self.T, self._s, self.bank.f_min, self.bank.f_max, tau6, self.level, self.n_levels, True)

    def allocate(self, tau: np.ndarray) -> AllocationResult:
        """Allocate a 6-DOF wrench [X, Y, Z, K, M, N] or a 4-DOF one [X, Y, Z, N] (K = M = 0)."""
        tau6 = as_wrench6(tau)
        f, frac = self.forces(tau6)
        bank_pwm = (self._kernels or self._resolve())[1]
        pwm = bank_pwm(self.bank.rows, self.bank.grid_pwm, self.bank.grid_force, f)
        achieved = self.B @ f
        if not self.saturation:
            over = (f > self.bank.f_max + 1e-9) | (f < self.bank.f_min - 1e-9)
            names = tuple(name for name, o in zip(self.bank.names, over) if o)
            # a rank-deficient B gives the least-squares wrench: report its share per DOF
            frac = np.array([a / d if abs(d) > 1e-12 else 1.0 for a, d in zip(achieved, tau6)])
            return AllocationResult(f, pwm, tau6, achieved, frac, bool(over.any()), self.bank.names, names)
        sat = bool(np.any(frac < 1.0 - 1e-9))
        return AllocationResult(f, pwm, tau6, achieved, frac, sat, self.bank.names)


def as_wrench6(tau: np.ndarray) -> np.ndarray:
    arr = np.asarray(tau, dtype=float).ravel()
    if arr.shape == (4,):
        arr = np.array([arr[0], arr[1], arr[2], 0.0, 0.0, arr[3]])
    if arr.shape != (6,):
        raise ValueError(f"wrench must have 4 ([X, Y, Z, N]) or 6 ([X, Y, Z, K, M, N]) values, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"wrench must be finite, got {arr.tolist()}")
    return np.ascontiguousarray(arr)


def _levels(priority: Sequence[Sequence[str]]) -> np.ndarray:
    level = np.full(6, -1, dtype=np.int64)
    for k, group in enumerate(priority):
        for dof in group:
            if dof not in WRENCH6:
                raise ValueError(f"unknown DOF {dof!r} in allocation priority; expected some of {WRENCH6}")
            if level[WRENCH6.index(dof)] >= 0:
                raise ValueError(f"DOF {dof!r} appears twice in the allocation priority")
            level[WRENCH6.index(dof)] = k
    last = len(priority)
    level[level < 0] = last
    # renumber densely
    _, dense = np.unique(level, return_inverse=True)
    return dense.astype(np.int64)
