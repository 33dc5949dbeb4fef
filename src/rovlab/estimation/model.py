"""The depth-and-heading observer model assembled from a vehicle and a configuration (Sandøy 2016, sec. 5.1).

State x = [z, psi, w, r, b_w, b_r], input u = [Z, N]. :func:`build_filter_model` takes the model
parameters from the vehicle file (or the configuration's overrides), builds A, B, E with
:func:`rovlab.models.linear.observer_model`, discretises them exactly (Phi, Delta, Gamma; Q by
Van Loan), turns each configured measurement into a channel (a row of H, its variance, its
lever-arm offset and its sensor-management settings) and checks that the configured sensor set
observes the whole state: an unobservable set is refused with a message naming the states it
cannot estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

# scipy (the discretisation, the observability test, chi-square quantiles) is imported where the
# design needs it, so that importing the filter (and loading a cached design) does not
from rovlab.models.linear import HeaveYawParams, observer_model
from rovlab.params.design import INPUTS, OBSERVER_STATES, DesignConfig
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import SENSOR_CHANNELS, Vehicle

STATES = OBSERVER_STATES


def _chi2_ppf(p: float, dof: int) -> float:
    """Quantile of the chi-square distribution (= scipy.stats.chi2.ppf(p, dof))."""
    from rovlab.estimation.consistency import chi2_ppf

    return float(chi2_ppf(p, dof))

_STATE_OF_QUANTITY = {"z": 0, "psi": 1, "w": 2, "r": 3}
_TIMEOUT_PERIODS = 5.0  # default timeout: this many sample periods of the sensor
_MIN_STUCK_SAMPLES = 5  # the variance check needs a few samples per block
_STARTUP_TOLERANCE = 0.01  # P has converged when every variance is within 1 % of its steady state
_STARTUP_TIME_CONSTANTS = 5.0  # then this many time constants of the error dynamics


@dataclass(frozen=True, eq=False)
class Channel:
    """One fused measurement: y_j = h_j x + offset_j + v_j, v_j ~ N(0, variance)."""

    name: str  # "<sensor>.<quantity>", e.g. "qualisys.z"
    column: str  # log column, "<quantity>_<sensor>", e.g. "z_qualisys"
    sensor: str
    kind: str
    quantity: str  # z, psi, w or r
    state_index: int
    offset: float  # subtracted from the raw sample (lever arm: z_VO = z_sensor - l_z)
    variance: float  # nominal R_j (SI units squared)
    timeout_s: float
    gate_probability: float
    gate_threshold: float  # chi-square (1 dof) bound on nu^2 / S; inf = no gate
    lose_after: int
    recovery_time_s: float
    recovery_samples: int  # N: samples over which a returning sensor's correction is spread (0: abrupt)
    reacquire_after_s: float
    startup_s: float  # no gate this long after the first sample
    stuck_samples: int  # samples per block of the variance (stuck) check; 0 = off
    stuck_bound: float  # lower chi-square quantile (stuck_samples - 1 dof) of the block scatter / R
    maneuver_acceleration: float = 1.0  # SI (rad/s^2 for psi): bound of a missed change's pull (0 = off)

    @property
    def angle(self) -> bool:
        return self.quantity == "psi"


@dataclass(frozen=True, eq=False)
class FilterModel:
    """Everything the discrete Kalman filter needs; immutable."""

    h: float  # sample time [s]
    params: HeaveYawParams
    T_w: float  # bias time constants [s]
    T_r: float
    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    W: np.ndarray
    Phi: np.ndarray
    Delta: np.ndarray
    Gamma: np.ndarray
    Q: np.ndarray
    channels: tuple[Channel, ...]
    H: np.ndarray  # m x 6
    R: np.ndarray  # m x m, diagonal
    x0: np.ndarray
    P0: np.ndarray
    observable: bool
    unobservable: tuple[str, ...]  # states that touch the unobservable subspace
    unobservable_directions: np.ndarray  # 6 x k basis (unit on a pivot state each)
    states: tuple[str, ...] = STATES
    inputs: tuple[str, ...] = INPUTS
    input_uncertainty: np.ndarray = field(default_factory=lambda: np.zeros(len(INPUTS)))  # kappa per input

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    def channel_config(self) -> np.ndarray:
        """The m x N_CFG array the compiled kernels read (see rovlab.estimation.fusion)."""
        return channel_config(self.channels, self.H)

    def wrap_states(self) -> np.ndarray:
        """Which states are angles kept in (-pi, pi] (psi)."""
        return np.array([s == "psi" for s in self.states], dtype=np.bool_)


def channel_config(channels: tuple[Channel, ...] | list[Channel], H: np.ndarray) -> np.ndarray:
    """The m x N_CFG array the compiled kernels read for channels with measurement rows H
    (see rovlab.estimation.fusion)."""
    from rovlab.estimation.layout import (
        CFG_ANGLE,
        CFG_GATE,
        CFG_LOSE_AFTER,
        CFG_MANEUVER,
        CFG_OFFSET,
        CFG_R,
        CFG_RAMP_N,
        CFG_RAMP_TIME,
        CFG_REACQUIRE,
        CFG_STARTUP,
        CFG_STATE,
        CFG_STUCK_BOUND,
        CFG_STUCK_N,
        CFG_TIMEOUT,
        N_CFG,
    )

    cfg = np.zeros((len(channels), N_CFG))
    for j, c in enumerate(channels):
        cfg[j, CFG_OFFSET] = c.offset
        cfg[j, CFG_R] = c.variance
        cfg[j, CFG_TIMEOUT] = c.timeout_s
        cfg[j, CFG_GATE] = c.gate_threshold
        cfg[j, CFG_LOSE_AFTER] = c.lose_after
        cfg[j, CFG_RAMP_TIME] = c.recovery_time_s
        cfg[j, CFG_RAMP_N] = c.recovery_samples
        cfg[j, CFG_ANGLE] = 1.0 if c.angle else 0.0
        cfg[j, CFG_REACQUIRE] = c.reacquire_after_s
        cfg[j, CFG_STARTUP] = c.startup_s
        cfg[j, CFG_STUCK_N] = c.stuck_samples
        cfg[j, CFG_STUCK_BOUND] = c.stuck_bound
        cfg[j, CFG_MANEUVER] = c.maneuver_acceleration
        row = H[j]
        unit = np.count_nonzero(row) == 1 and row[c.state_index] == 1.0
        cfg[j, CFG_STATE] = c.state_index if unit else -1
    return cfg


# --------------------------------------------------------------------------------------------
# Observability
# --------------------------------------------------------------------------------------------

def unobservable_subspace(A: np.ndarray, H: np.ndarray, *, rtol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis (n x k) of the unobservable subspace of (A, H); k = 0 when observable.

    The unobservable subspace is the largest A-invariant subspace inside ker H (Chen 2013,
    ch. 6): start from V = ker H and keep the part whose image under A stays in span V until it
    no longer shrinks. Rank decisions use singular values relative to the largest one of the
    matrix tested, so widely different time scales (bias time constants of 1844 s next to
    damping of 0.3 1/s) do not matter the way they do in the rank of [H; HA; ...; HA^5].
    """
    from scipy.linalg import null_space

    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    H = np.asarray(H, dtype=float).reshape(-1, n)
    V = null_space(H, rcond=rtol) if H.size else np.eye(n)
    while V.shape[1] > 0:
        C = A @ V - V @ (V.T @ A @ V)  # the part of A V leaving span V
        scale = max(float(np.linalg.norm(A, 2)), 1.0)
        N = null_space(C, rcond=rtol) if np.linalg.norm(C) > rtol * scale else np.eye(V.shape[1])
        if N.shape[1] == V.shape[1]:
            break
        V = V @ N
    return V


