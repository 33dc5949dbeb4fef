"""Controllers compared on one scenario, from the same seeds (issue 12: MRAC against LQG).

For each seed the scenario is drawn once (rovlab.sim.scenario: distributions and noise come
from the seed alone) and run once per controller, so every controller meets exactly the same
plant, noise, sensors and disturbances. Judged on the **true** depth against the **reference
model** z_m of the configuration's [mrac] table (second order, omega_m, zeta_m, started at the
true initial depth, at rest), the same yardstick for every controller, adaptive or not:

``depth_error_rms`` / ``depth_error_peak``
    RMS / largest |z - z_m| from the change (the first truth event; without one, ``t_change``
    below) to the end [m].
``settling_time_s``
    time after the change until |z - z_m| stays within ``band`` (1 cm) to the end (None: never).
``last10s_rms``
    RMS of z - z_m over the last 10 s [m].
``effort_rms``
    RMS of the achieved heave force from the change to the end [N].
``saturation_s``
    time during which the allocation could not give the demanded heave force or yaw moment
    (more than 1 mN / 1 mN m short) [s].
``parameter_bounds_held``
    adaptive controllers: every adapted parameter stayed within its projection bounds.
``diverged``
    a non-finite value or |z - z_m| above 1 m.

**Controllers at equal stiffness** (issue 28, item 3). Besides the components (``lqg``,
``mrac``, ...) a comparison may name *variants*: a component run with a configuration derived
from the scenario's (:data:`VARIANTS`).

``lqg-matched``
    the LQG as stiff as MRAC. MRAC's heave law, linearised at rest, is a PID on e = z - z_m
    (rovlab.control.mrac.equivalent_gains): state feedback K_z = lambda k_s, K_w = k_s + lambda M_0 -
    D_l0 (160 N/m and 111.7 N s/m for the thesis configuration's [mrac] table), plus the adapted
    net force, an integral of s (K_p = K_z + Gamma_F = 460 N/m, K_i = lambda Gamma_F = 600 N/(m s)).
    The variant keeps the LQG law and (i) solves the LQR's heave weights Q_z, Q_w (R and the heading
    weights unchanged) so that the discrete LQR's K on [z, w] equals [K_z, K_w]
    (:func:`match_lqr`); (ii) solves the filter's heave-bias spectral density psd.b_w so that the
    bias estimate gives the loop the same integral action as MRAC's adapted F: the effective integral
    gain, a force step divided by the integral of the depth error it leaves (for a PID exactly K_i),
    computed for both on the linear design model sampled at h with their filters
    (:func:`force_step_response`, :func:`match_bias_psd`); (iii) gives the LQG MRAC's reference
    model with its feed-forward ([lqg] reference_model, rovlab.control.lqg), so that both follow
    the same z_m. What remains between ``lqg-matched`` and ``mrac`` is the adaptation.
``mrac-f-only``
    MRAC adapting only the net force F (the gains of M, D_l and D_q set to 0: the model's values
    throughout): what adapting the mass and the damping adds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rovlab.control.lqg import LQGConfig
from rovlab.control.lqr import design_lqr_from_config
from rovlab.control.mrac import PARAMETERS, adapt, design_mrac, equivalent_gains, heave_law, reference_model
from rovlab.core.components import component_names
from rovlab.models.discretise import zoh
from rovlab.params.design import DesignConfig
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle
from rovlab.sim.designs import DesignBook
from rovlab.sim.prepare import prepare
from rovlab.sim.results import SimResult
from rovlab.sim.runner import run_prepared
from rovlab.sim.scenario import Scenario, scenario_from_dict

BAND_M = 0.01
LAST_S = 10.0
DIVERGED_M = 1.0
METRICS = ("depth_error_rms", "depth_error_peak", "settling_time_s", "last10s_rms", "effort_rms", "saturation_s")


# --------------------------------------------------------------------------------------------
# Controllers at equal stiffness: the variants
# --------------------------------------------------------------------------------------------

MATCH_RTOL = 1e-3  # relative tolerance of the matched gains (K_z, K_w and the integral gain)
_HEAVE = ("z", "w", "b_w")  # the heave states of the depth-and-heading filter


def _heave_filter(vehicle: Vehicle, config: DesignConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, Delta_Z, steady-state Kalman gain, H) of the filter's heave states [z, w, b_w] (the
    depth-and-heading KF of the configuration, every channel that measures one of them)."""
    from scipy.linalg import solve_discrete_are

    from rovlab.estimation.model import build_filter_model

    fm = build_filter_model(vehicle, config)
    idx = [fm.states.index(q) for q in _HEAVE]
    rows = [j for j in range(fm.H.shape[0]) if np.any(fm.H[j, idx] != 0.0)]
    Phi = fm.Phi[np.ix_(idx, idx)]
    H = fm.H[np.ix_(rows, idx)]
    R = fm.R[np.ix_(rows, rows)]
    P = solve_discrete_are(Phi.T, H.T, fm.Q[np.ix_(idx, idx)], R)  # the prior's steady state
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    return Phi, fm.Delta[idx, fm.inputs.index("Z")], K, H


