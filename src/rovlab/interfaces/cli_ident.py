"""Sub-commands ``identify``, ``added-mass`` and ``lab`` (Sandøy 2016, sec. 2.3 and ch. 4; docs/identification.md).

Interfaces hold no maths: these read files, call :mod:`rovlab.ident`, print the result (a table,
or JSON with ``--json``), draw the fit's PNG and, with ``--update``, write the estimates into a
vehicle file through :mod:`rovlab.params.edit` (validated before anything is written).

Plots: by default each ``identify`` writes ``<input stem>-<tool>.png`` into the working directory
(never next to the input, which may be packaged data inside the installed package; ``--plot PNG``
to choose, ``--no-plot`` to skip); ``added-mass`` plots only with ``--plot``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

SIGN_NOTE = ("Coefficients use SNAME signs: added mass and damping derivatives are negative "
             "(X_udot = -5.5 means 5.5 kg of added mass).")


def _number(kind: str) -> Callable[[str], float]:
    """An argparse type: a finite number, optionally positive or non-negative (bad values exit 2
    with 'argument --OPTION: expected ...')."""
    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(x):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if kind == "positive" and not x > 0:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
        if kind == "non-negative" and not x >= 0:
            raise argparse.ArgumentTypeError(f"expected a non-negative number, got {text!r}")
        return x

    parse.__name__ = f"{kind} number"
    return parse


def _seed(text: str) -> int:
    try:
        seed = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if seed < 0:
        raise argparse.ArgumentTypeError(f"expected a seed of 0 or more, got {text!r}")
    return seed


_finite = _number("finite")
_positive = _number("positive")
_nonnegative = _number("non-negative")


def register(sub: argparse._SubParsersAction) -> None:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--json", action="store_true", help="machine-readable output on stdout")
    common.add_argument("--plot", metavar="PNG", help="write the fit's figure here (default: <input stem>-<tool>.png "
                        "in the working directory)")
    common.add_argument("--no-plot", action="store_true", help="do not write a figure")
    common.add_argument("--update", metavar="VEHICLE.toml",
                        help="write the estimates into this vehicle file (comments kept, source note added, "
                             "validated before writing)")

    ident = sub.add_parser("identify", help="identify vehicle parameters from lab data (Sandøy 2016, sec. 2.3 and ch. 4)",
                           description="Identify vehicle parameters from the logs of the lab experiments. " + SIGN_NOTE)
    isub = ident.add_subparsers(dest="ident_command", metavar="EXPERIMENT")
    isub.required = True

    p = isub.add_parser("thrust", parents=[common], help="thrust curve from a load-cell staircase or a static table",
                        description="Fit f = K_L s + K_NL s|s| (s = u -/+ dead band, u = pwm - neutral) forward and "
                                    "reverse. Log columns: time_s, pwm_us (staircase set-point), force_n (thrust, "
                                    "positive forward). With --table: pwm_us, force_n (or force_kgf), or the "
                                    "maker's T200 CSV (force in kgf).")
    p.add_argument("file")
    p.add_argument("--table", action="store_true", help="FILE is a static table, not a time series")
    p.add_argument("--pair", type=int, default=1, metavar="N",
                   help="N identical thrusters were on the rig together: divide the force by N")
    p.add_argument("--window", type=_positive, default=5.0, metavar="S", help="average the last S seconds of each step (5)")
    p.add_argument("--cutoff", type=_positive, default=1.0, metavar="HZ", help="Butterworth cut-off frequency (1 Hz)")
    dead = p.add_mutually_exclusive_group()
    dead.add_argument("--deadband", type=_nonnegative, default=25.0, metavar="US", help="fixed dead band (25 us)")
    dead.add_argument("--fit-deadband", action="store_true", help="fit the dead band too")
    p.add_argument("--neutral", type=_positive, default=1500.0, metavar="US", help="neutral PWM (1500 us)")
    p.add_argument("--range", type=_finite, nargs=2, metavar=("LO", "HI"), help="use only points with LO <= pwm <= HI")
    p.add_argument("--max-force", type=_positive, metavar="N", help="drop points with |thrust| above N newtons")
    p.add_argument("--thruster", metavar="NAME[,NAME]", help="thruster(s) to update (required with --update)")
    p.set_defaults(func=_cmd_thrust)

    p = isub.add_parser("towing", parents=[common], help="surge/sway/heave damping from towing-carriage runs",
                        description="Columns: run, time_s, speed_mps, force_n (force the rig applies to the vehicle "
                                    "along the DOF's positive axis). " + SIGN_NOTE)
    p.add_argument("file")
    p.add_argument("--rig", metavar="FILE", help="rig-only runs (same columns) whose drag is subtracted")
    p.add_argument("--terms", default="linear,quadratic,cubic", help="terms to fit (default linear,quadratic,cubic)")
    p.add_argument("--dof", choices=("surge", "sway", "heave"),
                   help="DOF towed; required unless the log says it: a speed column u_mps (surge), v_mps (sway) "
                        "or w_mps (heave) instead of speed_mps, or the virtual lab's '# setting.dof' line")
    p.add_argument("--min-steady", type=_positive, default=2.0, metavar="S", help="shortest usable steady window (2 s)")
    p.add_argument("--trim", type=_nonnegative, default=1.0, metavar="S", help="seconds cut from each end of a window (1)")
    p.add_argument("--no-tare", action="store_true", help="do not subtract the force at rest around each run")
    p.set_defaults(func=_cmd_towing)

    p = isub.add_parser("yaw", parents=[common], help="yaw damping from constant-moment runs",
                        description="Columns: run, time_s, moment_nm, heading_rad (wrapped or not). " + SIGN_NOTE)
    p.add_argument("file")
    p.add_argument("--terms", default="linear,quadratic", help="terms to fit (default linear,quadratic)")
    p.add_argument("--min-steady", type=_positive, default=2.0, metavar="S", help="shortest usable steady window (2 s)")
    p.set_defaults(func=_cmd_yaw)

    p = isub.add_parser("step", parents=[common], help="added mass and linear damping from a step/relay response",
                        description="Output-error fit of u(s)/tau(s) = k/(s + a). Columns: time_s, force_n, "
                                    "position_m (or time_s, moment_nm, heading_rad for yaw). Reports gain k, pole a, "
                                    "added_mass = m - 1/k and linear_damping = -a/k, both SNAME-signed (negative).")
    p.add_argument("file")
    p.add_argument("--mass", type=_positive, metavar="KG",
                   help="rigid-body mass m (I_zz in kg m^2 for yaw); default: the --vehicle's")
    p.add_argument("--vehicle", metavar="NAME|FILE",
                   help="hold this vehicle's quadratic and cubic damping of the DOF fixed in the fit (the added "
                        "mass is then not biased by the nonlinear damping)")
    p.add_argument("--dof", choices=("surge", "sway", "heave", "yaw"),
                   help="DOF (for --update); default: yaw for a moment_nm/heading_rad log, surge otherwise")
    p.add_argument("--fit-bias", action="store_true",
                   help="fit a constant unlogged force (net buoyancy in heave, tether pull)")
    p.add_argument("--added-mass-only", action="store_true",
                   help="with --update, write only the added mass (keep the file's damping, e.g. from towing)")
    p.set_defaults(func=_cmd_step)

    p = isub.add_parser("noise", parents=[common], help="sensor variances (filter R) from a resting log",
                        description="Columns: time_s and one per channel. For --update, name channel columns "
                                    "<sensor>.<channel> (pressure.z) or <channel>_<sensor> (z_pressure), with the "
                                    "sensor names of the vehicle file's [[sensors]].")
    p.add_argument("file")
    p.add_argument("--detrend", type=int, default=1, choices=(0, 1, 2, 3),
                   help="degree of the drift polynomial removed (1: linear)")
    p.add_argument("--allan", action="store_true", help="also compute the Allan deviation")
    p.add_argument("--no-stationarity-check", action="store_true",
                   help="accept channels that do not look like noise at rest (steps, a staircase, wandering)")
    p.set_defaults(func=_cmd_noise)

    p = isub.add_parser("dive", help="heave and yaw (and surge and sway with a DVL or a position) added mass, "
                                     "damping and net buoyancy from a dive log (issue 29)",
                        description="Output-error identification of heave and yaw from the vehicle's own log: the "
                                    "commanded PWM through the vehicle's thrust curves as input, depth, heading and yaw "
                                    "rate as outputs; surge and sway too where the log carries a DVL's u, v or a "
                                    "position's x, y (the vehicle file's dvl or motion_capture sensor; "
                                    "LOCAL_POSITION_NED in a MAVLink log). LOG: a CSV (time_s, pwm_<thruster> or tau_Z/tau_N, "
                                    "<channel>_<sensor> columns, as rovlab lab dive and rovlab mavlink convert write "
                                    "them), a .tlog, a .BIN or a recorded .mcap. Reports each parameter's estimate, "
                                    "standard deviation and correlations, refuses what the log does not determine, and "
                                    "scores 1-, 10- and 100-step predictions on the last part of the log. " + SIGN_NOTE)
    p.add_argument("file", metavar="LOG")
    p.add_argument("--vehicle", required=True, metavar="NAME|FILE",
                   help="the vehicle file to start from (thrust curves, sensors, rigid-body mass and inertia)")
    p.add_argument("--dofs", help="DOFs to identify, from heave, yaw, surge, sway (default heave,yaw, and surge,sway "
                                   "when the log carries position or velocity: a DVL's u, v or a position's x, y)")
    p.add_argument("--free", default="added_mass,linear,quadratic,net_buoyancy",
                   help="parameters to estimate per DOF, from added_mass, linear, quadratic, net_buoyancy, "
                        "thrust_scale (default added_mass,linear,quadratic,net_buoyancy; added_mass and thrust_scale "
                        "exclude each other: no dive tells them apart)")
    p.add_argument("--split", type=_positive, default=0.7, metavar="SHARE",
                   help="share of the log used to identify; the rest validates (0.7)")
    p.add_argument("--compare", metavar="NAME|FILE|none",
                   help="a published parameter set whose predictions are scored too: a packaged set (wu2018) or a "
                        "TOML file of sets (FILE:NAME picks one); default: the packaged set listed for the vehicle "
                        "(bluerov2_heavy: wu2018), none for other vehicles")
    p.add_argument("--json", action="store_true", help="machine-readable output on stdout")
    p.add_argument("--plot", metavar="PNG", help="write the validation figure here (default: <log stem>-dive.png in the "
                   "working directory)")
    p.add_argument("--no-plot", action="store_true", help="do not write a figure")
    p.add_argument("--update", metavar="VEHICLE.toml",
                   help="write the estimates into this vehicle file (comments kept, source notes with the log, time "
                        "span, method and standard deviations; validated before writing)")
    p.set_defaults(func=_cmd_dive)

    am = sub.add_parser("added-mass", help="added mass from box geometry (DNV-RP-H103, Sandøy 2016, sec. 4.2.1)",
                        description="Eidsvik's empirical method on DNV-RP-H103 tables. Give the six dimensions "
                                    "or --vehicle to use its [geometry]. " + SIGN_NOTE)
    for name, unit in (("length", "M"), ("width", "M"), ("height", "M"), ("area-front", "M2"), ("area-side", "M2"),
                       ("area-top", "M2")):
        am.add_argument(f"--{name}", type=_positive, metavar=unit)
    am.add_argument("--rho", type=_positive, metavar="KG/M3", help="water density (1000, or the vehicle's)")
    am.add_argument("--vehicle", metavar="NAME|FILE", help="take the geometry from this vehicle")
    am.add_argument("--json", action="store_true", help="machine-readable output on stdout")
    am.add_argument("--plot", metavar="PNG", help="write the DNV tables with the points used")
    am.add_argument("--update", metavar="VEHICLE.toml", help="write [added_mass] into this vehicle file")
    am.set_defaults(func=_cmd_added_mass)

    lab = sub.add_parser("lab", help="virtual lab: generate realistic experiment data from a vehicle file",
                         description="Generate the data of a lab experiment from a vehicle whose true parameters are "
                                     "known (seeded; the seed, settings and truth go into '#' comment lines).")
    lsub = lab.add_subparsers(dest="lab_command", metavar="EXPERIMENT")
    lsub.required = True
    lcommon = argparse.ArgumentParser(add_help=False)
    lcommon.add_argument("--vehicle", default="udrone", metavar="NAME|FILE", help="packaged name or TOML file (udrone)")
    lcommon.add_argument("--seed", type=_seed, help="random seed, 0 or more (default: a fresh one, printed)")
    lcommon.add_argument("--out", required=True, metavar="FILE", help="CSV file to write")
    lcommon.add_argument("--json", action="store_true", help="print what was written as JSON")

    p = lsub.add_parser("thrust", parents=[lcommon], help="load-cell PWM staircase")
    p.add_argument("--thruster", metavar="NAME[,NAME]", help="thruster(s) on the rig (default: the first)")
    p.add_argument("--pwm-start", type=_positive, default=1300.0)
    p.add_argument("--pwm-stop", type=_positive, default=1700.0)
    p.add_argument("--pwm-step", type=_positive, default=10.0)
    p.add_argument("--step-s", type=_positive, default=30.0, help="seconds per step (30)")
    p.add_argument("--rate-hz", type=_positive, default=50.0)
    p.add_argument("--noise-n", type=_nonnegative, default=0.3, help="load-cell white noise std [N]")
    p.set_defaults(func=_cmd_lab_thrust)

    p = lsub.add_parser("towing", parents=[lcommon], help="towing-carriage runs and rig-only runs")
    p.add_argument("--dof", choices=("surge", "sway", "heave"), default="surge")
    p.add_argument("--speeds", help="comma-separated speeds [m/s] (default +-0.1..0.5)")
    p.add_argument("--hold-s", type=_positive, default=15.0, help="seconds at constant speed (15)")
    p.add_argument("--noise-n", type=_nonnegative, default=0.15, help="load-cell white noise std [N]")
    p.add_argument("--rig-out", metavar="FILE", help="rig-only runs (default: <out stem>-rig.csv)")
    p.set_defaults(func=_cmd_lab_towing)

    p = lsub.add_parser("yaw", parents=[lcommon], help="constant-moment yaw runs")
    p.add_argument("--moments", help="comma-separated moments [N m] (default 0.25,0.5,0.75,1,2)")
    p.add_argument("--duration-s", type=_positive, default=30.0)
    p.add_argument("--moment-error", type=_nonnegative, default=0.0,
                   help="relative std of the applied moment per run (allocation error; 0)")
    p.set_defaults(func=_cmd_lab_yaw)

    p = lsub.add_parser("step", parents=[lcommon], help="relay test observed by motion capture")
    p.add_argument("--dof", choices=("surge", "sway", "heave", "yaw"), default="surge")
    p.add_argument("--force", type=_positive, default=2.0, help="relay force [N] (moment [N m] for yaw)")
    p.add_argument("--amplitude", type=_positive, default=0.3, help="switching position [m] (rad for yaw)")
    p.add_argument("--duration-s", type=_positive, default=60.0)
    p.add_argument("--linear", action="store_true", help="linear damping only in the truth")
    p.add_argument("--buoyancy-error", type=_finite, default=1.0, metavar="N",
                   help="heave: how much more buoyant than the file the vehicle is (1 N)")
    p.set_defaults(func=_cmd_lab_step)

    p = lsub.add_parser("noise", parents=[lcommon], help="resting sensor log")
    p.add_argument("--samples", type=int, default=6796, help="samples (6796 as in the thesis)")
    p.add_argument("--rate-hz", type=_positive)
    p.set_defaults(func=_cmd_lab_noise)

    p = lsub.add_parser("plan-dive", help="an excitation manoeuvre for identify dive, with the expected standard "
                                          "deviations (issue 29)",
                        description="Plan a random multi-level heave force and yaw moment within the thrust limits and "
                                    "a depth band, with rests, and print how well each parameter will be determined "
                                    "(Cramér-Rao standard deviations from the Fisher information at the vehicle file's "
                                    "values, with its sensors' noise) before anything is flown.")
    p.add_argument("--vehicle", default="bluerov2_heavy", metavar="NAME|FILE",
                   help="packaged name or TOML file (bluerov2_heavy)")
    p.add_argument("--dofs", default="heave,yaw", help="DOFs to excite, from heave, yaw, surge, sway (default heave,yaw; "
                                                       "surge and sway need a DVL or a position sensor in the vehicle "
                                                       "file)")
    p.add_argument("--duration", type=_positive, default=300.0, metavar="S", help="length of the manoeuvre (300 s)")
    p.add_argument("--depth-min", type=_positive, default=1.0, metavar="M", help="top of the depth band (1 m)")
    p.add_argument("--depth-max", type=_positive, default=3.0, metavar="M", help="bottom of the depth band (3 m)")
    p.add_argument("--heave-speed", type=_positive, default=0.4, metavar="M/S",
                   help="heave speed the largest level reaches (0.4 m/s)")
    p.add_argument("--yaw-rate", type=_positive, default=60.0, metavar="DEG/S",
                   help="yaw rate the largest level reaches (60 deg/s)")
    p.add_argument("--surge-speed", type=_positive, default=0.4, metavar="M/S",
                   help="surge speed the largest level reaches (0.4 m/s)")
    p.add_argument("--sway-speed", type=_positive, default=0.3, metavar="M/S",
                   help="sway speed the largest level reaches (0.3 m/s)")
    p.add_argument("--box-m", type=_positive, default=10.0, metavar="M",
                   help="surge/sway: side of the square about the start the vehicle is kept in (10 m)")
    p.add_argument("--seed", type=_seed, default=0, help="random seed of the sequence (0)")
    p.add_argument("--out", required=True, metavar="PLAN.toml", help="plan file to write")
    p.add_argument("--json", action="store_true", help="print the plan's summary and expected sigmas as JSON")
    p.set_defaults(func=_cmd_lab_plan_dive)

    p = lsub.add_parser("dive", parents=[lcommon], help="fly a dive plan on a hidden vehicle (issue 29)",
                        description="Fly a plan (rovlab lab plan-dive) on a hidden 'true' vehicle with the process "
                                    "model, the thrusters (PWM quantised to 1 us, dead band) and a BlueROV2's sensors "
                                    "(depth at 2 Hz, smoothed AHRS heading and yaw rate at 20 Hz; a DVL or positioning "
                                    "system at its file's rate and variance); the log is what "
                                    "rovlab identify dive reads. The truth goes into the file's JSON sidecar.")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--plan", metavar="PLAN.toml", help="the plan to fly (rovlab lab plan-dive)")
    what.add_argument("--pilot", action="store_true",
                      help="no plan: a pilot flies the dive by joystick in ArduSub's MANUAL mode (descents, holds by "
                           "eye, turns, forward runs, pauses; rovlab.ident.pilot), drawn from --seed")
    p.add_argument("--duration", type=_positive, default=300.0, metavar="S", help="--pilot: length of the dive (300 s)")
    p.add_argument("--truth-vehicle", metavar="NAME|FILE",
                   help="the true vehicle (default: --vehicle with its heave and yaw added mass and damping changed by "
                        "up to --spread and its net buoyancy by up to 2 N, drawn from --seed)")
    p.add_argument("--spread", type=_nonnegative, default=0.25, help="relative spread of the hidden vehicle (0.25)")
    p.add_argument("--depth-rate", type=_positive, default=2.0, metavar="HZ", help="pressure samples per second (2)")
    p.set_defaults(func=_cmd_lab_dive)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------

def _user_error(msg: str) -> Exception:
    from rovlab.interfaces.cli import UserError

    return UserError(msg)


def _run(file: str, fn: Callable[[], Any]) -> Any:
    """Call an identification, turning its IdentificationError into a clean user error."""
    import numpy as np

    from rovlab.ident.fitting import IdentificationError

    try:
        # The readers refuse implausible magnitudes; should a fit still overflow or divide by
        # zero, stop with a message instead of a traceback or NaN estimates (and keep LAPACK from
        # printing its own complaints about non-finite input).
        with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
            return fn()
    except IdentificationError as exc:
        text = str(exc)  # messages about a run already start with the file's name
        raise _user_error(text if text.startswith(f"{file}:") else f"{file}: {text}") from None
    except (FloatingPointError, ZeroDivisionError, OverflowError, np.linalg.LinAlgError) as exc:
        raise _user_error(f"{file}: the data cannot be fitted ({type(exc).__name__}: {exc}); expected a log of "
                          "the experiment in SI units (check the columns' units and scaling)") from None


def _clean(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if hasattr(x, "tolist"):
        return _clean(x.tolist())
    return x


def _emit(args: argparse.Namespace, data: dict[str, Any], text: str) -> None:
    if args.json:
        json.dump(_clean(data), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(text)


def _plot(args: argparse.Namespace, tool: str, draw: Callable[[Path], Any]) -> str | None:
    """Write the figure (default: ``<input stem>-<tool>.png`` in the working directory); a missing
    matplotlib only warns."""
    from rovlab.ident import plots
    from rovlab.ident.plots import PlotUnavailable

    if getattr(args, "no_plot", False):
        return None
    if args.plot:
        path = Path(args.plot)
    elif getattr(args, "file", None):
        path = Path(f"{Path(args.file).stem}-{tool}.png")
    else:
        return None
    if path.suffix.lower() not in plots.FORMATS:
        raise _user_error(f"--plot {path}: a figure file must end in {', '.join(plots.FORMATS)}")
    if path.is_dir():
        raise _user_error(f"--plot {path}: is a directory; give a file name such as {path / (tool + '.png')}")
    try:
        draw(path)
    except PlotUnavailable as exc:
        print(f"rovlab: note: no figure written: {exc}", file=sys.stderr)
        return None
    except OSError as exc:
        raise _user_error(f"cannot write the figure {path}: {exc.strerror or exc}") from None
    return str(path)


def _check_update_target(path: str) -> Path:
    from rovlab.params.vehicle import packaged_vehicle_names, packaged_vehicle_path

    p = Path(path)
    if not p.exists():
        if path in packaged_vehicle_names():
            raise _user_error(f"--update needs a vehicle file, not the packaged name {path!r}; copy it first: "
                              f"cp {packaged_vehicle_path(path)} my_{path}.toml")
        raise _user_error(f"--update: no such file {path}")
    pkg = packaged_vehicle_path("x").parent.resolve()
    if p.resolve().parent == pkg:
        raise _user_error(f"--update: {path} is a packaged vehicle file; copy it and update the copy")
    if not p.is_file():
        raise _user_error(f"--update: {path} is not a file; expected a vehicle TOML file")
    if not os.access(p, os.W_OK):
        raise _user_error(f"--update: {path} is read-only; expected a vehicle file you may write (nothing was written)")
    return p


def _update(args: argparse.Namespace, edits: dict[str, Any], blocks: list[str], what: str) -> str | None:
    if not args.update:
        return None
    from rovlab.params.edit import edit_vehicle_file

    target = _check_update_target(args.update)
    note = f"{what} ({_dt.date.today().isoformat()})"
    try:
        edit_vehicle_file(target, edits, sources={b: note for b in blocks})
    except OSError as exc:  # a read-only folder, a full disk: the file is left as it was
        raise _user_error(f"--update: cannot write {target}: {exc.strerror or exc}; the file is unchanged "
                          "(nothing was written)") from None
    print(f"updated {target}: " + ", ".join(k for k, v in edits.items() if not _is_delete(v))
          + f"; source note: {note}", file=sys.stderr)
    return str(target)


def _is_delete(v: Any) -> bool:
    from rovlab.params.edit import DELETE

    return v is DELETE


def _pm(x: float, se: float) -> str:
    if se is None or not math.isfinite(se) or se == 0:
        return f"{x:.5g}"
    return f"{x:.5g} ± {se:.2g}"


def _terms(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def _floats(text: str | None, what: str) -> list[float] | None:
    if text is None:
        return None
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise _user_error(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise _user_error(f"{what}: expected comma-separated finite numbers, got {text!r}")
    return values


# --------------------------------------------------------------------------------------------
# identify
# --------------------------------------------------------------------------------------------

def _cmd_thrust(args: argparse.Namespace) -> int:
    from rovlab.ident import plots, thrust

    if args.update and not args.thruster:
        raise _user_error("--update needs --thruster NAME (or NAME,NAME for a pair) to say which [[thrusters]] entry")
    if args.pair < 1:
        raise _user_error(f"--pair must be at least 1, got {args.pair}")
    dead = None if args.fit_deadband else args.deadband
    rng = tuple(args.range) if args.range else None
    if args.table:
        pwm, force, fmt = thrust.read_thrust_table(args.file)
        fit = _run(args.file, lambda: thrust.fit_thrust_curve(
            pwm, force / args.pair, neutral_us=args.neutral, deadband_us=dead, pwm_range=rng,
            max_force_n=args.max_force, pair=args.pair))
        source = f"static table ({fmt})"
    else:
        from rovlab.params.validate import ConfigError

        try:
            log = thrust.read_thrust_log(args.file)
        except ConfigError as exc:
            try:  # a static table (e.g. the maker's CSV) given without --table: say so
                thrust.read_thrust_table(args.file)
            except ConfigError:
                raise exc from None
            raise _user_error(f"{exc}\n  {args.file} has PWM and force columns but no time: for a static table "
                              "add --table") from None
        fit = _run(args.file, lambda: thrust.fit_thrust_log(
            log["time_s"], log["pwm_us"], log["force_n"], pair=args.pair, window_s=args.window, cutoff_hz=args.cutoff,
            neutral_us=args.neutral, deadband_us=dead, pwm_range=rng, max_force_n=args.max_force))
        source = f"load-cell staircase, {fit.pwm_us.size} steps"
    png = _plot(args, "thrust", lambda p: plots.plot_thrust(fit, p, title=f"Thrust: {Path(args.file).name}"))
    updated = None
    if args.update:
        names = [n.strip() for n in args.thruster.split(",") if n.strip()]
        updated = _update(args, thrust.thrust_edits(fit, names), [f"thrusters[name={n}]" for n in names],
                          f"curve: rovlab identify thrust {Path(args.file).name}"
                          + (f" --pair {args.pair}" if args.pair > 1 else ""))
    data = fit.as_dict() | {"file": args.file, "source": source, "plot": png, "updated": updated}
    se = fit.stderr
    skipped = fit.steps.skipped_us if fit.steps is not None else ()
    text = "\n".join([
        f"thrust curve from {args.file} ({source}" + (f", force / {args.pair}" if args.pair > 1 else "") + ")",
        f"  forward  K_L_pos  = {_pm(fit.K_L_pos, se['K_L_pos'])} N/us    K_NL_pos = {_pm(fit.K_NL_pos, se['K_NL_pos'])} N/us^2",
        f"  reverse  K_L_neg  = {_pm(fit.K_L_neg, se['K_L_neg'])} N/us    K_NL_neg = {_pm(fit.K_NL_neg, se['K_NL_neg'])} N/us^2",
        f"  dead band {_pm(fit.deadband_us, se['deadband_us'])} us ({'fitted' if fit.deadband_fitted else 'fixed'}), "
        f"neutral {fit.neutral_us:g} us",
        f"  RMS residual {fit.rms_n:.4g} N over {fit.pwm_us.size} points ({fit.n_pos} forward, {fit.n_neg} reverse)",
    ] + ([f"  skipped {len(skipped)} step(s) shorter than the {args.window:g} s window"] if skipped else [])
      + ([f"  figure: {png}"] if png else []))
    _emit(args, data, text)
    return 0


def _damping_text(fit, file: str, label: str) -> str:
    lines = [f"{label} from {file}: {len(fit.points)} runs" + (f", {len(fit.rig_points)} rig-only runs subtracted"
                                                               if fit.rig_points else "")]
    unit = "N m s/rad" if fit.dof == "yaw" else "N s/m"
    units = {"linear": unit, "quadratic": unit.replace(" s", " s^2").replace("/rad", "/rad^2").replace("/m", "/m^2"),
             "cubic": unit.replace(" s", " s^3").replace("/rad", "/rad^3").replace("/m", "/m^3")}
    for t in fit.terms:
        lines.append(f"  {t:9s} = {_pm(getattr(fit, t), fit.stderr[t])} {units[t]}")
    lines.append(f"  RMS residual {fit.rms:.4g} {fit.unit}")
    for t, (c, se) in fit.pinned.items():
        lines.append(f"  note: {t} came out {c:+.3g} ± {se:.2g}, not significantly positive: fixed at 0 (SNAME "
                     "damping is <= 0) and the other terms refitted")
    if fit.dof == "yaw":
        lines.append("  run   rate       moment      window      (rad/s, N m)")
    else:
        lines.append("  run   speed      force       window      (m/s, N)")
    for p in fit.points:
        lines.append(f"  {p.run:<4d} {p.speed:+.4f}  {p.force:+9.4f}   {p.start_s:7.2f}-{p.end_s:.2f} s")
    return "\n".join(lines)


def _cmd_towing(args: argparse.Namespace) -> int:
    from rovlab.ident import plots, towing

    table = towing.read_towing(args.file)
    rig = towing.read_towing(args.rig) if args.rig else None
    args.dof = _towing_dof(args, table)
    fit = _run(args.file, lambda: towing.identify_towing(table, rig, terms=_terms(args.terms), dof=args.dof,
                                                         min_s=args.min_steady, trim_s=args.trim,
                                                         tare=not args.no_tare))
    png = _plot(args, "towing", lambda p: plots.plot_damping(fit, p, title=f"{args.dof} damping: {Path(args.file).name}"))
    updated = _update(args, towing.damping_edits(fit, args.dof), ["damping"],
                      f"{args.dof}: rovlab identify towing {Path(args.file).name}"
                      + (f" --rig {Path(args.rig).name}" if args.rig else "") + f" (terms {','.join(fit.terms)})")
    data = fit.as_dict() | {"file": args.file, "rig_file": args.rig, "plot": png, "updated": updated}
    text = _damping_text(fit, args.file, f"{args.dof} damping (SNAME)") + (f"\n  figure: {png}" if png else "")
    _emit(args, data, text)
    return 0


def _towing_dof(args: argparse.Namespace, table) -> str:
    """The towed DOF: --dof, or what the log says. Never a silent default (a heave log used to be
    reported, and written with --update, as surge)."""
    from rovlab.ident import towing

    found = towing.dof_of_log(table)
    if args.dof is None:
        if found is None:
            raise _user_error(f"{args.file}: which DOF was towed? the log does not say (its speed column is "
                              "speed_mps, not u_mps, v_mps or w_mps, and it has no '# setting.dof' line); "
                              "expected --dof surge, --dof sway or --dof heave")
        return found
    if found is not None and found != args.dof:
        raise _user_error(f"{args.file}: --dof {args.dof}, but the log says it is a {found} towing log; expected "
                          f"--dof {found} (or no --dof)")
    return args.dof


def _cmd_yaw(args: argparse.Namespace) -> int:
    from rovlab.ident import plots, towing, yaw

    table = yaw.read_yaw(args.file)
    fit = _run(args.file, lambda: yaw.identify_yaw(table, terms=_terms(args.terms), min_s=args.min_steady))
    png = _plot(args, "yaw", lambda p: plots.plot_damping(fit, p, title=f"yaw damping: {Path(args.file).name}"))
    updated = _update(args, towing.damping_edits(fit, "yaw"), ["damping"],
                      f"yaw: rovlab identify yaw {Path(args.file).name} (terms {','.join(fit.terms)})")
    d = fit.as_dict()
    data = {"linear": d["linear"], "quadratic": d["quadratic"]} | d | {"file": args.file, "plot": png,
                                                                      "updated": updated}
    text = _damping_text(fit, args.file, "yaw damping (SNAME)") + (f"\n  figure: {png}" if png else "")
    _emit(args, data, text)
    return 0


def _cmd_step(args: argparse.Namespace) -> int:
    from rovlab.ident import plots, step

    table, t, f, x = step.read_step(args.file)
    # read_step took the yaw columns (moment_nm, heading_rad) or the translational ones (force_n,
    # position_m): the DOF must agree, or --update would write e.g. a surge test into N_rdot
    yaw = not table.has("position_m")
    if args.dof is None:
        args.dof = "yaw" if yaw else "surge"
    elif yaw != (args.dof == "yaw"):
        have = "time_s, moment_nm, heading_rad (a yaw log)" if yaw else "time_s, force_n, position_m (a surge, sway or heave log)"
        need = ("time_s, moment_nm, heading_rad" if args.dof == "yaw" else "time_s, force_n, position_m")
        raise _user_error(f"{args.file}: --dof {args.dof} needs the columns {need}, but the file has {have}; "
                          f"use --dof {'yaw' if yaw else 'surge, sway or heave'}")
    damping = None
    if args.vehicle is not None:
        from rovlab.params.vehicle import DOF4, load_vehicle

        known = load_vehicle(args.vehicle)
        i = DOF4.index(args.dof)
        damping = (float(known.damping_quadratic[i]), float(known.damping_cubic[i]))
        if args.mass is None:
            args.mass = float(known.I_zz if args.dof == "yaw" else known.mass)
    if args.mass is None:
        raise _user_error("identify step: give --mass (the rigid-body mass, I_zz for yaw) or --vehicle NAME|FILE "
                          "to take it from a vehicle file")
    fit = _run(args.file, lambda: step.fit_step_response(t, f, x, mass=args.mass, bias=args.fit_bias,
                                                         damping=damping))
    if fit.added_mass > 0:
        print(f"rovlab: note: the added mass comes out positive: --mass {args.mass:g} is more than the total "
              f"{'inertia' if yaw else 'mass'} 1/k = {1 / fit.gain:.4g} the test shows; --mass is the rigid-body "
              f"{'inertia I_zz [kg m^2]' if yaw else 'mass [kg]'} (a vehicle file refuses a positive added mass)",
              file=sys.stderr)
    png = _plot(args, "step", lambda p: plots.plot_step(
        fit, p, title=f"Relay/step response ({args.dof}): {Path(args.file).name}",
        position_unit="rad" if yaw else "m", force_unit="N m" if yaw else "N",
        position_label="heading" if yaw else "position", force_label="moment" if yaw else "force"))
    edits = step.step_edits(fit, args.dof)
    if args.added_mass_only:
        edits = {k: v for k, v in edits.items() if k.startswith("added_mass.")}
    elif args.update:
        from rovlab.params.vehicle import DOF4, load_vehicle

        i = DOF4.index(args.dof)
        current = load_vehicle(_check_update_target(args.update))
        if (current.damping_quadratic[i] != 0 or current.damping_cubic[i] != 0) and damping is None:
            print(f"rovlab: note: {args.update} also has quadratic/cubic {args.dof} damping; the step test's linear "
                  "damping is an equivalent linearisation that already contains them (use --added-mass-only to "
                  "keep the file's damping)", file=sys.stderr)
    how = f" --vehicle {args.vehicle}" if damping is not None else ""
    updated = _update(args, edits, ["added_mass"] + (["damping"] if len(edits) > 1 else []),
                      f"{args.dof}: rovlab identify step {Path(args.file).name} --mass {args.mass:g}{how}")
    data = fit.as_dict() | {"file": args.file, "dof": args.dof, "plot": png, "updated": updated}
    se = fit.stderr
    key, _ = step.DOF_KEYS[args.dof]
    text = "\n".join([
        f"first-order model u(s)/tau(s) = k/(s + a) from {args.file} ({fit.time_s.size} samples, output error)",
        f"  gain k = {_pm(fit.gain, se['gain'])}   pole a = {_pm(fit.pole, se['pole'])} 1/s",
        f"  with m = {args.mass:g}: added mass {key} = m - 1/k = {_pm(fit.added_mass, se['added_mass'])} (SNAME)",
        f"  linear damping = -a/k = {_pm(fit.linear_damping, se['linear_damping'])} (SNAME)",
    ] + ([f"  force bias = {_pm(fit.bias, se['bias'])}"] if fit.bias_fitted else []) + [
        f"  fit {fit.fit_percent:.2f} %, RMS position residual {fit.rms:.3g} {'rad' if yaw else 'm'}",
        (f"  quadratic {fit.fixed_damping[0]:g} and cubic {fit.fixed_damping[1]:g} damping held fixed "
         f"(from {args.vehicle})" if damping is not None else
         "  note: a linear model; nonlinear damping makes these an equivalent linearisation at the test's speeds "
         "(--vehicle holds known nonlinear damping fixed)"),
    ] + ([f"  figure: {png}"] if png else []))
    _emit(args, data, text)
    return 0


def _cmd_noise(args: argparse.Namespace) -> int:
    from rovlab.core.units import squared
    from rovlab.ident import noise, plots

    table, cols = noise.read_noise(args.file)
    est = _run(args.file, lambda: noise.noise_variances(table["time_s"], cols, detrend=args.detrend, allan=args.allan,
                                                        check_stationary=not args.no_stationarity_check))
    png = _plot(args, "noise", lambda p: plots.plot_noise(est, p, title=f"Resting log {Path(args.file).name}: "
                                                                        f"drift (degree {args.detrend}) removed"))
    updated = None
    if args.update:
        from rovlab.params.vehicle import load_vehicle

        target = _check_update_target(args.update)
        edits = _run(args.file, lambda: noise.noise_edits(est, load_vehicle(target)))
        sensors = sorted({k.split("]")[0] + "]" for k in edits})
        updated = _update(args, edits, sensors, f"variance: rovlab identify noise {Path(args.file).name} "
                                                f"({est.time_s.size} samples, drift degree {args.detrend})")
    units = {k: _column_unit(k) for k in est.channels}
    data = est.as_dict() | {"file": args.file, "plot": png, "updated": updated,
                            "units": {k: u or None for k, u in units.items()}}
    lines = [f"measurement variances (R diagonal) from {args.file}: {est.time_s.size} samples at {est.rate_hz:.4g} Hz, "
             f"drift of degree {args.detrend} removed",
             f"  {'column':18s} {'variance':>12s} {'':9s} {'std':>11s} {'':5s}  95 % interval of the variance"]
    for k, c in est.channels.items():
        u = units[k] or "(column's unit)"
        u2 = squared(units[k]) or "(column's unit)^2"
        lines.append(f"  {k:18s} {c.variance:12.5g} {u2:9s} {c.std:11.4g} {u:5s}  "
                     f"{c.ci95[0]:.4g} .. {c.ci95[1]:.4g} {u2}")
    if not all(units.values()):
        lines.append("  (a column named <quantity>_<sensor> or <sensor>.<quantity>, e.g. z_pressure, gets its SI unit)")
    if png:
        lines.append(f"  figure: {png}")
    _emit(args, data, "\n".join(lines))
    return 0


def _column_unit(column: str) -> str:
    """The SI unit of a resting log's column named ``<quantity>_<sensor>`` or ``<sensor>.<quantity>``
    ('' for another name)."""
    from rovlab.core.units import unit
    from rovlab.ident.noise import parse_channel_column

    parsed = parse_channel_column(column)
    return unit(parsed[1]) if parsed else ""


def _cmd_added_mass(args: argparse.Namespace) -> int:
    from rovlab.ident import added_mass, plots

    dims = {k: getattr(args, k) for k in ("length", "width", "height", "area_front", "area_side", "area_top")}
    if args.vehicle:
        from rovlab.params.vehicle import load_vehicle

        v = load_vehicle(args.vehicle)
        if v.geometry is None:
            raise _user_error(f"vehicle {v.name!r} has no [geometry] block; give --length ... --area-top instead")
        g = v.geometry
        base = {"length": g.length, "width": g.width, "height": g.height, "area_front": g.area_front,
                "area_side": g.area_side, "area_top": g.area_top}
        dims = {k: (dims[k] if dims[k] is not None else base[k]) for k in dims}
        rho = args.rho if args.rho is not None else v.water_density
    else:
        missing = ["--" + k.replace("_", "-") for k, x in dims.items() if x is None]
        if missing:
            raise _user_error("added-mass needs " + ", ".join(missing) + " (or --vehicle NAME to use its geometry)")
        rho = args.rho if args.rho is not None else 1000.0
    est = _run("added-mass", lambda: added_mass.added_mass_dnv(**dims, rho=rho))
    if max(dims["length"], dims["width"], dims["height"]) > 20.0:
        print(f"rovlab: note: the dimensions are read in metres (L, W, H = {dims['length']:g}, {dims['width']:g}, "
              f"{dims['height']:g} m) and the areas in m^2; were they given in millimetres?", file=sys.stderr)
    png = None
    if args.plot:
        png = _plot(args, "added-mass", lambda p: plots.plot_added_mass(est, p))
    updated = _update(args, added_mass.added_mass_edits(est), ["added_mass"],
                      "rovlab added-mass: Eidsvik/DNV-RP-H103 from L, W, H = "
                      f"{dims['length']:g}, {dims['width']:g}, {dims['height']:g} m")
    data = est.as_dict() | {"inputs": dims | {"rho": rho}, "plot": png, "updated": updated}
    lines = ["added mass (SNAME; Eidsvik's method on DNV-RP-H103 tables, Sandøy 2016, sec. 4.2.1)",
             f"  X_udot = {est.X_udot:9.4f} kg", f"  Y_vdot = {est.Y_vdot:9.4f} kg",
             f"  Z_wdot = {est.Z_wdot:9.4f} kg", f"  N_rdot = {est.N_rdot:9.4f} kg m^2",
             f"  lambda = {est.scale:.4f}; c_xy = {est.c_xy:.4f}, c_yz = {est.c_yz:.4f}, c_xz = {est.c_xz:.4f}",
             f"  cross-section W vs H differ by {100 * est.cross_section_mismatch:.0f} % "
             "(the method assumes about 10 % or less)"]
    lines += [f"  extrapolated: {e}" for e in est.extrapolated]
    if png:
        lines.append(f"  figure: {png}")
    _emit(args, data, "\n".join(lines))
    return 0


# --------------------------------------------------------------------------------------------
# lab
# --------------------------------------------------------------------------------------------

def _lab_vehicle(args: argparse.Namespace):
    from rovlab.params.vehicle import load_vehicle

    return load_vehicle(args.vehicle)


def _lab_call(fn: Callable[[], Any]) -> Any:
    try:
        return fn()
    except (ValueError, KeyError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        raise _user_error(str(msg)) from None


def _lab_report(args: argparse.Namespace, written: list[tuple[str, Any]], nxt: str) -> int:
    from rovlab.ident.lab import write_lab_data

    out = []
    for path, data in written:
        try:
            write_lab_data(path, data)
        except OSError as exc:
            raise _user_error(f"cannot write {path}: {exc.strerror or exc}") from None
        rows = len(next(iter(data.columns.values())))
        out.append({"file": path, "rows": rows, "experiment": data.experiment, "seed": data.seed,
                    "vehicle": data.vehicle, "truth": dict(data.truth), "notes": list(data.notes)})
    if args.json:
        json.dump(_clean({"written": out, "seed": written[0][1].seed, "next": nxt}), sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    for o in out:
        print(f"wrote {o['file']}: {o['experiment']}, {o['rows']} rows, vehicle {o['vehicle']}, seed {o['seed']}")
        if o["truth"]:
            print("  truth: " + ", ".join(f"{k} = {v:.6g}" for k, v in o["truth"].items()))
        for n in o["notes"]:
            print(f"  note: {n}")
    print(f"next: {nxt}")
    return 0


def _cmd_lab_thrust(args: argparse.Namespace) -> int:
    from rovlab.ident import lab

    v = _lab_vehicle(args)
    names = [n.strip() for n in args.thruster.split(",")] if args.thruster else None
    data = _lab_call(lambda: lab.thrust_rig(v, names, seed=args.seed, pwm_start=args.pwm_start, pwm_stop=args.pwm_stop,
                                            pwm_step=args.pwm_step, step_s=args.step_s, rate_hz=args.rate_hz,
                                            noise_std_n=args.noise_n))
    n = len(names) if names else 1
    window = min(5.0, 0.5 * args.step_s)
    nxt = (f"rovlab identify thrust {args.out}" + (f" --pair {n}" if n > 1 else "")
           + (f" --window {window:g}" if window != 5.0 else ""))
    return _lab_report(args, [(args.out, data)], nxt)


def _cmd_lab_towing(args: argparse.Namespace) -> int:
    from rovlab.ident import lab

    v = _lab_vehicle(args)
    speeds = _floats(args.speeds, "--speeds") or lab.DEFAULT_SPEEDS
    veh, rig = _lab_call(lambda: lab.towing_runs(v, args.dof, seed=args.seed, speeds=speeds, hold_s=args.hold_s,
                                                 noise_std_n=args.noise_n))
    out = Path(args.out)
    rig_out = args.rig_out or str(out.with_name(f"{out.stem}-rig{out.suffix or '.csv'}"))
    nxt = f"rovlab identify towing {args.out} --rig {rig_out} --dof {args.dof}"
    return _lab_report(args, [(args.out, veh), (rig_out, rig)], nxt)


def _cmd_lab_yaw(args: argparse.Namespace) -> int:
    from rovlab.ident import lab

    v = _lab_vehicle(args)
    moments = _floats(args.moments, "--moments") or lab.DEFAULT_MOMENTS
    data = _lab_call(lambda: lab.yaw_runs(v, seed=args.seed, moments=moments, duration_s=args.duration_s,
                                          moment_error=args.moment_error))
    return _lab_report(args, [(args.out, data)], f"rovlab identify yaw {args.out}")


def _cmd_lab_step(args: argparse.Namespace) -> int:
    from rovlab.ident import lab

    v = _lab_vehicle(args)
    data = _lab_call(lambda: lab.relay_test(v, args.dof, seed=args.seed, force=args.force, amplitude=args.amplitude,
                                            duration_s=args.duration_s, linear=args.linear,
                                            buoyancy_error_n=args.buoyancy_error))
    nxt = (f"rovlab identify step {args.out} --mass {data.truth['mass']:g} --dof {args.dof}"
           + (" --fit-bias" if args.dof == "heave" else "")
           + ("" if args.linear else f" --vehicle {args.vehicle}"))  # known nonlinear damping held fixed
    return _lab_report(args, [(args.out, data)], nxt)


def _cmd_lab_noise(args: argparse.Namespace) -> int:
    from rovlab.ident import lab

    v = _lab_vehicle(args)
    data = _lab_call(lambda: lab.resting_log(v, seed=args.seed, samples=args.samples, rate_hz=args.rate_hz))
    return _lab_report(args, [(args.out, data)], f"rovlab identify noise {args.out}")


# --------------------------------------------------------------------------------------------
# dives (issue 29)
# --------------------------------------------------------------------------------------------

def _dofs_arg(text: str) -> list[str]:
    return [d.strip() for d in text.split(",") if d.strip()]


def _cmd_lab_plan_dive(args: argparse.Namespace) -> int:
    from rovlab.ident import plan as dive_plan
    from rovlab.ident.dive import sensor_channels as dive_sensors

    v = _lab_vehicle(args)
    plan = _lab_call(lambda: dive_plan.plan_dive(
        v, _dofs_arg(args.dofs), args.duration, seed=args.seed, depth_min=args.depth_min, depth_max=args.depth_max,
        heave_speed=args.heave_speed, yaw_rate=math.radians(args.yaw_rate), surge_speed=args.surge_speed,
        sway_speed=args.sway_speed, box_m=args.box_m))
    expected = dive_plan.expected_sigmas(v, plan)
    command = (f"rovlab lab plan-dive --vehicle {args.vehicle} --dofs {','.join(plan.dofs)} --duration {args.duration:g} "
               f"--seed {args.seed} ({_dt.date.today().isoformat()})")
    try:
        dive_plan.write_plan(args.out, plan, expected, command=command)
    except OSError as exc:
        raise _user_error(f"cannot write {args.out}: {exc.strerror or exc}") from None
    nxt = f"rovlab lab dive --plan {args.out} --vehicle {args.vehicle} --seed 1 --out dive.csv"
    if args.json:
        data = {"plan": args.out, "vehicle": v.name, "dofs": list(plan.dofs), "duration_s": plan.duration_s,
                "depth_band_m": [plan.depth_min, plan.depth_max], "amplitude": plan.settings.get("amplitude"),
                "capacity": {k: list(c) for k, c in plan.capacity.items()},
                "horizontal_guard": ({"box_m": plan.box_m, "position_gain": plan.position_gain,
                                      "heading_gain": plan.heading_gain, "heading_damping": plan.heading_damping}
                                     if plan.horizontal else None),
                "expected": [{"parameter": e.name, "dof": e.dof, "guess": e.guess, "sigma": e.sigma,
                              "percent": e.percent if math.isfinite(e.percent) else None} for e in expected],
                "next": nxt}
        json.dump(_clean(data), sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    amp = plan.settings.get("amplitude", {})
    print(f"wrote {args.out}: {plan.duration_s:g} s of {' and '.join(plan.dofs)} excitation for {v.name}, depth band "
          f"{plan.depth_min:g}-{plan.depth_max:g} m")
    for dof, a in amp.items():
        lo, hi = plan.capacity[dof]
        unit = "N m" if dof == "yaw" else "N"
        print(f"  {dof}: levels up to {a:.3g} {unit} (thrusters give {lo:.3g} .. {hi:.3g} {unit} in {dof} alone)")
    print("expected standard deviations (Cramér-Rao, at the vehicle file's values, first 70 % of the log):")
    print(f"  {'parameter':10s} {'guess':>12s} {'sigma':>12s} {'sigma %':>9s}")
    for e in expected:
        pct = f"{e.percent:8.2f}%" if math.isfinite(e.percent) else "        -"
        print(f"  {e.name:10s} {e.guess:12.5g} {e.sigma:12.3g} {pct}  {e.unit}")
    print("  (the heading's AHRS errors counted as correlated over 0.5 s; a guess of 0 has no percentage)")
    if plan.horizontal:
        when = "in every other 40 s period, the yaw excitation off" if "yaw" in plan.dofs else "throughout"
        print(f"  surge/sway: {when} and the heading held (gain "
              f"{plan.heading_gain:g} N m/rad, damping {plan.heading_damping:g} N m s/rad); box {plan.box_m:g} m about "
              f"the start (position law {plan.position_gain:g} N/m)")
        print("  (surge/sway sigmas count the DVL's or position's noise only: with a quiet DVL the surge/sway force "
              "noise dominates, and the fit's sigmas were 6-16 times these on bluerov2_heavy_dvl; "
              "docs/identification.md)")
        if "yaw" in plan.dofs and "u" not in dive_sensors(v):
            print("  note: no DVL in the vehicle file: yaw in a surge/sway plan is poorly determined from a position "
                  "alone (the Munk moment needs the surge and sway velocity); fly yaw in a heave,yaw plan of its own")
    print(f"next: {nxt}")
    return 0


def _cmd_lab_dive(args: argparse.Namespace) -> int:
    from rovlab.ident import dive, lab
    from rovlab.ident import plan as dive_plan
    from rovlab.params.vehicle import load_vehicle

    v = _lab_vehicle(args)
    seed = args.seed if args.seed is not None else lab.new_seed()
    if args.pilot:
        from rovlab.ident import pilot

        plan: Any = _lab_call(lambda: pilot.pilot_dive(v, args.duration, seed=seed))
    else:
        plan = dive_plan.read_plan(args.plan)
        if plan.vehicle != v.name:
            print(f"rovlab: note: {args.plan} was planned for {plan.vehicle!r}, flown with {v.name!r}", file=sys.stderr)
    truth = (load_vehicle(args.truth_vehicle) if args.truth_vehicle
             else _lab_call(lambda: dive.hidden_vehicle(v, seed, spread=args.spread)))
    flight = _lab_call(lambda: dive.fly_plan(plan, v, truth, seed=seed, depth_rate_hz=args.depth_rate))
    notes = flight.notes + ((f"the depth guard held the excitation for {flight.guard_s:g} s",) if flight.guard_s else ())
    notes += (f"true depth {flight.depth_range[0]:.2f} .. {flight.depth_range[1]:.2f} m",)
    fmt = {k: ".6g" for k in flight.columns if k.startswith("pwm_")}
    data = lab.LabData("dive", flight.columns, flight.truth,
                       {"plan": args.plan or f"none: a pilot (seed {seed}, {args.duration:g} s)",
                        "truth_vehicle": args.truth_vehicle or f"hidden (seed {seed}, spread {args.spread:g})",
                        "depth_rate_hz": args.depth_rate}, seed, v.name, fmt, notes)
    return _lab_report(args, [(args.out, data)], f"rovlab identify dive {args.out} --vehicle {args.vehicle}")


def _cmd_dive(args: argparse.Namespace) -> int:
    from rovlab.ident import dive
    from rovlab.params.vehicle import load_vehicle

    if not 0.2 <= args.split <= 0.95:
        raise _user_error(f"--split must be within 0.2 .. 0.95 (the share of the log used to identify), got {args.split:g}")
    dofs = _dofs_arg(args.dofs) if args.dofs is not None else None
    bad = [d for d in dofs or () if d not in dive.ALL_DOFS]
    if bad or dofs == []:
        raise _user_error(f"--dofs {args.dofs}: identification from dives covers {', '.join(dive.ALL_DOFS)} (surge and "
                          "sway need position or velocity in the log)")
    free = _dofs_arg(args.free)
    unknown = [k for k in free if k not in dive.KEYS]
    if unknown or not free:
        raise _user_error(f"--free {args.free}: expected a selection of {', '.join(dive.KEYS)}")
    v = load_vehicle(args.vehicle)
    target = _check_update_target(args.update) if args.update else None
    try:
        data = _run(args.file, lambda: read_dive_log(args.file, v))
    except (ValueError, RuntimeError) as exc:  # rovlab.interfaces.mavlink.logs.LogError, a missing pymavlink
        raise _user_error(str(exc)) from None
    if dofs is None:
        from rovlab.ident.dive import default_dofs

        dofs = list(default_dofs(data))
    compare = _compare_set(args.compare, v)
    fit = _run(args.file, lambda: dive.identify_dive(data, v, dofs=dofs, free=free, split=args.split, compare=compare))
    updated = None
    if target is not None:
        edits = dive.dive_edits(fit, v)
        if not edits:
            print(f"rovlab: note: nothing determined by {args.file}: {target} left as it was", file=sys.stderr)
        else:
            from rovlab.params.edit import edit_vehicle_file

            notes = {b: f"{n} ({_dt.date.today().isoformat()})" for b, n in
                     dive.provenance(fit, Path(args.file).name).items()}
            try:
                edit_vehicle_file(target, edits, sources=notes)
            except OSError as exc:
                raise _user_error(f"--update: cannot write {target}: {exc.strerror or exc}; the file is unchanged "
                                  "(nothing was written)") from None
            updated = str(target)
            print(f"updated {target}: " + ", ".join(edits) + "; source notes: " + "; ".join(notes.values()),
                  file=sys.stderr)
    png = _plot(args, "dive", lambda p: _dive_figure(fit, data, v, p))
    d = fit.as_dict() | {"vehicle": v.name, "updated": updated, "plot": png}
    _emit(args, d, _dive_text(fit, v.name, args.compare) + (f"\n  figure: {png}" if png else ""))
    return 0


def _compare_set(text: str | None, vehicle: Any) -> Any:
    """The published set to score (rovlab.ident.published): --compare NAME|FILE, 'none', or the
    vehicle's default."""
    from rovlab.ident import published

    if text is not None and text.strip().lower() == "none":
        return None
    try:
        return published.default_set(vehicle) if text is None else published.load_set(text)
    except (ValueError, OSError) as exc:  # IdentificationError is a ValueError
        raise _user_error(str(exc)) from None