def _pivot_basis(V: np.ndarray) -> np.ndarray:
    """Rotate a subspace basis so that each column is 1 on its own pivot state."""
    from scipy.linalg import qr

    if V.shape[1] == 0:
        return V
    _, _, piv = qr(V.T, pivoting=True)
    pivots = piv[: V.shape[1]]
    Vp = V @ np.linalg.inv(V[pivots, :])
    Vp[np.abs(Vp) < 1e-12] = 0.0
    return Vp


def describe_direction(v: np.ndarray, names: tuple[str, ...] = STATES) -> str:
    terms = []
    for value, name in zip(v, names):
        if value == 0.0:
            continue
        if abs(value - 1.0) < 1e-9:
            terms.append(name)
        else:
            terms.append(f"{value:.3g} {name}")
    return " + ".join(terms).replace("+ -", "- ")


def observability(A: np.ndarray, H: np.ndarray, names: tuple[str, ...] = STATES
                  ) -> tuple[bool, tuple[str, ...], np.ndarray]:
    """(observable, states touching the unobservable subspace, its pivot basis)."""
    V = _pivot_basis(unobservable_subspace(A, H))
    touched = tuple(name for i, name in enumerate(names) if V.shape[1] and np.any(V[i, :] != 0.0))
    return V.shape[1] == 0, touched, V