def force_step_response(vehicle: Vehicle, config: DesignConfig, controller: str, *, step: float = 1.0,
                        duration_s: float = 120.0, filtered: bool = True) -> dict[str, Any]:
    """A heave force step on the linear design model (m - Z_wdot, Z_w of the configuration),
    sampled at its h as the loop does it (filter correction, law, plant and prediction over one
    sample), from rest at the set-point, with the configuration's filter (steady-state gain) and
    ``controller`` ("lqg": its K and b_w; "mrac": its law and adaptation, reference model at rest;
    ``filtered=False``: MRAC's law on the true z and w instead of the filter's).

    Returns the depth error z and the force estimate the law used (b_w or F_hat) per sample, and
    ``integral_gain``: step / (sum of z h), the effective integral gain [N/(m s)] (for a PID
    exactly its K_i), ``peak_m`` and ``estimate_iae_s`` (integral of |1 - estimate / step|)."""
    h = float(config.sample_time)
    mv = config.model_values(vehicle)
    M, D = mv["m"] - mv["Z_wdot"], -mv["Z_w"]
    Php, Gp = zoh(np.array([[0.0, 1.0], [0.0, -D / M]]), np.array([[0.0], [1.0 / M]]), h)
    Phi, Dz, Kf, H = _heave_filter(vehicle, config)
    n = int(math.ceil(duration_s / h))
    if controller == "mrac":
        d = design_mrac(vehicle, config)
        c = d.config
        st = np.concatenate([d.theta0, [0.0, 0.0]])
        Y = np.zeros(4)
        F0 = float(d.theta0[3])

        def law(xh: np.ndarray) -> tuple[float, float]:
            Z, s_ = heave_law(st, xh[0], xh[1], 0.0, 0.0, 0.0, c.lam, c.k_s, Y)
            used = float(st[3]) - F0
            adapt(st, Y, s_, d.gamma, c.sigma, d.theta0, d.lo, d.hi, h)
            return Z + F0, used  # deviations from the balance at rest (Z = -F0)
        x = np.zeros(2)
        xh = np.zeros(3)
        z = np.empty(n)
        est = np.empty(n)
        for k in range(n):
            xh = xh + Kf @ (H[:, :2] @ x - H @ xh)
            Z, est[k] = law(xh if filtered else x)
            z[k] = x[0]
            x = Php @ x + Gp[:, 0] * (Z + step)
            xh = Phi @ xh + Dz * Z
    elif controller == "lqg" and filtered:
        # the same sample as above, linear: X = [z, w, z_hat, w_hat, b_hat] (prior), X+ = A X + b step
        K = design_lqr_from_config(vehicle, config).K
        corr = np.block([[np.eye(2), np.zeros((2, 3))], [Kf @ H[:, :2], np.eye(3) - Kf @ H]])  # after the correction
        L = np.array([0.0, 0.0, K[0, 0], K[0, 2], 1.0])  # Z = -L X+
        A = np.zeros((5, 5))
        A[:2] = np.hstack([Php, np.zeros((2, 3))]) - np.outer(Gp[:, 0], L)
        A[2:] = np.hstack([np.zeros((3, 2)), Phi]) - np.outer(Dz, L)
        A = A @ corr
        b = np.concatenate([Gp[:, 0], np.zeros(3)]) * step
        X = np.zeros((n, 5))
        for k in range(1, n):
            X[k] = A @ X[k - 1] + b
        z = X[:, 0]
        est = (X @ corr.T)[:, 4]
    else:
        raise ValueError(f"controller must be 'lqg' (filtered) or 'mrac', got {controller!r}")
    # the integral of the depth error above where it settles: a filter whose bias is a Gauss-Markov
    # state (not a random walk) leaves an offset of ~1e-7 m/N that would otherwise grow the integral
    area = float(np.sum(z - z[-1]) * h)
    peak = float(np.max(np.abs(z)))
    return {"z": z, "estimate": est, "h": h, "integral_gain": step / area if area > 0 else math.inf,
            "peak_m": peak / abs(step), "estimate_iae_s": float(np.sum(np.abs(1.0 - est / step)) * h),
            "offset_m": float(z[-1]) / abs(step),
            "settled": bool(np.max(np.abs(np.diff(z[-20:]))) < 1e-6 * max(peak, 1e-300)
                            and abs(est[-1] / step - 1.0) < 1e-3)}


