"""The depth-and-heading Kalman filter as a closed-loop component (estimator slot).

A thin binding of the kernels of :mod:`rovlab.estimation.kalman` (correct with sensor
management, Joseph updates; predict with Phi, Delta, Q) to the slots of
:mod:`rovlab.core.components`: :class:`KalmanFilter` holds the filter's constants (the unpacked
model arrays) and its state (x, P, the channel states), :func:`build` designs it from a vehicle
and a configuration. The filter's input is [Z, N]: the heave force and yaw moment of the wrench
the allocation achieved.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit, plain
from rovlab.core.components import ComponentInfo, EstimatorSpec, register_component, register_estimator
from rovlab.core.summary import render
from rovlab.core.units import squared
from rovlab.core.units import unit as quantity_unit
from rovlab.estimation.fusion import new_channel_state
from rovlab.estimation.kalman import correct_arrays, pack_model, predict_arrays, unpack_model, work_size
from rovlab.estimation.model import FilterModel, build_filter_model
from rovlab.params.design import MEASURABLE, DesignConfig
from rovlab.params.vehicle import Vehicle

# what each state of the depth-and-heading model estimates (rovlab.core.components.TRUTH)
_NAV = {"z": "z", "psi": "psi", "w": "w", "r": "r", "b_w": "b_Z", "b_r": "b_N"}
_INPUTS = (2, 3)  # Z and N of the wrench [X, Y, Z, N]


class KalmanFilter(NamedTuple):
    Phi: np.ndarray
    Delta: np.ndarray
    Q: np.ndarray
    H: np.ndarray
    cfg: np.ndarray  # channel configuration (rovlab.estimation.fusion CFG_*)
    wrap: np.ndarray  # 1.0 for angle states
    sp: np.ndarray  # Phi in sparse form
    inputs: np.ndarray  # int64: indices of the model's inputs in the wrench [X, Y, Z, N]
    x: np.ndarray  # state estimate (n)
    P: np.ndarray  # covariance (n x n)
    ch: np.ndarray  # sensor-management state (m x N_CH)
    u: np.ndarray  # (p) work
    work: np.ndarray  # kernel scratch
    kappa: np.ndarray  # (p) relative uncertainty of each input (the thrusters' wrench)


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _correct(est, t, y, present, rep):
    correct_arrays(est.x, est.P, est.ch, est.H, est.cfg, est.wrap, t, y, present, rep, est.work)


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _predict(est, t, tau):
    for i in range(est.inputs.shape[0]):
        est.u[i] = tau[est.inputs[i]]
    predict_arrays(est.x, est.P, est.Delta, est.Q, est.wrap, est.sp, est.u, est.work, est.kappa)


register_estimator(KalmanFilter, state=("x", "P", "ch"), correct=_correct, predict=_predict)


def from_model(fm: FilterModel) -> KalmanFilter:
    """The component of a designed filter model, at its initial belief."""
    packed = pack_model(fm.Phi, fm.Delta, fm.Q, fm.H, fm.channel_config(), fm.wrap_states(), fm.input_uncertainty)
    # plain functions: set-up code run once, which need not compile anything
    Phi, Delta, Q, H, cfg, wrap, sp, kappa = (np.array(a, dtype=float, order="C")
                                              for a in plain(unpack_model)(packed))
    n, m = fm.Phi.shape[0], len(fm.channels)
    return KalmanFilter(Phi, Delta, Q, H, cfg, wrap, sp, np.array(_INPUTS, dtype=np.int64),
                        fm.x0.astype(float).copy(), fm.P0.astype(float).copy(), plain(new_channel_state)(m),
                        np.zeros(len(_INPUTS)), np.empty(plain(work_size)(n, m)), kappa)


def build(vehicle: Vehicle, config: DesignConfig, *, require_observable: bool = True) -> EstimatorSpec:
    """Design the depth-and-heading filter of a configuration (raises ConfigError; an unobservable
    sensor set too, unless not ``require_observable``: ``rovlab design --allow-unobservable``)."""
    fm = build_filter_model(vehicle, config, require_observable=require_observable)
    return EstimatorSpec(kernel=from_model(fm), states=tuple(fm.states), nav=tuple(_NAV[s] for s in fm.states),
                         channels=tuple(fm.channels), h=fm.h, model=fm)


def observer_model(spec: EstimatorSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The filter's own continuous model (A, B, E, W), the scenario's observer plant (Sandøy 2016,
    sec. 5.3: the case study on the observer model)."""
    fm = spec.model
    return fm.A, fm.B, fm.E, fm.W