# --------------------------------------------------------------------------------------------
# Start-up phase
# --------------------------------------------------------------------------------------------

_DIRECT_STEPS = 2_000  # the recursion step by step this long (every packaged design settles in < 300)


def startup_time(Phi: np.ndarray, Q: np.ndarray, H: np.ndarray, R: np.ndarray, P0: np.ndarray, h: float, *,
                 tolerance: float = _STARTUP_TOLERANCE, time_constants: float = _STARTUP_TIME_CONSTANTS,
                 max_steps: int = _DIRECT_STEPS) -> float:
    """How long the innovation gate should wait after the start [s].

    The gate tests innovations against the filter's own S = h P h^T + R, which is only right
    once P has left its (arbitrary) initial value P0 and the initial estimation error has decayed
    -- P0 = 0 in the thesis design claims a perfect start. With every channel sampled each step,
    the Riccati recursion from P0 converges to the steady-state prior covariance P_inf, and the
    error of the steady-state filter decays as the eigenvalues of Phi (I - K_inf H) (Anderson &
    Moore 1979, Optimal Filtering, ch. 4: exponential forgetting of the initial condition). The
    start-up phase is the number of steps until every diagonal entry of P is within ``tolerance``
    of P_inf, plus ``time_constants`` time constants of the slowest error mode.

    The recursion runs step by step for up to ``max_steps`` steps. A design that has not settled
    by then (a bias driven by almost no noise settles with its own time constant: psd.b_w = 1e-12
    takes ~10^5 steps of 0.1 s) continues by doubling (:func:`_riccati_doubling`): P_inf and the
    first step within ``tolerance`` of it in O(log steps) work, whatever the design.
    """
    n = Phi.shape[0]
    I = np.eye(n)
    P = np.array(P0, dtype=float)
    history = []
    settled = False
    for _ in range(max(1, min(int(max_steps), _DIRECT_STEPS))):
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        IKH = I - K @ H
        P = Phi @ (IKH @ P @ IKH.T + K @ R @ K.T) @ Phi.T + Q
        P = 0.5 * (P + P.T)
        history.append(np.diag(P).copy())
        if len(history) > 2 and np.allclose(history[-1], history[-2], rtol=1e-12, atol=0.0):
            settled = True
            break
    if settled:
        final = history[-1]
        k_conv = 0
        for k in range(len(history) - 1, -1, -1):
            if np.any(np.abs(history[k] - final) > tolerance * np.abs(final)):
                k_conv = k + 1
                break
    else:
        P, k_conv = _settle_by_doubling(Phi, Q, H, R, P, history, tolerance)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    rho = float(np.max(np.abs(np.linalg.eigvals(Phi @ (I - K @ H)))))
    tau = -h / math.log(rho) if 0.0 < rho < 1.0 else 0.0
    return float((k_conv + 1) * h + time_constants * tau)


_MAX_DOUBLINGS = 64  # 2^64 steps: beyond any float's resolution of a time