def match_lqr(vehicle: Vehicle, config: DesignConfig, K_z: float, K_w: float) -> DesignConfig:
    """The configuration with the LQR's heave weights Q_z, Q_w solved so that the discrete LQR's
    gains on z and w are K_z and K_w (within MATCH_RTOL); R and the heading weights unchanged.
    ConfigError when no positive weights give them (a K_w too small for K_z: the LQR's return
    difference condition)."""
    from scipy.optimize import least_squares

    target = np.array([K_z, K_w])

    def with_q(logq: np.ndarray) -> DesignConfig:
        Q = np.array(config.lqr_Q, dtype=float)
        Q[0], Q[2] = np.exp(logq)
        return replace(config, lqr_Q=Q, lqr_bryson=None)

    def residual(logq: np.ndarray) -> np.ndarray:
        K = design_lqr_from_config(vehicle, with_q(logq)).K
        return (K[0, [0, 2]] - target) / target

    mv = config.model_values(vehicle)
    M, D = mv["m"] - mv["Z_wdot"], -mv["Z_w"]
    r = float(config.lqr_R[0])
    # start: the continuous LQR of the heave model, K_z = sqrt(q_z / r), q_w = r (K_w^2 + 2 D K_w - 2 M K_z)
    q0 = np.array([r * K_z**2, max(r * (K_w**2 + 2.0 * D * K_w - 2.0 * M * K_z), 1e-3 * r * K_w**2)])
    try:
        sol = least_squares(residual, np.log(q0), xtol=1e-14, ftol=1e-14, gtol=1e-14)
        ok = bool(np.max(np.abs(sol.fun)) < MATCH_RTOL)
    except ConfigError:
        ok = False
    if not ok:
        raise ConfigError([Problem(config.file or config.name, "mrac", {"K_z": K_z, "K_w": K_w},
                                   "MRAC gains an LQR can have: positive weights on z and w give K_w = "
                                   f"{K_w:.4g} N s/m with K_z = {K_z:.4g} N/m only when K_w^2 + 2 D K_w > 2 M K_z "
                                   f"(M = {M:.4g} kg, D = {D:.4g} N s/m); raise mrac.k_s or lower mrac.lambda")],
                          "filter configuration")
    return with_q(sol.x)


