"""Allocation kernels in plain Python written in numba's subset (no numba import).

:mod:`rovlab.allocation.solvers` publishes them compiled (``allocate_kernel`` and ``matvec``:
what the simulator's compiled loop calls) and runs these plain versions for one-off use
(``Allocator(..., compiled=False)``: ``rovlab allocate`` never imports numba nor compiles).
The algorithm is described in :mod:`rovlab.allocation.solvers`.
"""

from __future__ import annotations

import numpy as np

_TOL = 1e-9

KERNELS = ("matvec", "_max_fraction", "_add_wrench", "allocate_kernel")


def matvec(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A @ v as a plain loop: for these 6 x n matrices a BLAS call costs more than the sums."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        acc = 0.0
        for j in range(A.shape[1]):
            acc += A[i, j] * v[j]
        out[i] = acc
    return out


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