def _riccati_doubling(Phi: np.ndarray, Q: np.ndarray, H: np.ndarray, R: np.ndarray):
    """The 2^i-step maps of the filter's Riccati recursion P' = Phi P (I + G P)^-1 Phi^T + Q,
    G = H^T R^-1 H, by the structured doubling algorithm (Chu, Fan & Lin 2005, "A structure-preserving
    doubling algorithm for discrete-time algebraic Riccati equations"; Anderson & Moore 1979, ch. 6,
    for the doubling of the Riccati difference equation): the triple (A_i, G_i, H_i) maps any P0 to
    P_{2^i} = H_i + A_i^T P0 (I + G_i P0)^-1 A_i, and H_i is P_{2^i} from P0 = 0, which converges to
    P_inf quadratically. Yields the triples, one doubling at a time."""
    n = Phi.shape[0]
    I = np.eye(n)
    A, G, Hk = Phi.T.copy(), H.T @ np.linalg.solve(R, H), np.array(Q, dtype=float)
    for _ in range(_MAX_DOUBLINGS):
        yield A, G, Hk
        W = np.linalg.inv(I + G @ Hk)
        A, G, Hk = A @ W @ A, G + A @ W @ G @ A.T, Hk + A.T @ Hk @ W @ A
        Hk = 0.5 * (Hk + Hk.T)
        G = 0.5 * (G + G.T)


def _apply(step: tuple[np.ndarray, np.ndarray, np.ndarray], P: np.ndarray) -> np.ndarray:
    A, G, Hk = step
    out = Hk + A.T @ P @ np.linalg.solve(np.eye(P.shape[0]) + G @ P, A)
    return 0.5 * (out + out.T)


def _settle_by_doubling(Phi: np.ndarray, Q: np.ndarray, H: np.ndarray, R: np.ndarray, P: np.ndarray,
                        history: list[np.ndarray], tolerance: float) -> tuple[np.ndarray, int]:
    """(P_inf, the last step outside ``tolerance`` of it) for a recursion that is at P after
    ``len(history)`` steps (their variances) and has not settled: P_inf from the doubling, then a
    binary descent over the 2^i-step maps for the first step within tolerance (the variances approach P_inf
    monotonically once the slow mode dominates). A variance whose steady state is 0 (a state no
    noise reaches) counts as settled below the smallest normal double."""
    maps = []
    P_inf: np.ndarray | None = None
    prev: np.ndarray | None
    for step in _riccati_doubling(Phi, Q, H, R):
        maps.append(step)
        prev, P_inf = P_inf, step[2]
        if prev is not None and np.allclose(np.diag(P_inf), np.diag(prev), rtol=1e-13, atol=0.0):
            break
    assert P_inf is not None
    target = np.diag(P_inf)
    floor = np.maximum(tolerance * np.abs(target), np.finfo(float).tiny)

    def inside(X: np.ndarray) -> bool:
        return bool(np.all(np.abs(np.diag(X) - target) <= floor))

    if inside(P):  # within tolerance already: the last step outside is in the history
        far = [k for k, d in enumerate(history) if np.any(np.abs(d - target) > floor)]
        return P_inf, far[-1] + 1 if far else 0
    # extend the maps until the longest one brings P within tolerance
    while not inside(_apply(maps[-1], P)) and len(maps) < _MAX_DOUBLINGS:
        A, G, Hk = maps[-1]
        W = np.linalg.inv(np.eye(P.shape[0]) + G @ Hk)
        maps.append((A @ W @ A, G + A @ W @ G @ A.T, Hk + A.T @ Hk @ W @ A))
    taken = 0
    X = P
    for i in range(len(maps) - 1, -1, -1):
        Y = _apply(maps[i], X)
        if not inside(Y):
            X, taken = Y, taken + 2 ** i
    # P after len(history) + taken steps is the last outside; the next one is inside
    return P_inf, len(history) + taken


# --------------------------------------------------------------------------------------------
# Assembly
# --------------------------------------------------------------------------------------------