def _dive_figure(fit: Any, data: Any, vehicle: Any, path: Path) -> Any:
    from rovlab.ident import dive, plots

    models = {"identified": {d: f.model for d, f in fit.fits.items() if not f.refused_dof},
              "file": {d: dive.dof_model(vehicle, d) for d, f in fit.fits.items() if not f.refused_dof}}
    if fit.compare is not None:
        models["published"] = fit.compare.models(vehicle, tuple(models["file"]))
    traces = dive.validation_traces(fit.fitted or data, models, *fit.valid_span)  # yaw's input as fitted
    return plots.plot_dive(fit, traces, path, title=f"Dive validation: {Path(fit.file).name} ({vehicle.name}), "
                                                    f"identified on {fit.ident_span[0]:.0f}-{fit.ident_span[1]:.0f} s, "
                                                    f"validated on {fit.valid_span[0]:.0f}-{fit.valid_span[1]:.0f} s")


def _dive_text(fit, vehicle: str, compare_arg: str | None = None) -> str:
    a, b = fit.ident_span
    lines = [f"{', '.join(fit.fits)} from {fit.file} (vehicle {vehicle}): identification {a:.1f}-{b:.1f} s, validation "
             f"{fit.valid_span[0]:.1f}-{fit.valid_span[1]:.1f} s; output error; standard deviations robust to "
             "correlated errors (Newey-West; clustered by window)"]
    lines += [f"  {n}" for n in fit.notes]
    for dof, f in fit.fits.items():
        if f.refused_dof:
            lines.append(f"{dof}: not identified: {f.refused_dof}")
            continue
        unit = "rad/s" if dof == "yaw" else "m/s"
        lines.append(f"{dof}: {sum(f.samples.values())} samples in {f.windows} windows, speed RMS {f.speed_rms:.3g} "
                     f"max {f.speed_max:.3g} {unit}; residual RMS "
                     + ", ".join(f"{k} {v:.3g}" for k, v in f.rms.items()))
        lines.append(f"  {'parameter':9s} {'estimate':>12s} {'sigma':>10s} {'sigma %':>8s} {'file':>12s}")
        for p in f.params:
            if p.status == "estimated":
                pct = 100 * p.sigma / abs(p.estimate) if p.estimate else math.inf
                lines.append(f"  {p.name:9s} {p.estimate:12.5g} {p.sigma:10.3g} {pct:7.2f}% {p.start:12.5g}  {p.unit}"
                             + (f"  ({p.note})" if p.note else ""))
            elif p.status == "refused":
                lines.append(f"  {p.name:9s} {'refused':>12s} {'':10s} {'':8s} {p.start:12.5g}  {p.note}")
        if len(f.estimated) > 1:
            names = [dict((p.key, p.name) for p in f.params)[k] for k in f.estimated]
            lines.append("  correlations: " + ", ".join(
                f"{names[i]}/{names[j]} {f.correlation[i, j]:+.2f}" for i in range(len(names))
                for j in range(i + 1, len(names)) if abs(f.correlation[i, j]) >= 0.5) or "  correlations: all below 0.5")
    if fit.prediction:
        from rovlab.ident.dive import HORIZONS, PREDICTION_STEP_S

        pub = fit.compare is not None and any("published" in r for r in fit.prediction.values())
        cols = "identified / file" + (f" / published {fit.compare.name}" if pub else "")
        lines.append(f"prediction RMSE on the validation segment (steps of {PREDICTION_STEP_S:g} s; {cols}):")
        width = 28 if pub else 22
        head = "".join(f"{f'{k} step' + ('s' if k > 1 else ''):>{width}s}" for k in HORIZONS)
        lines.append(f"  {'':12s}{head}")
        for out, rows in fit.prediction.items():
            scale, unit = {"heading_rad": (180 / math.pi, "deg"), "u_mps": (1.0, "m/s"), "v_mps": (1.0, "m/s")}.get(
                out, (1.0, "m"))
            keys = ("identified", "file") + (("published",) if pub else ())
            cells = "".join(f"{' / '.join(f'{rows[k][i] * scale:.3g}' for k in keys):>{width}s}"
                            for i in range(len(HORIZONS)))
            lines.append(f"  {out.split('_')[0] + ' [' + unit + ']':12s}{cells}")
        if pub:
            lines.append(f"  {fit.compare.note()}")
        elif compare_arg is not None and compare_arg.strip().lower() == "none":
            lines.append("  no published parameter set compared (--compare none)")
        else:
            from rovlab.ident.published import packaged_sets

            listed = "; ".join(f"{n} for {', '.join(s.vehicles)}" for n, s in packaged_sets().items() if s.vehicles)
            lines.append(f"  no published parameter set compared: none is listed for {vehicle} (packaged: {listed}); "
                         "--compare NAME|FILE scores one")
    return "\n".join(lines)


