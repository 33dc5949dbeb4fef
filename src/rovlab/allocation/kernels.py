"""Allocation kernels in plain Python written in numba's subset (no numba import).

:mod:`rovlab.allocation.solvers` publishes them compiled (``allocate_kernel`` and ``matvec``:
what the simulator's compiled loop calls) and runs these plain versions for one-off use
(``Allocator(..., compiled=False)``: ``rovlab allocate`` never imports numba nor compiles).
The algorithm (the exact lexicographic optimum by small LP stages) is in
:mod:`rovlab.allocation.lexicographic`, also plain; its functions are compiled together with
these (they are listed in KERNELS, so the compiled copies call each other).
"""

from __future__ import annotations

import numpy as np

from rovlab.allocation.lexicographic import (  # noqa: F401  (the compiled copies resolve these names here)
    _DEGENERATE_BEFORE_BLAND,
    _DIR_TOL,
    _DUAL_TOL,
    _FIXED,
    _FREE,
    _INEQ,
    _NULL_TOL,
    _fix_coordinate,
    _is_bound_of,
    _lp_stage,
    _pivot,
    _solve_small,
    least_distance,
    lexicographic_allocate,
    null_basis,
)

_TOL = 1e-9

KERNELS = ("matvec", "null_basis", "_pivot", "_lp_stage", "_fix_coordinate", "_is_bound_of", "_solve_small",
           "least_distance", "lexicographic_allocate", "allocate_kernel", "allocate_into")


def matvec(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A @ v as a plain loop: for these 6 x n matrices a BLAS call costs more than the sums."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        acc = 0.0
        for j in range(A.shape[1]):
            acc += A[i, j] * v[j]
        out[i] = acc
    return out


def allocate_kernel(B: np.ndarray, T: np.ndarray, s: np.ndarray, f_min: np.ndarray, f_max: np.ndarray,
                    tau: np.ndarray, level: np.ndarray, n_levels: int, redistribute: bool):
    """Prioritised, direction-preserving allocation. Returns (f, fraction per DOF).

    ``level[j]`` is the priority level of DOF j (0 = highest); ``s`` = W^-1/2 (T is the
    weighted pseudo-inverse built with it). Each level is scaled along its own direction by the
    largest fraction possible once the levels above hold theirs (the exact lexicographic
    optimum, found by small LP stages), DOFs demanded zero stay zero, and the forces are the
    least-effort ones giving that wrench; a feasible demand is met exactly. With one level this
    is the largest direction-preserving scaling of the whole wrench. ``redistribute=False``
    keeps the forces in the pseudo-inverse's range (no null-space use on redundant vehicles).
    See rovlab.allocation.lexicographic.
    """
    return lexicographic_allocate(B, T, s, f_min, f_max, tau, level, n_levels, redistribute)


def allocate_into(B: np.ndarray, T: np.ndarray, s: np.ndarray, f_min: np.ndarray, f_max: np.ndarray,
                  tau: np.ndarray, level: np.ndarray, n_levels: int, redistribute: bool,
                  f: np.ndarray, frac: np.ndarray) -> bool:
    """:func:`allocate_kernel` into f (n) and frac (6), for a caller stepping it every sample
    (the simulator's loop): a demand the pseudo-inverse meets within the limits (most samples)
    costs one matrix-vector product and allocates nothing. Returns whether it was met in full."""
    n = B.shape[1]
    inside = True
    for i in range(n):
        acc = 0.0
        for j in range(6):
            acc += T[i, j] * tau[j]
        f[i] = acc
        if acc > f_max[i] or acc < f_min[i]:
            inside = False
    if inside:
        for j in range(6):
            frac[j] = 1.0
        return True
    f2, frac2 = lexicographic_allocate(B, T, s, f_min, f_max, tau, level, n_levels, redistribute)
    met = True
    for i in range(n):
        f[i] = f2[i]
    for j in range(6):
        frac[j] = frac2[j]
        if frac2[j] < 1.0:
            met = False
    return met