def match_bias_psd(vehicle: Vehicle, config: DesignConfig, integral_gain: float) -> DesignConfig:
    """The configuration with the filter's heave-bias spectral density psd.b_w solved so that the
    LQG's effective integral gain (force_step_response) is ``integral_gain`` (within MATCH_RTOL)."""
    from scipy.optimize import brentq

    def with_psd(log_psd: float) -> DesignConfig:
        psd = np.array(config.psd, dtype=float)
        psd[4] = math.exp(log_psd)
        return replace(config, psd=psd)

    def gap(log_psd: float) -> float:
        return math.log(force_step_response(vehicle, with_psd(log_psd), "lqg")["integral_gain"] / integral_gain)

    lo, hi = math.log(1e-6), math.log(1e6)
    if not gap(lo) < 0.0 < gap(hi):
        raise ConfigError([Problem(config.file or config.name, "process_noise.psd.b_w", float(config.psd[4]),
                                   f"a heave-bias density for which the LQG's integral gain can be {integral_gain:.4g} "
                                   "N/(m s) (none between 1e-6 and 1e6)")], "filter configuration")
    return with_psd(brentq(gap, lo, hi, xtol=1e-6, rtol=1e-9))


def matched_lqg(vehicle: Vehicle, config: DesignConfig) -> tuple[DesignConfig, dict[str, Any]]:
    """The ``lqg-matched`` variant's configuration (module docstring) and what it matched."""
    mrac_design = design_mrac(vehicle, config)
    g = equivalent_gains(mrac_design)
    ref = config.table("mrac")
    out = match_lqr(vehicle, config, g["K_z"], g["K_w"])
    mrac_step = force_step_response(vehicle, config, "mrac")
    out = match_bias_psd(vehicle, out, mrac_step["integral_gain"])
    out = replace(out, name=f"{config.name}, LQG matched to MRAC", controller="lqg",
                  tables={**out.tables, "lqg": LQGConfig(reference_model=True, bandwidth=ref.bandwidth,
                                                         damping=ref.damping, given=True,
                                                         source="rovlab compare: MRAC's reference model")})
    lqr = design_lqr_from_config(vehicle, out)
    lqg_step = force_step_response(vehicle, out, "lqg")
    thesis_step = force_step_response(vehicle, config, "lqg", duration_s=2000.0)
    thesis_K = design_lqr_from_config(vehicle, config).K
    q = np.asarray(out.lqr_Q)
    info = {
        "mrac": {"K_z": g["K_z"], "K_w": g["K_w"], "K_p": g["K_p"], "K_i": g["K_i"], "M_0": g["M_0"],
                 "D_l0": g["D_l0"], "Gamma_F": g["Gamma_F"],
                 "closed_loop_poles": [[p.real, p.imag] for p in g["poles"]],
                 "integral_gain_sampled": mrac_step["integral_gain"], "peak_m_per_N": mrac_step["peak_m"],
                 "estimate_iae_s": mrac_step["estimate_iae_s"]},
        "lqg-matched": {"K_z": float(lqr.K[0, 0]), "K_w": float(lqr.K[0, 2]), "Q_z": float(q[0]), "Q_w": float(q[2]),
                        "R_Z": float(np.asarray(out.lqr_R)[0]), "z_max_m": float(1.0 / math.sqrt(q[0])),
                        "w_max_m_s": float(1.0 / math.sqrt(q[2])), "psd_b_w": float(out.psd[4]),
                        "integral_gain_sampled": lqg_step["integral_gain"], "peak_m_per_N": lqg_step["peak_m"],
                        "estimate_iae_s": lqg_step["estimate_iae_s"],
                        "reference_model": {"bandwidth_rad_s": ref.bandwidth, "damping": ref.damping}},
        "lqg": {"K_z": float(thesis_K[0, 0]), "K_w": float(thesis_K[0, 2]), "psd_b_w": float(config.psd[4]),
                "integral_gain_sampled": thesis_step["integral_gain"], "peak_m_per_N": thesis_step["peak_m"],
                "estimate_iae_s": thesis_step["estimate_iae_s"]},
        "tolerance": MATCH_RTOL,
        "definitions": {
            "K_z, K_w": "heave state feedback on z [N/m] and w [N s/m] (MRAC: lambda k_s, k_s + lambda M_0 - D_l0)",
            "K_p, K_i": "MRAC with its adapted net force as a PID: K_z + Gamma_F [N/m], lambda Gamma_F [N/(m s)]",
            "integral_gain_sampled": "a 1 N heave force step on the linear design model, sampled at h with the "
                                     "controller's filter: 1 N / integral of the depth error [N/(m s)]",
            "peak_m_per_N": "largest depth error after that step [m per N]",
            "estimate_iae_s": "integral of |1 - force estimate / step| after it [s]",
        },
    }
    return out, info


