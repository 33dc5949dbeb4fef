"""Thrust allocation: from a demanded 6-DOF wrench to thruster forces and PWM commands.

* Unconstrained: the weighted pseudo-inverse T = W^-1/2 pinv(B W^-1/2) (for a square,
  invertible B this is B^-1, so a 4-DOF demand is met exactly with K = M = 0; Fossen 2011,
  sec. 12.3.2).
* Saturation-aware (the default): the demand is split into priority levels (DOF groups).
  Level by level, the largest fraction alpha in [0, 1] of that level's wrench that keeps every
  thruster within its own asymmetric limits [f_min_i, f_max_i] is added, so a level that
  cannot be met is *scaled* along its own direction and never bent; lower levels get what is
  left. With one level holding all DOFs this is direction-preserving scaling of the whole
  wrench. For redundant thruster sets, thrusters that hit a limit are frozen there and the rest
  of the level is redistributed over the free ones while they still span the wrench space
  (redistributed pseudo-inverse, Bodson 2002, J. Guid. Control Dyn. 25(4)).
  No thruster force is ever clipped on its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numba import njit

from rovlab.allocation.geometry import configuration_matrix
from rovlab.models.thrusters import ThrusterBank, bank_pwm
from rovlab.params.vehicle import WRENCH6, Vehicle

DEFAULT_PRIORITY: tuple[tuple[str, ...], ...] = (("K", "M"), ("Z",), ("N",), ("X", "Y"))
SCALE_ALL: tuple[tuple[str, ...], ...] = (WRENCH6,)
_TOL = 1e-9


def weighted_pinv(B: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """T (n x 6) minimising f^T W f subject to B f = tau (least squares if B lacks rank)."""
    n = B.shape[1]
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (n,) or np.any(~np.isfinite(w)) or np.any(w <= 0):
        raise ValueError(f"thruster weights must be {n} positive numbers, got {w.tolist()}")
    s = 1.0 / np.sqrt(w)
    return s[:, None] * np.linalg.pinv(B * s[None, :])


@njit(cache=True)
def matvec(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A @ v as a plain loop: for these 6 x n matrices a BLAS call costs more than the sums."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        acc = 0.0
        for j in range(A.shape[1]):
            acc += A[i, j] * v[j]
        out[i] = acc
    return out


@njit(cache=True)
def _max_fraction(f: np.ndarray, d: np.ndarray, f_min: np.ndarray, f_max: np.ndarray,
                  free: np.ndarray) -> float:
    alpha = 1.0
    for i in range(f.shape[0]):
        if not free[i]:
            continue
        if d[i] > _TOL:
            alpha = min(alpha, (f_max[i] - f[i]) / d[i])
        elif d[i] < -_TOL:
            alpha = min(alpha, (f_min[i] - f[i]) / d[i])
    return max(alpha, 0.0)


@njit(cache=True)
def _add_wrench(B: np.ndarray, T: np.ndarray, s: np.ndarray, f_min: np.ndarray, f_max: np.ndarray,
                f: np.ndarray, dtau: np.ndarray, redistribute: bool) -> float:
    """Add the largest fraction a in [0, 1] of the wrench increment dtau to the forces f (in
    place) that keeps every thruster within its limits, without changing the direction of
    dtau; return a. Redundant sets redistribute over unsaturated thrusters first."""
    n = B.shape[1]
    free_all = np.ones(n, dtype=np.bool_)
    d = matvec(T, dtau)
    total = _max_fraction(f, d, f_min, f_max, free_all)
    f += total * d
    if not redistribute or total >= 1.0 - _TOL or n <= 6:
        return total
    free = free_all.copy()
    for _ in range(n):
        n_free = 0
        for i in range(n):
            if f[i] >= f_max[i] - 1e-9 or f[i] <= f_min[i] + 1e-9:
                free[i] = False  # freeze thrusters sitting at a limit
            if free[i]:
                n_free += 1
        if n_free < 6:
            break
        Bs = np.zeros((6, n))
        for i in range(n):
            if free[i]:
                Bs[:, i] = B[:, i] * s[i]
        Tf = np.linalg.pinv(Bs)
        for i in range(n):
            Tf[i, :] *= s[i]
        rest = (1.0 - total) * dtau
        d2 = Tf @ rest
        # accept only if the free thrusters reproduce the remaining wrench exactly
        if np.max(np.abs(B @ d2 - rest)) > 1e-7 * (1.0 + np.max(np.abs(rest))):
            break
        a2 = _max_fraction(f, d2, f_min, f_max, free)
        f += a2 * d2
        total += (1.0 - total) * a2
        if a2 >= 1.0 - _TOL or a2 <= _TOL:
            break
    return total


@njit(cache=True)
def allocate_kernel(B: np.ndarray, T: np.ndarray, s: np.ndarray, f_min: np.ndarray, f_max: np.ndarray,
                    tau: np.ndarray, level: np.ndarray, n_levels: int, redistribute: bool):
    """Prioritised, direction-preserving allocation. Returns (f, fraction per DOF).

    ``level[j]`` is the priority level of DOF j (0 = highest); ``s`` = W^-1/2 is used to build
    weighted pseudo-inverses of thruster subsets when redistributing.

    1. The whole wrench at once: if it is feasible (possibly after redistribution) it is met
       exactly and nothing else is done.
    2. Otherwise level by level from the top, each adding the largest feasible fraction of its
       own wrench on top of the levels above (lower levels start at zero).
    3. Two more sweeps in priority order let each level grow further where the levels added
       after it have freed thruster capacity (their forces can cancel), so the top level never
       gets less than it would alone.
    """
    n = B.shape[1]
    f = np.zeros(n)
    frac = np.ones(6)
    total = _add_wrench(B, T, s, f_min, f_max, f, tau.copy(), redistribute)
    if total >= 1.0 - _TOL or n_levels == 1:
        for j in range(6):
            if tau[j] != 0.0:
                frac[j] = 1.0 if total >= 1.0 - _TOL else total
        return f, frac
    f[:] = 0.0
    alpha = np.zeros(n_levels)
    for sweep in range(3):
        for lv in range(n_levels):
            if alpha[lv] >= 1.0 - _TOL:
                continue
            dtau = np.zeros(6)
            any_dof = False
            for j in range(6):
                if level[j] == lv and tau[j] != 0.0:
                    dtau[j] = (1.0 - alpha[lv]) * tau[j]
                    any_dof = True
            if not any_dof:
                alpha[lv] = 1.0
                continue
            a = _add_wrench(B, T, s, f_min, f_max, f, dtau, redistribute)
            alpha[lv] += (1.0 - alpha[lv]) * a
    for j in range(6):
        if tau[j] != 0.0:
            frac[j] = alpha[level[j]]
    return f, frac


@dataclass(frozen=True)
class AllocationResult:
    forces: np.ndarray  # per thruster [N]
    pwm_us: np.ndarray  # per thruster [us]
    demanded: np.ndarray  # 6-DOF wrench asked for [X, Y, Z, K, M, N]
    achieved: np.ndarray  # 6-DOF wrench the forces produce
    fraction: np.ndarray  # per DOF: achieved share of the demand (1 = met)
    saturated: bool  # some DOF could not be met in full
    thruster_names: tuple[str, ...]

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
        }


class Allocator:
    """Allocation for one vehicle: precomputes B, its weighted pseudo-inverse and the limits.

    ``priority`` lists DOF groups from most to least important (a DOF not listed goes last);
    ``SCALE_ALL`` keeps the whole wrench direction instead. ``saturation=False`` gives the
    plain unconstrained pseudo-inverse (forces may exceed the limits; PWM is then saturated).
    """

    def __init__(self, vehicle: Vehicle, *, priority: Sequence[Sequence[str]] = DEFAULT_PRIORITY,
                 weights: np.ndarray | None = None, saturation: bool = True) -> None:
        self.vehicle = vehicle
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
        return allocate_kernel(self.B, self.T, self._s, self.bank.f_min, self.bank.f_max, tau6,
                               self.level, self.n_levels, True)

    def allocate(self, tau: np.ndarray) -> AllocationResult:
        """Allocate a 6-DOF wrench [X, Y, Z, K, M, N] or a 4-DOF one [X, Y, Z, N] (K = M = 0)."""
        tau6 = as_wrench6(tau)
        f, frac = self.forces(tau6)
        pwm = bank_pwm(self.bank.rows, self.bank.grid_pwm, self.bank.grid_force, f)
        if not self.saturation:
            f_real = np.clip(f, self.bank.f_min, self.bank.f_max)
            achieved = self.B @ f_real
            sat = bool(np.any(f > self.bank.f_max + 1e-9) or np.any(f < self.bank.f_min - 1e-9))
            frac = np.array([a / d if abs(d) > 1e-12 else 1.0 for a, d in zip(achieved, tau6)])
            f = f_real
        else:
            achieved = self.B @ f
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
