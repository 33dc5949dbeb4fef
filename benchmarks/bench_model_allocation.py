"""Per-call cost of the 4-DOF model and of thrust allocation against plain numpy/scipy.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_model_allocation.py
(`make bench` runs every benchmark). Prints times and speed-up ratios measured in the same run.
Goal (issue 2): allocation including saturation handling well under 20 us per call on one core.
Issue 11: priority allocation is the exact lexicographic optimum; its kernel is timed on a set of
seeded random saturating demands against scipy's bounded least squares (lsq_linear, which neither
keeps K = M = 0 nor the wrench direction) and against the same lexicographic LP solved level by
level with scipy.optimize.linprog (HiGHS), whose fractions it also reports agreeing with.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import _timing  # noqa: E402  (sets the thread variables before numpy loads)
import numpy as np  # noqa: E402
from scipy.optimize import linprog, lsq_linear  # noqa: E402

from rovlab.allocation import SCALE_ALL, Allocator  # noqa: E402
from rovlab.allocation.solvers import allocate_kernel  # noqa: E402
from rovlab.models import kinetics as k  # noqa: E402
from rovlab.params import load_vehicle  # noqa: E402


def main() -> None:
    v = load_vehicle("udrone")
    p = k.pack(v)
    nu = np.array([0.3, 0.1, -0.2, 0.4])
    tau = np.array([5.0, 1.0, 3.0, 0.2])
    b = np.zeros(4)
    x = np.concatenate([np.zeros(4), nu])

    M = k.mass_matrix(v)

    def numpy_nu_dot():  # the textbook way: build the matrices, then solve
        lhs = (k.C_RB(v, nu) + k.C_A(v, nu) + k.D_L(v) + k.D_NL(v, nu)) @ nu + k.restoring(v)
        return np.linalg.solve(M, tau + b - lhs)

    rows = [
        ("nu_dot, compiled kernel", _timing.per_call(lambda: k.nu_dot_packed(p, nu, tau, b)),
         "numpy matrices + solve", _timing.per_call(numpy_nu_dot)),
        ("nu_dot, Python API nu_dot(vehicle, ...)", _timing.per_call(lambda: k.nu_dot(v, x[:4], nu, tau)),
         "numpy matrices + solve", _timing.per_call(numpy_nu_dot)),
        ("RK4 step (4 evaluations), compiled", _timing.per_call(lambda: k.rk4_step(p, x, tau, b, 0.01)),
         "RK4 with numpy nu_dot", _timing.per_call(lambda: [numpy_nu_dot() for _ in range(4)])),
    ]
    _timing.table("4-DOF model per call (uDrone)", rows)

    for name in ("udrone", "bluerov2_heavy"):
        veh = load_vehicle(name)
        alloc = Allocator(veh)
        scale = Allocator(veh, priority=SCALE_ALL)
        B = alloc.B
        feasible = np.array([5.0, 2.0, 8.0, 0.0, 0.0, 0.5])
        # beyond what the thrusters can give (uDrone: 1300-1700 us; Heavy: T200 at 16 V)
        hard = np.array([40.0, 10.0, 60.0, 0.0, 0.0, 3.0]) * (1.0 if name == "udrone" else 4.0)

        def lstsq():
            return np.linalg.lstsq(B, feasible, rcond=None)[0]

        def bounded(t=hard):
            return lsq_linear(B, t, bounds=(alloc.f_min, alloc.f_max)).x

        def kernel(t=hard):
            return allocate_kernel(alloc.B, alloc.T, alloc._s, alloc.f_min, alloc.f_max, t, alloc.level,
                                   alloc.n_levels, True)

        rows = [
            ("exact, feasible, forces (Allocator.forces)", _timing.per_call(lambda: alloc.forces(feasible)),
             "numpy.linalg.lstsq", _timing.per_call(lstsq)),
            ("full allocate() incl. PWM, feasible", _timing.per_call(lambda: alloc.allocate(feasible)),
             "numpy.linalg.lstsq (forces only)", _timing.per_call(lstsq)),
            ("saturating, priority, full allocate()", _timing.per_call(lambda: alloc.allocate(hard)),
             "scipy lsq_linear with bounds", _timing.per_call(bounded)),
            ("saturating, scale, full allocate()", _timing.per_call(lambda: scale.allocate(hard)),
             "scipy lsq_linear with bounds", _timing.per_call(bounded)),
            ("saturating, priority, compiled kernel", _timing.per_call(kernel),
             "scipy lsq_linear with bounds", _timing.per_call(bounded)),
        ]
        _timing.table(f"Allocation per call ({name}, {B.shape[1]} thrusters)", rows)
        res = alloc.allocate(hard)
        res_s = scale.allocate(hard)
        ls = B @ bounded()
        print(f"   demand {hard.tolist()} (not feasible):")
        print(f"     rovlab priority  -> {np.round(res.achieved, 2).tolist()}  (fractions per DOF "
              f"{np.round(res.fraction, 2).tolist()})")
        print(f"     rovlab scale     -> {np.round(res_s.achieved, 2).tolist()}  (angle to demand "
              f"{_angle(res_s.achieved, hard):.2f} deg)")
        print(f"     scipy lsq_linear -> {np.round(ls, 2).tolist()}  (angle to demand {_angle(ls, hard):.2f} deg, "
              f"K, M not kept at zero)")

    for name in ("udrone", "bluerov2_heavy"):
        _bench_lexicographic(name)


# demand scale per DOF [X, Y, Z (N), K, M, N (N m)], about 2-3x what the thrusters can give
_SCALES = {"udrone": np.array([60.0, 60.0, 80.0, 0.0, 0.0, 6.0]),
           "bluerov2_heavy": np.array([200.0, 200.0, 250.0, 0.0, 0.0, 30.0])}


def lexicographic_linprog(alloc: Allocator, tau6: np.ndarray) -> np.ndarray:
    """Fraction per priority level by scipy linprog (HiGHS), level by level: variables
    [f, alpha_l], B f = sum alpha_l tau_l, limits on f, 0 <= alpha <= 1, maximise the highest
    level's alpha, fix it, and so on (the peer: how one would do it with scipy)."""
    n = alloc.B.shape[1]
    levels = [lv for lv in range(alloc.n_levels) if np.any(tau6[alloc.level == lv] != 0.0)]
    A_eq = np.hstack([alloc.B, -np.array([np.where(alloc.level == lv, tau6, 0.0) for lv in levels]).T])
    bounds = list(zip(alloc.f_min, alloc.f_max)) + [(0.0, 1.0)] * len(levels)
    alpha = np.ones(alloc.n_levels)
    for j, lv in enumerate(levels):
        c = np.zeros(n + len(levels))
        c[n + j] = -1.0
        a = float(np.clip(linprog(c, A_eq=A_eq, b_eq=np.zeros(6), bounds=bounds, method="highs").x[n + j], 0, 1))
        bounds[n + j] = (a, a)
        alpha[lv] = a
    return alpha