def mrac_force_only(vehicle: Vehicle, config: DesignConfig) -> tuple[DesignConfig, dict[str, Any]]:
    """The ``mrac-f-only`` variant: MRAC with the adaptation gains of M, D_l and D_q set to 0."""
    mc = config.table("mrac")
    gain = {**mc.gain, "M": 0.0, "D_l": 0.0, "D_q": 0.0}
    return (replace(config.with_table("mrac", replace(mc, gain=gain)), controller="mrac",
                    name=f"{config.name}, MRAC adapting F only"), {"gain": gain})


@dataclass(frozen=True)
class Variant:
    """A controller of a comparison that is a component with a derived configuration."""

    component: str
    derive: Callable[[Vehicle, DesignConfig], tuple[DesignConfig, dict[str, Any]]]
    description: str


VARIANTS: dict[str, Variant] = {
    "lqg-matched": Variant("lqg", matched_lqg, "the LQG as stiff as MRAC: LQR heave gains = MRAC's state feedback, "
                                               "bias density giving MRAC's integral gain, MRAC's reference model"),
    "mrac-f-only": Variant("mrac", mrac_force_only, "MRAC adapting only the net force F (M, D_l, D_q at the model)"),
}


def controller_names() -> tuple[str, ...]:
    """Every name a comparison takes: the controller components, then the variants."""
    return (*component_names("controller"), *VARIANTS)


def component_of(name: str) -> str:
    """The controller component a comparison's controller name runs (itself unless a variant)."""
    return VARIANTS[name].component if name in VARIANTS else name


def reference_model_response(sc: Scenario, times: np.ndarray, omega: float, zeta: float) -> np.ndarray:
    """z_m at the given (equally spaced) times for the scenario's depth schedule, exact with the
    set-point held between samples, from the true initial depth at rest."""
    h = float(times[1] - times[0]) if len(times) > 1 else 0.1
    A, B = reference_model(omega, zeta)
    Phi, G = zoh(A, B, h)
    idx = np.maximum(np.searchsorted(sc.reference_times, times, side="right") - 1, 0)
    r = sc.reference_z[idx]
    x = np.array([sc.initial[2], 0.0])
    out = np.empty(len(times))
    for k in range(len(times)):
        out[k] = x[0]
        x = Phi @ x + G[:, 0] * r[k]
    return out


def change_time(sc: Scenario) -> float:
    """When the disturbance starts: the first truth event, else a quarter of the run (a tether
    pull acts from the start; the first quarter holds the initial depth step)."""
    return float(sc.events[0].t_s) if sc.events else 0.25 * sc.duration_s


def run_metrics(result: SimResult, zm: np.ndarray, t_change: float, bounds: tuple[np.ndarray, np.ndarray] | None
                ) -> dict[str, Any]:
    """The numbers of one run (module docstring)."""
    c = result.columns
    t = c["time_s"]
    h = float(t[1] - t[0])
    err = c["true_z"] - zm
    win = t >= t_change - 1e-9
    last = t >= t[-1] - LAST_S + 1e-9
    out: dict[str, Any] = {
        "depth_error_rms": _rms(err[win]), "depth_error_peak": float(np.max(np.abs(err[win]))),
        "settling_time_s": _settling(t[win], err[win], t_change), "last10s_rms": _rms(err[last]),
        "effort_rms": _rms(c["tau_Z"][win]),
    }
    short = np.zeros(len(t), dtype=bool)
    for o in ("Z", "N"):
        if f"tau_{o}" in c:
            short |= np.abs(c[f"tau_{o}_demanded"] - c[f"tau_{o}"]) > 1e-3
    out["saturation_s"] = float(short.sum() * h)
    finite = all(np.all(np.isfinite(v)) for k, v in c.items() if k.startswith(("true_", "tau_", "ctrl_")))
    out["diverged"] = bool(not finite or not np.all(np.abs(err) < DIVERGED_M))
    if bounds is not None:
        lo, hi = bounds
        held = True
        finals = {}
        for i, p in enumerate(PARAMETERS):
            col = c.get(f"ctrl_{_state_name(p)}")
            if col is None:
                continue
            tol = 1e-9 * max(1.0, abs(lo[i]), abs(hi[i]))
            held &= bool(np.all((col >= lo[i] - tol) & (col <= hi[i] + tol)))
            finals[p] = float(col[-1])
        out["parameter_bounds_held"] = held
        out["parameters_final"] = finals
    return out