def read_dive_log(path: str | Path, vehicle: Any) -> Any:
    """A dive (rovlab.ident.dive.DiveData) from a CSV log, or from a .tlog / .BIN / .mcap MAVLink
    log through the MAVLink log readers (SERVO_OUTPUT_RAW through the thrust curves,
    SCALED_PRESSURE2 depth, ATTITUDE heading and yaw rate), the same columns as a CSV's; or from a
    ROS node's recording (FILE.mcap with its FILE.rovlab.mcap: the PWM it commanded and the samples
    each control step used)."""
    from rovlab.ident import dive

    path = Path(path)
    if path.suffix.lower() not in (".tlog", ".bin", ".mcap"):
        return dive.read_dive(path, vehicle)
    series = path if path.name.endswith(".rovlab.mcap") else path.with_name(path.stem + ".rovlab.mcap")
    if path.suffix.lower() == ".mcap" and series.exists():  # a ROS node's recording (e.g. rovlab ros2 node --fly)
        from rovlab.io.timeseries import read_mcap_columns

        cols = read_mcap_columns(series)  # its PWM commands and the samples of each step (meas_<column>)
        return dive.dive_from_columns({k.removeprefix("meas_"): v for k, v in cols.items()
                                       if k == "time_s" or k.startswith(("meas_", "pwm_"))}, vehicle, file=str(path))
    from types import SimpleNamespace

    from rovlab.interfaces.mavlink.logs import filter_columns, read_records, stamp_outliers

    records = read_records(path)
    drop = set(stamp_outliers([r[0] for r in records], 100.0))
    records = [r for i, r in enumerate(records) if i not in drop]
    kinds = {"depth": "pressure", "heading": "imu", "rate": "imu", "x": "motion_capture", "y": "motion_capture",
             "u": "dvl", "v": "dvl"}
    chans = tuple(SimpleNamespace(column=v[0], kind=kinds[k], quantity=v[2])
                  for k, v in dive.sensor_channels(vehicle).items())
    cols = filter_columns(records, vehicle, chans, 0.1, file=str(path))
    return dive.dive_from_columns(cols, vehicle, file=str(path))