def summary(spec: EstimatorSpec) -> dict[str, Any]:
    """The discretised depth-and-heading model (Sandøy 2016, secs. 5.1-5.2): the keys of
    ``rovlab design --json``."""
    from rovlab.estimation.model import describe_direction

    fm = spec.model
    p = fm.params
    return {
        "sample_time": fm.h,
        "states": list(fm.states),
        "inputs": list(fm.inputs),
        "measurements": [c.name for c in fm.channels],
        "Phi": fm.Phi.tolist(),
        "Delta": fm.Delta.tolist(),
        "Gamma": fm.Gamma.tolist(),
        "Q": fm.Q.tolist(),
        "H": fm.H.tolist(),
        "R": fm.R.tolist(),
        "observable": bool(fm.observable),
        "unobservable": list(fm.unobservable),
        "unobservable_directions": [describe_direction(fm.unobservable_directions[:, k])
                                    for k in range(fm.unobservable_directions.shape[1])],
        "model": {"M_w": p.M_w, "M_r": p.M_r, "Z_w": p.Z_w, "N_r": p.N_r, "T_w": fm.T_w, "T_r": fm.T_r},
        "W": np.diag(fm.W).tolist(),
    }


def describe(spec: EstimatorSpec) -> list[str]:
    """The design for people: SI units throughout (radians, never degrees), the same numbers as
    :func:`summary`, labelled."""
    fm = spec.model
    p = fm.params
    out = ["  units: states z [m], psi [rad], w [m/s], r [rad/s], b_w [N], b_r [N m]; inputs Z [N], N [N m]",
           f"  model: M_w = {p.M_w:.6g} kg, M_r = {p.M_r:.6g} kg m^2, Z_w = {p.Z_w:.6g} kg/s, "
           f"N_r = {p.N_r:.6g} kg m^2/s",
           f"    velocity time constants: heave M_w/-Z_w = {_ratio(p.M_w, -p.Z_w)}, "
           f"yaw M_r/-N_r = {_ratio(p.M_r, -p.N_r)}",
           f"  bias model (Gauss-Markov): time constants T_w = {fm.T_w:.6g} s (b_w), T_r = {fm.T_r:.6g} s (b_r)",
           "  process noise W = diag(" + ", ".join(f"{n} {v:.6g}" for n, v in zip(fm.states, np.diag(fm.W))) + ")",
           "  measurements (variance in the unit of the measured quantity squared):"]
    for c in fm.channels:
        gate = "off" if not np.isfinite(c.gate_threshold) else f"chi2 {c.gate_threshold:.3g}"
        unit = squared(quantity_unit(c.quantity)) or "(SI unit)^2"  # z m^2, psi rad^2, w m^2/s^2, r rad^2/s^2
        out.append(f"    {c.name:16s} column {c.column:14s} variance {c.variance:.6g} {unit}  l_z {c.offset:+.4g} m  "
                   f"timeout {c.timeout_s:g} s  gate {gate}")
    if fm.observable:
        out.append("  observable: yes")
    else:
        dirs = summary(spec)["unobservable_directions"]
        out.append(f"  observable: NO -- cannot estimate {', '.join(fm.unobservable)} ({'; '.join(dirs)})")
    for name in ("Phi", "Delta", "Gamma", "Q", "H", "R"):
        out.extend(render({name: getattr(fm, name)}))
    return out


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.6g} s" if b > 0 else "none (no damping)"


register_component(ComponentInfo(
    "kf", "estimator", build,
    description="depth-and-heading Kalman filter with bias states (Sandøy 2016, sec. 5.1)", measurable=MEASURABLE,
    observer_model=observer_model, summary=summary, describe=describe))