def _state_name(p: str) -> str:
    return f"{p}_hat"


def _rms(x: np.ndarray) -> float:
    return float(math.sqrt(np.mean(np.square(x)))) if x.size else math.nan


def _settling(t: np.ndarray, err: np.ndarray, t0: float) -> float | None:
    outside = np.nonzero(np.abs(err) > BAND_M)[0]
    if outside.size == 0:
        return 0.0
    if outside[-1] >= len(t) - 1:
        return None
    return float(t[outside[-1] + 1] - t0)


def compare(data: Mapping[str, Any], file: str, controllers: Sequence[str], seeds: Sequence[int], *,
            keep: int = 1, progress: Any = None) -> tuple[dict[str, Any], dict[str, list[SimResult]]]:
    """Run the scenario for every seed with every controller (same seeds, same draws).

    Returns (comparison, results): the comparison.json content, and the full results of the first
    ``keep`` seeds per controller (for figures)."""
    book = DesignBook()
    per: dict[str, list[dict[str, Any]]] = {c: [] for c in controllers}
    kept: dict[str, list[SimResult]] = {c: [] for c in controllers}
    first: Scenario | None = None
    refmodel: tuple[float, float] | None = None
    bounds_of: dict[str, Any] = {}
    derived: dict[str, tuple[DesignConfig, dict[str, Any]]] = {}
    done = 0
    for i, seed in enumerate(seeds):
        sc = scenario_from_dict(data, file=file, seed=seed)
        first = first or sc
        for ctl in controllers:
            comp = component_of(ctl)
            config = None
            if ctl in VARIANTS:
                if ctl not in derived:  # once per comparison: the scenario's vehicle and configuration
                    base = prepare(replace(sc, controller=comp), book=book)
                    derived[ctl] = VARIANTS[ctl].derive(base.vehicle, base.config)
                config = derived[ctl][0]
            prep = prepare(replace(sc, controller=comp), config=config, book=book)
            if refmodel is None:
                mc = prep.config.table("mrac")
                refmodel = (mc.bandwidth, mc.damping)
            model = prep.design.controller.model
            bounds = (model.lo, model.hi) if hasattr(model, "lo") and hasattr(model, "hi") else None
            if bounds is not None and ctl not in bounds_of:
                bounds_of[ctl] = model
            res = run_prepared(prep)
            t = res.columns["time_s"]
            zm = reference_model_response(sc, t, *refmodel)
            m = run_metrics(res, zm, change_time(sc), bounds)
            m["seed"] = seed
            per[ctl].append(m)
            if i < keep:
                res.columns["refmodel_z"] = zm
                kept[ctl].append(res)
            done += 1
            if progress:
                progress(done, len(seeds) * len(controllers))
    assert first is not None and refmodel is not None
    out: dict[str, Any] = {
        "scenario": first.name, "description": first.description, "source": first.source,
        "controllers": list(controllers), "runs": len(seeds), "seeds": [int(s) for s in seeds],
        "reference_model": {"bandwidth_rad_s": refmodel[0], "damping": refmodel[1]},
        "change_s": change_time(first), "band_m": BAND_M, "last_s": LAST_S,
        "definitions": {
            "depth_error": "true depth - reference model output z_m (same reference model for every controller)",
            "depth_error_rms": "RMS of the depth error from change_s to the end [m]",
            "depth_error_peak": "largest |depth error| from change_s to the end [m]",
            "settling_time_s": "time after change_s until |depth error| stays within band_m (null: never) [s]",
            "last10s_rms": "RMS of the depth error over the last 10 s [m]",
            "effort_rms": "RMS of the achieved heave force from change_s to the end [N]",
            "saturation_s": "time the allocation fell short of the demanded Z or N [s]",
            "parameter_bounds_held": "every adapted parameter stayed within its projection bounds in every run",
            "values": "with several runs: the mean over runs; 'spread' gives p95 and max",
        },
        "variants": {name: {"component": VARIANTS[name].component, "description": VARIANTS[name].description,
                            **derived[name][1]} for name in controllers if name in derived},
    }
    for ctl in controllers:
        runs = per[ctl]
        entry: dict[str, Any] = {}
        spread: dict[str, Any] = {}
        for key in METRICS:
            vals = [r[key] for r in runs]
            fin = np.array([v for v in vals if v is not None and math.isfinite(v)], dtype=float)
            if key == "settling_time_s" and len(fin) < len(vals):
                entry[key] = None  # some run never settled
                spread[key] = {"never_settled": len(vals) - len(fin),
                               **({"p95": float(np.percentile(fin, 95)), "max": float(fin.max())} if fin.size else {})}
                continue
            entry[key] = float(fin.mean()) if fin.size else None
            if fin.size:
                spread[key] = {"p95": float(np.percentile(fin, 95)), "max": float(fin.max()),
                               "min": float(fin.min())}
        entry["diverged"] = int(sum(r["diverged"] for r in runs))
        if ctl in bounds_of:
            model = bounds_of[ctl]
            entry["parameter_bounds_held"] = bool(all(r.get("parameter_bounds_held", False) for r in runs))
            entry["parameters"] = {
                p: {"initial": float(model.theta0[i]), "lower": float(model.lo[i]), "upper": float(model.hi[i]),
                    "final_mean": float(np.mean([r["parameters_final"][p] for r in runs]))}
                for i, p in enumerate(PARAMETERS)}
        entry["spread"] = spread
        entry["per_run"] = runs
        out[ctl] = entry
    return out, kept