def _bench_lexicographic(name: str) -> None:
    alloc = Allocator(load_vehicle(name))
    rng = np.random.default_rng(113)
    demands = rng.normal(size=(400, 6)) * _SCALES[name] * rng.uniform(0.5, 2.0, size=(400, 1))
    args = (alloc.B, alloc.T, alloc._s, alloc.f_min, alloc.f_max)
    saturating = [t for t in demands
                  if np.any(allocate_kernel(*args, t, alloc.level, alloc.n_levels, True)[1] < 1.0)]
    few = saturating[:40]  # the LP peers are slow; time them on the first 40

    def kernel_all(ds=saturating):
        for t in ds:
            allocate_kernel(*args, t, alloc.level, alloc.n_levels, True)

    def allocate_all(ds=saturating):
        for t in ds:
            alloc.allocate(t)

    def lsq_all(ds=few):
        for t in ds:
            lsq_linear(alloc.B, t, bounds=(alloc.f_min, alloc.f_max))

    def lp_all(ds=few):
        for t in ds:
            lexicographic_linprog(alloc, t)

    k_s = _timing.per_call(kernel_all) / len(saturating)
    a_s = _timing.per_call(allocate_all) / len(saturating)
    lsq_s = _timing.per_call(lsq_all, repeat=3) / len(few)
    lp_s = _timing.per_call(lp_all, repeat=3) / len(few)
    # worst single demand (best of 5 timings each) for the kernel
    worst = 0.0
    for t in saturating:
        worst = max(worst, _timing.per_call(lambda t=t: kernel_all([t]), min_time=0.002))
    rows = [
        ("priority kernel from Python, mean", k_s, "scipy lsq_linear with bounds", lsq_s),
        ("priority kernel from Python, mean", k_s, "lexicographic LP, scipy linprog (HiGHS)", lp_s),
        ("priority kernel, slowest demand (best of 5)", worst, "lexicographic LP, scipy linprog (HiGHS)", lp_s),
        ("full allocate() incl. PWM, mean", a_s, "lexicographic LP, scipy linprog (HiGHS)", lp_s),
    ]
    _timing.table(f"Exact priority allocation, {len(saturating)} seeded saturating demands ({name}, "
                  f"{alloc.B.shape[1]} thrusters)", rows)
    diff = max(float(np.max(np.abs(np.where(t != 0, lexicographic_linprog(alloc, t)[alloc.level], 1.0)
                                   - allocate_kernel(*args, t, alloc.level, alloc.n_levels, True)[1])))
               for t in few)
    print(f"   largest fraction difference to the linprog lexicographic optimum over {len(few)} demands: {diff:.1e}")


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


if __name__ == "__main__":
    main()