def build_filter_model(vehicle: Vehicle, config: DesignConfig, *, require_observable: bool = True
                       ) -> FilterModel:
    """Assemble Phi, Delta, Gamma, Q, H, R and the channels; raise ConfigError on any problem."""
    from rovlab.models.discretise import discretise

    file = config.file or config.name
    params = HeaveYawParams.from_values(**config.model_values(vehicle))
    if not (params.M_w > 0 and params.M_r > 0):
        raise ConfigError([Problem(file, "model", {"M_w": params.M_w, "M_r": params.M_r},
                                   "positive total masses m - Z_wdot and I_zz - N_rdot")], "filter configuration")
    T_w, T_r = config.bias_time_constants(params.M_w, params.M_r)
    A, B, E = observer_model(params, T_w, T_r)
    W = config.W
    with np.errstate(all="ignore"):  # overflow is reported below, naming the file's values
        disc = discretise(A, B, E, W, config.sample_time)
    if not all(np.all(np.isfinite(M)) for M in (disc.Phi, disc.Delta, disc.Q)):
        values = (f"h = {config.sample_time:g} s, psd = [" + ", ".join(f"{w:g}" for w in config.psd[2:])
                  + f"], T = [{T_w:g}, {T_r:g}] s")
        raise ConfigError([Problem(file, "sample_time, process_noise", values,
            "values whose discretisation is finite (Phi, Delta and Van Loan's Q overflow: "
            "check the sample time, the spectral densities and the bias time constants)")],
            "filter configuration")

    channels, problems = make_channels(vehicle, config, _STATE_OF_QUANTITY, estimator="kf")
    if problems:
        raise ConfigError(problems, "filter configuration")

    H = np.zeros((len(channels), len(STATES)))
    for j, c in enumerate(channels):
        H[j, c.state_index] = 1.0
    R = np.diag([c.variance for c in channels])
    observable, touched, V = observability(A, H)
    if not observable and require_observable:
        raise ConfigError([unobservable_problem(file, channels, touched, V)], "filter configuration")
    # The gate is only valid once the filter has converged: a shorter start-up phase than the
    # design needs lets it discard healthy sensors while the filter is the one that is wrong (with
    # the thesis's P0 = 0 and startup_s = 0 the closed loop lost both depth sensors and diverged).
    auto = startup_time(disc.Phi, disc.Q, H, R, config.P0, config.sample_time) if observable else 0.0
    for c, mc in zip(channels, config.measurements):
        if not math.isnan(c.startup_s) and c.startup_s < auto and np.isfinite(c.gate_threshold):
            problems.append(Problem(file, f"fusion.startup_s ({mc.key})", c.startup_s,
                                    f"at least {auto:.3g} s for {c.name}: the start-up phase this design needs "
                                    "before its innovation gate is valid (P converged from P0 plus 5 time constants "
                                    "of the error dynamics); leave it out to use that value"))
    if problems:
        raise ConfigError(problems, "filter configuration")
    channels = [replace(c, startup_s=auto) if math.isnan(c.startup_s) else c for c in channels]
    return FilterModel(
        h=config.sample_time, params=params, T_w=T_w, T_r=T_r, A=A, B=B, E=E, W=W, Phi=disc.Phi,
        Delta=disc.Delta, Gamma=disc.Gamma, Q=disc.Q, channels=tuple(channels), H=H, R=R,
        x0=np.array(config.initial_state), P0=config.P0, observable=observable, unobservable=touched,
        unobservable_directions=V, input_uncertainty=np.full(len(INPUTS), float(config.thrust_uncertainty)),
    )