def table(comparison: Mapping[str, Any]) -> str:
    """The comparison as a text table (one row per controller)."""
    ctls = comparison["controllers"]
    n = comparison["runs"]
    head = (f"{comparison['scenario']}: {n} run{'s' if n != 1 else ''} per controller, seeds "
            f"{comparison['seeds'][0]}..{comparison['seeds'][-1]}; error = true depth - reference model "
            f"(omega {comparison['reference_model']['bandwidth_rad_s']:g} rad/s, zeta "
            f"{comparison['reference_model']['damping']:g}); change at {comparison['change_s']:g} s"
            + ("; values are means over runs (max in brackets)" if n > 1 else ""))
    cols = [("RMS err [cm]", "depth_error_rms", 100.0), ("peak [cm]", "depth_error_peak", 100.0),
            ("settle [s]", "settling_time_s", 1.0), ("last 10 s [cm]", "last10s_rms", 100.0),
            ("effort [N]", "effort_rms", 1.0), ("saturated [s]", "saturation_s", 1.0)]
    header = f"{'controller':12s} " + " ".join(f"{c[0]:>16s}" for c in cols) + f" {'bounds':>7s} {'diverged':>8s}"
    lines = [head, header]
    for ctl in ctls:
        e = comparison[ctl]
        cells = []
        for _, key, k in cols:
            v = e.get(key)
            mx = e["spread"].get(key, {}).get("max")
            text = "-" if v is None else f"{v * k:.3g}"
            if n > 1 and mx is not None:
                text += f" ({mx * k:.3g})"
            if key == "settling_time_s" and e["spread"].get(key, {}).get("never_settled"):
                text += f" [{e['spread'][key]['never_settled']} never]"
            cells.append(f"{text:>16s}")
        held = e.get("parameter_bounds_held")
        lines.append(f"{ctl:12s} " + " ".join(cells) + f" {('-' if held is None else 'held' if held else 'LEFT'):>7s} "
                     f"{e['diverged']:>8d}")
    lines.append("('-': not applicable or never settled to 1 cm; bounds: adapted parameters within their "
                 "projection set)")
    variants = comparison.get("variants", {})
    m = variants.get("lqg-matched")
    if m:
        a, b, t = m["mrac"], m["lqg-matched"], m["lqg"]
        lines.append(f"lqg-matched: LQR K_z {b['K_z']:.4g} N/m, K_w {b['K_w']:.4g} N s/m = MRAC's lambda k_s, "
                     f"k_s + lambda M_0 - D_l0 (lqg: {t['K_z']:.3g}, {t['K_w']:.3g}); bias density b_w "
                     f"{b['psd_b_w']:.3g} (lqg: {t['psd_b_w']:.3g}) for MRAC's integral gain "
                     f"{a['integral_gain_sampled']:.4g} N/(m s) (lqg: {t['integral_gain_sampled']:.3g}); MRAC's "
                     "reference model in front")
    if "mrac-f-only" in variants:
        lines.append("mrac-f-only: MRAC adapting only the net force F (M, D_l, D_q held at the model)")
    return "\n".join(lines)


