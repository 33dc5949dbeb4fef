"""Per-call cost of the 4-DOF model and of thrust allocation against plain numpy/scipy.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_model_allocation.py
(`make bench` runs every benchmark). Prints times and speed-up ratios measured in the same run.
Goal (issue 2): allocation including saturation handling well under 20 us per call on one core.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import _timing  # noqa: E402  (sets the thread variables before numpy loads)

import numpy as np  # noqa: E402
from scipy.optimize import lsq_linear  # noqa: E402

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


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


if __name__ == "__main__":
    main()