def make_channels(vehicle: Vehicle, config: DesignConfig, state_of: dict[str, int], *, estimator: str
                  ) -> tuple[list[Channel], list[Problem]]:
    """The configuration's measurements as channels of a filter whose state index of each
    measurable quantity is ``state_of`` (every problem collected, none raised). Shared by the
    depth-and-heading filter and the 4-DOF EKF: the same sensor-management settings, lever arms
    and variances."""

    file = config.file or config.name
    channels: list[Channel] = []
    problems: list[Problem] = []
    for mc in config.measurements:
        sensor = mc.resolve(vehicle, file)
        if mc.quantity not in SENSOR_CHANNELS.get(sensor.kind, ()):
            problems.append(Problem(file, f"{mc.key}.quantity", mc.quantity,
                                    f"a channel of sensor {sensor.name!r} (kind {sensor.kind}): "
                                    + ", ".join(c for c in SENSOR_CHANNELS[sensor.kind] if c in state_of)))
            continue
        if mc.quantity not in state_of:
            problems.append(Problem(file, f"{mc.key}.quantity", mc.quantity,
                                    f"{', '.join(state_of)}: the filter of estimator = \"{estimator}\" has no "
                                    f"state {mc.quantity}" + ("; the 4-DOF filter (estimator = \"ekf\") fuses it"
                                                              if estimator == "kf" else "")))
            continue
        variance = mc.variance if mc.variance is not None else sensor.variance.get(mc.quantity)
        if variance is None:
            problems.append(Problem(file, f"{mc.key}.variance", "missing",
                                    f"a variance: vehicle {vehicle.name!r} gives none for "
                                    f"{sensor.name}.{mc.quantity}"))
            continue
        name = f"{sensor.name}.{mc.quantity}"
        if any(c.name == name for c in channels):
            problems.append(Problem(file, mc.key, name, "each sensor quantity at most once"))
            continue
        f = mc.fusion
        timeout = f.timeout_s if f.timeout_s is not None else _TIMEOUT_PERIODS / sensor.rate_hz
        rate = min(sensor.rate_hz, 1.0 / config.sample_time)  # samples the filter can see per second
        n_ramp = max(1, int(round(f.recovery_time_s * rate))) if f.recovery_time_s > 0 else 0
        n_stuck = int(round(f.stuck_window_s * rate)) if f.stuck_window_s > 0 else 0
        if 0 < n_stuck < _MIN_STUCK_SAMPLES:
            problems.append(Problem(file, f"{mc.key}.stuck_window_s", f.stuck_window_s,
                                    f"a window of at least {_MIN_STUCK_SAMPLES} samples of {sensor.name} "
                                    f"({_MIN_STUCK_SAMPLES / rate:g} s at {rate:g} Hz), or 0 to switch the check off"))
            continue
        # Lever arm (Sandøy 2016, sec. 5.1): p_VO = p_m - R(Theta) l; with phi = theta = 0 the depth
        # moves by l_z only, and w, r and psi need no correction.
        offset = float(sensor.position[2]) if mc.quantity == "z" else 0.0
        channels.append(Channel(
            name=name, column=f"{mc.quantity}_{sensor.name}", sensor=sensor.name, kind=sensor.kind,
            quantity=mc.quantity, state_index=state_of[mc.quantity], offset=offset,
            variance=float(variance), timeout_s=float(timeout), gate_probability=f.gate_probability,
            gate_threshold=_chi2_ppf(f.gate_probability, 1) if f.gate_probability < 1.0 else np.inf,
            lose_after=f.gate_failures_to_lose, recovery_time_s=f.recovery_time_s, recovery_samples=n_ramp,
            reacquire_after_s=f.reacquire_after_s, startup_s=math.nan if f.startup_s is None else f.startup_s,
            stuck_samples=n_stuck, stuck_bound=_stuck_bound(sensor, mc.quantity, float(variance), n_stuck),
            maneuver_acceleration=f.maneuver_acceleration,
        ))
    return channels, problems

def _stuck_bound(sensor: Any, quantity: str, variance: float, n: int) -> float:
    """The stuck check's bound (rovlab.estimation.fusion): the chi-square scatter bound of a raw
    sensor's white noise, or 0 (the repetition check) for an autopilot's estimate and for a sensor
    quantised coarser than its noise (step q: q^2/12 > R/4, where a still vehicle repeats values)."""
    if not n:
        return 0.0
    q = float(getattr(sensor, "resolution", {}).get(quantity, 0.0))
    if getattr(sensor, "reports", "measurement") == "estimate" or q * q / 12.0 > variance / 4.0:
        return 0.0
    from rovlab.estimation.layout import STUCK_FALSE_ALARM

    return _chi2_ppf(STUCK_FALSE_ALARM, n - 1)


def unobservable_problem(file: str, channels, touched: tuple[str, ...], V: np.ndarray,
                         states: tuple[str, ...] = STATES) -> Problem:
    names = ", ".join(c.name for c in channels) or "no measurements"
    directions = "; ".join(describe_direction(V[:, k], states) for k in range(V.shape[1]))
    missing = [s for s in ("z", "psi") if s in touched]
    hint = (" Add a measurement of " + " and ".join(missing) + "." if missing
            else " Add a measurement that sees these states.")
    return Problem(file, "measurements", names,
                   f"a sensor set that observes the whole state; these cannot be estimated: "
                   f"{', '.join(touched)} (unobservable directions: {directions}).{hint}")