def figure(path: Any, comparison: Mapping[str, Any], kept: Mapping[str, list[SimResult]]) -> Any:
    """Overlay of the first seed's runs: depth, error against the reference model, heave force,
    and the adapted net force against the true one (matplotlib, imported here only)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    colours = {"lqg": "tab:blue", "lqg-matched": "tab:green", "mrac": "tab:red", "mrac-f-only": "tab:orange"}
    drawn_ref = False
    for ctl, results in kept.items():
        if not results:
            continue
        c = results[0].columns
        t = c["time_s"]
        col = colours.get(ctl)
        if not drawn_ref:
            ax[0].plot(t, c["ref_z"], "k:", lw=1, label="set-point")
            ax[0].plot(t, c["refmodel_z"], "k--", lw=1, label="reference model")
            if "true_b_w" in c:
                ax[3].plot(t, c["true_b_w"], "k--", lw=1, label="true net down force (weight - buoyancy + bias + pull)")
            drawn_ref = True
        ax[0].plot(t, c["true_z"], color=col, lw=1.2, label=f"{ctl}: true depth")
        ax[1].plot(t, 100.0 * (c["true_z"] - c["refmodel_z"]), color=col, lw=1.0, label=ctl)
        ax[2].plot(t, c["tau_Z"], color=col, lw=1.0, label=ctl)
        if "ctrl_F_hat" in c:
            ax[3].plot(t, c["ctrl_F_hat"], color=col, lw=1.2, label=f"{ctl}: adapted F")
        elif "est_b_w" in c:
            ax[3].plot(t, c["est_b_w"], color=col, lw=1.0, label=f"{ctl}: bias estimate b_w")
    t0 = comparison["change_s"]
    ax[1].axhspan(-100 * BAND_M, 100 * BAND_M, color="0.9", zorder=0,
                  label=f"±{100 * BAND_M:g} cm (settling band)")
    for i, a in enumerate(ax):
        a.axvline(t0, color="0.6", lw=0.8, label=f"change at {t0:g} s" if i == 0 else None)
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="best")
    ax[0].invert_yaxis()
    ax[0].set_ylabel("depth z [m] (down)")
    ax[1].set_ylabel("z - z_m [cm]")
    ax[2].set_ylabel("heave force Z [N]")
    ax[3].set_ylabel("net down force [N]")
    ax[3].set_xlabel("time [s]")
    ax[0].set_title(f"{comparison['scenario']} (seed {comparison['seeds'][0]}): " + " vs ".join(kept))
    fig.tight_layout()
    from rovlab.core.files import write_figure

    try:
        write_figure(fig, path, dpi=110)  # atomic: a full disk leaves no partial figure
    finally:
        plt.close(fig)
    return path
