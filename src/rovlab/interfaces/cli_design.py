"""Sub-commands ``design`` (observer and LQR design) and ``filter`` (offline estimation of a log).

Interfaces hold no maths: these load the files, call rovlab.estimation / rovlab.control and
format the answer.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.params.validate import ConfigError, Problem

INPUT_COLUMNS = ("tau_Z", "tau_N")


def register(sub: argparse._SubParsersAction) -> None:
    des = sub.add_parser("design", help="design a configuration's estimator and controller and show them (the KF: "
                                        "discretised model, observability; the LQR: gains)")
    _common(des)
    des.add_argument("--json", action="store_true", help="machine-readable output (SI units)")
    des.add_argument("--allow-unobservable", action="store_true",
                     help="report an unobservable sensor set instead of refusing it")
    des.set_defaults(func=_cmd_design)

    fil = sub.add_parser("filter", help="estimate depth, heading, velocities and biases from a recorded log")
    fil.add_argument("log", help="CSV log: time_s, tau_Z, tau_N and one column per fused sensor channel "
                                 "(e.g. z_qualisys, z_pressure, psi_qualisys); empty or nan = no sample; or an MCAP "
                                 "log with rovlab's topics (a simulation's timeseries.mcap, a `rovlab ros2 node "
                                 "--record` recording); or a MAVLink dive: a .tlog, or an .mcap recorded by "
                                 "rovlab mavlink (needs rovlab[mavlink]; docs/mavlink.md)")
    fil.add_argument("--out", required=True, help="output CSV (- for standard output)")
    fil.add_argument("--estimator", default=None, metavar="NAME",
                     help="the estimator to replay the log with: any registered one (kf, ekf, a plugin's; "
                          "default: the configuration's estimator)")
    fil.add_argument("--max-gap-steps", type=int, default=10_000, metavar="N",
                     help="a gap of more than N filter samples restarts the filter from its prior instead of "
                          "predicting through it (default 10000)")
    fil.add_argument("--trust-vehicle-file", action="store_true",
                     help="an ArduSub log's parameters (frame, MOT_n_DIRECTION, PWM range) that disagree with the "
                          "vehicle file: warn instead of refusing")
    _common(fil)
    fil.set_defaults(func=_cmd_filter)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", default="udrone", help="packaged vehicle name or TOML file (default: udrone)")
    p.add_argument("--config", default="default",
                   help="filter/controller configuration: packaged name (default, thesis) or TOML file "
                        "(default: default)")


# --------------------------------------------------------------------------------------------
# design
# --------------------------------------------------------------------------------------------

def _cmd_design(args: argparse.Namespace) -> int:
    """The design of a configuration's estimator and controller, as each component summarises
    itself (ComponentInfo.summary / describe; a component with neither by its table's values)."""
    import inspect

    from rovlab.core.components import component
    from rovlab.core.summary import render, table_values
    from rovlab.interfaces.cli import UserError
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle
    from rovlab.sim.components import build_pair

    vehicle = load_vehicle(args.vehicle)
    config = load_design_config(args.config)
    est_info, ctl_info = component("estimator", config.estimator), component("controller", config.controller)
    options: dict[str, Any] = {}
    if args.allow_unobservable and est_info is not None:
        if "require_observable" not in inspect.signature(est_info.build).parameters:
            raise UserError(f"--allow-unobservable: estimator {est_info.name!r} has no such option "
                            "(it checks its own observability; kf has the option)")
        options["require_observable"] = False
    est, ctl = build_pair(vehicle, config, estimator_options=options)  # ConfigError for unknown names
    assert est_info is not None and ctl_info is not None
    parts = (("estimator", est_info, est), ("controller", ctl_info, ctl))
    info: dict[str, Any] = {"vehicle": vehicle.name, "config": config.name, "sample_time": est.h,
                            "estimator": est_info.name, "controller": ctl_info.name}
    summaries = {}
    for kind, ci, spec in parts:
        summary = ci.summary(spec) if ci.summary is not None else {}
        if not summary and ci.default_table is not None:
            summary = {ci.name: table_values(config.table(ci.name))}
        summaries[kind] = summary
        info.update({k: v for k, v in summary.items() if k not in info})
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    print(f"vehicle {vehicle.name}, configuration {config.name} ({config.file}); sample time {est.h:g} s")
    for kind, ci, spec in parts:
        print(f"{kind} {ci.name}: {ci.description or '(no description)'}")
        lines = ci.describe(spec) if ci.describe is not None else render(summaries[kind])
        for line in lines or ["  (the component declares no summary and owns no table)"]:
            print(line)
    return 0


# --------------------------------------------------------------------------------------------
# filter
# --------------------------------------------------------------------------------------------

def _check_initial(config, model) -> None:
    """Refuse an initial belief no filter can start from (e.g. a depth of 1e308 m)."""
    from rovlab.estimation.streaming import MAX_ABS_SAMPLE

    problems = []
    for i, name in enumerate(model.states):
        x, sd = float(model.x0[i]), float(np.sqrt(max(model.P0[i, i], 0.0)))
        if not abs(x) <= MAX_ABS_SAMPLE:
            problems.append(Problem(config.file, f"initial.state.{name}", x,
                                    f"|value| <= {MAX_ABS_SAMPLE:g} (SI units)"))
        if not sd <= MAX_ABS_SAMPLE:
            problems.append(Problem(config.file, f"initial.std.{name}", sd, f"<= {MAX_ABS_SAMPLE:g} (SI units)"))
    if problems:
        raise ConfigError(problems, "configuration")


def _cmd_filter(args: argparse.Namespace) -> int:
    from rovlab.interfaces.cli import UserError

    if args.max_gap_steps < 1:
        raise UserError(f"--max-gap-steps must be at least 1, got {args.max_gap_steps}")
    filt, inputs, vehicle, config = _offline_filter(args)
    with tempfile.TemporaryDirectory(prefix="rovlab-filter-") as tmp:
        return _filter(args, vehicle, config, filt, inputs, _as_csv(args.log, vehicle, filt.model, Path(tmp),
                                                                          trust=args.trust_vehicle_file,
                                                                          max_gap_steps=args.max_gap_steps))


def _offline_filter(args: argparse.Namespace):
    """(filter, its input columns, vehicle, configuration) for ``rovlab filter``: the
    depth-and-heading filter's own replay for estimator kf (its kernels, its inputs Z and N), any
    other registered estimator through its slots (rovlab.estimation.offline; the wrench X, Y, Z, N)."""
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    vehicle = load_vehicle(args.vehicle)
    config = load_design_config(args.config)
    name = args.estimator or config.estimator
    if name == "kf":
        from rovlab.estimation.filtering import DepthHeadingFilter
        from rovlab.estimation.model import build_filter_model

        model = build_filter_model(vehicle, config)
        _check_initial(config, model)
        return DepthHeadingFilter(model), INPUT_COLUMNS, vehicle, config
    from rovlab.core.components import component, unknown_component
    from rovlab.estimation.offline import WRENCH_COLUMNS, ComponentFilter

    info = component("estimator", name)
    if info is None:
        where = "--estimator" if args.estimator else f"{config.file}: estimator"
        raise ConfigError([Problem(where, "estimator", name, unknown_component("estimator", name))], "command line")
    return ComponentFilter(info.build(vehicle, config)), WRENCH_COLUMNS, vehicle, config


def _as_csv(log: str, vehicle, model, folder: Path, *, trust: bool = False, max_gap_steps: int | None = None) -> str:
    """The log as a CSV the filter reads: a CSV as it is; a MAVLink dive (.tlog, or an .mcap with
    /mavlink/ topics) converted from its telemetry; another .mcap (rovlab's topics: a simulation
    or a vehicle node's recording) from its measurement and command columns."""
    from rovlab.interfaces.cli import UserError

    suffix = Path(log).suffix.lower()
    if suffix in (".tlog", ".bin"):
        return _mavlink_as_csv(log, vehicle, model, folder, trust=trust, max_gap_steps=max_gap_steps)
    if suffix != ".mcap":
        return log
    try:
        from rovlab.io.timeseries import mcap_topics, read_mcap_columns

        topics = mcap_topics(log)
    except (ImportError, RuntimeError):
        raise UserError("reading MCAP needs the 'mcap' package: pip install 'rovlab[log]'") from None
    except OSError as exc:
        raise UserError(f"cannot read {log}: {exc.strerror or exc}") from None
    if any(t.startswith("/mavlink/") for t in topics):
        return _mavlink_as_csv(log, vehicle, model, folder, trust=trust, max_gap_steps=max_gap_steps)
    from rovlab.io.logwriter import write_csv

    out = folder / (Path(log).stem + ".csv")
    write_csv(out, read_mcap_columns(log), exact=("time_s",))
    return str(out)


def _mavlink_as_csv(log: str, vehicle, model, folder: Path, *, trust: bool = False,
                    max_gap_steps: int | None = None) -> str:
    """A MAVLink dive (.tlog, DataFlash .BIN, or .mcap recorded by rovlab mavlink) as the CSV the
    filter reads, after checking the vehicle file against the autopilot parameters the log carries
    (frame, MOT_n_DIRECTION, PWM range: rovlab.interfaces.mavlink.autopilot) unless ``trust``."""
    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.mavlink import MavlinkMissing
    from rovlab.interfaces.mavlink.autopilot import TRUST_HINT, check_vehicle
    from rovlab.interfaces.mavlink.logs import LogError, left_out_lines, log_parameters, read_records, write_filter_log

    out = folder / (Path(log).stem + ".csv")
    try:
        records = read_records(log)
        params = log_parameters(records)
        problems = check_vehicle(vehicle, params, source=str(log))
        if problems and not trust:
            raise ConfigError(problems, f"vehicle file {vehicle.name} against the autopilot parameters of the log "
                                        f"(rovlab vehicle from-ardusub {log} --base {vehicle.name} --out V.toml writes one "
                                        f"that agrees; {TRUST_HINT})")
        if problems:
            print(f"rovlab filter: --trust-vehicle-file: {len(problems)} disagreement(s) with {log}'s parameters "
                  "ignored", file=sys.stderr)
        if not params:
            print(f"rovlab filter: {log} carries no autopilot parameters: the vehicle file's thruster directions "
                  "cannot be checked", file=sys.stderr)
        summary = write_filter_log(log, vehicle, model, out, records=records, max_gap_steps=max_gap_steps)
    except (LogError, MavlinkMissing, RuntimeError) as exc:
        raise UserError(str(exc)) from None
    for line in left_out_lines(log, summary):
        print(f"rovlab filter: {line}", file=sys.stderr)
    counts = ", ".join(f"{k} {v}" for k, v in summary["samples"].items())
    print(f"rovlab filter: {log}: {summary['messages']} MAVLink messages -> {summary['rows']} rows ({counts})",
          file=sys.stderr)
    return str(out)


def _filter(args: argparse.Namespace, vehicle, config, filt, inputs: tuple[str, ...], log: str) -> int:
    from rovlab.io.logreader import LogStream

    model = filt.model
    columns = [c.column for c in model.channels]
    # a simulation's timeseries.csv names the samples meas_<quantity>_<sensor>: read those as they are
    header = set(LogStream(log, required=("time_s",)).header)
    source = {c: f"meas_{c}" if c not in header and f"meas_{c}" in header else c for c in columns}
    # tau_Z and tau_N are required; the surge and sway inputs of a 4-DOF estimator are 0 when the log
    # has none (a depth-and-heading controller's log commands neither)
    absent = tuple(c for c in inputs if c not in header and c not in INPUT_COLUMNS)
    stream = LogStream(log, required=("time_s",) + tuple(c for c in inputs if c not in absent) + tuple(source.values()))
    chunks = iter(stream)  # a reader thread parses ahead from here (while the kernels load)
    try:
        return _filter_chunks(args, vehicle, config, filt, inputs, absent, stream, chunks, columns, source)
    finally:
        close = getattr(chunks, "close", None)
        if close is not None:
            close()


def _filter_chunks(args: argparse.Namespace, vehicle, config, filt, inputs: tuple[str, ...], absent: tuple[str, ...],
                   stream, chunks, columns: list[str], source: dict[str, str]) -> int:
    from rovlab.estimation.layout import (
        EVENT_NONFINITE,
        EVENT_REJECTED,
        EVENT_USED,
        REASON_NAMES,
        REASON_STUCK,
        STATUS_LOST,
        STATUS_NAMES,
        status_label,
    )
    from rovlab.estimation.streaming import IntervalError, StreamingFilter
    from rovlab.interfaces.cli import UserError
    from rovlab.io.logwriter import ChunkWriter

    model = filt.model
    runner = StreamingFilter(filt, max_gap_steps=args.max_gap_steps)
    m = len(columns)
    # status codes -> labels ('ok', 'lost-timeout', ...): code = 8 status + reason
    assert len(REASON_NAMES) <= 8
    labels = [status_label(c // 8, c % 8) if c // 8 < len(STATUS_NAMES) and c % 8 < len(REASON_NAMES) else "?"
              for c in range(8 * len(STATUS_NAMES))]
    # the column names of a simulation's timeseries.csv (est_*, var_*, status_*): one scheme everywhere
    names = ["time_s", *(f"est_{s}" for s in model.states), *(f"var_{s}" for s in model.states),
             *(f"status_{c}" for c in columns)]
    estimator = args.estimator or config.estimator
    comments = [f"rovlab filter {args.log}: vehicle {vehicle.name}, configuration {config.name}, "
                f"estimator {estimator}, h = {model.h:g} s", "units: SI (m, rad, m/s, rad/s, N, N m); var_* are the variances"]
    samples = np.zeros(m, dtype=np.int64)
    used = np.zeros(m, dtype=np.int64)
    rejected = np.zeros(m, dtype=np.int64)
    stuck = np.zeros(m, dtype=np.int64)
    faulty = np.zeros(m, dtype=np.int64)
    lost = np.zeros(m, dtype=np.int64)
    gaps = 0
    n_rows = 0
    t_first = t_last = t_prev = math.nan
    rows_read = 0  # rows of the chunks before this one
    converted = Path(stream.file) != Path(args.log)  # a MAVLink dive or an MCAP, converted into a temporary CSV
    restart_times: dict[int, float] = {}  # row -> its time, for a converted log (its lines are the user's nowhere)

    def emit(writer: ChunkWriter, run) -> None:
        nonlocal n_rows
        out: dict[str, Any] = {"time_s": run.t}
        for i, s in enumerate(model.states):
            out[f"est_{s}"] = run.x[:, i]
        for i, s in enumerate(model.states):
            out[f"var_{s}"] = run.variance[:, i]
        for j, c in enumerate(columns):
            out[f"status_{c}"] = (run.status[:, j].astype(np.int32) * 8 + run.reason[:, j], labels)
            used[j] += int(np.count_nonzero(run.event[:, j] == EVENT_USED))
            rej = run.event[:, j] == EVENT_REJECTED
            frozen = rej & (run.reason[:, j] == REASON_STUCK)  # the status word says lost-stuck there
            stuck[j] += int(np.count_nonzero(frozen))
            rejected[j] += int(np.count_nonzero(rej & ~frozen))
            faulty[j] += int(np.count_nonzero(run.event[:, j] == EVENT_NONFINITE))
            lost[j] += int(np.count_nonzero(run.status[:, j] >= STATUS_LOST))
        writer.write(out)
        n_rows += run.t.size

    # plain CSV (pandas reads it with defaults); what it is goes in a JSON sidecar, written with the
    # CSV when it is complete (a full disk or Ctrl-C leaves neither, and an earlier run's pair as it was)
    sidecar = None if args.out == "-" else {
        "what": comments[0], "units": comments[1], "vehicle": vehicle.name, "configuration": config.name,
        "estimator": estimator, "sample_time_s": model.h, "log": str(args.log)}
    try:
        with ChunkWriter(args.out, names, significant=10, exact=("time_s",), sidecar=sidecar) as writer:
            try:
                chunk = next(chunks, None)
                while chunk is not None:
                    nxt = next(chunks, None)
                    t = chunk.data["time_s"]
                    if math.isnan(t_first):
                        t_first = float(t[0])
                    t_last = float(t[-1])
                    u = np.column_stack([np.zeros(t.size) if c in absent else chunk.data[c] for c in inputs])
                    y = np.column_stack([chunk.data[source[c]] for c in columns])
                    samples += np.count_nonzero(~np.isnan(y), axis=0)
                    dt = np.diff(np.concatenate([[t_prev], t]) if math.isfinite(t_prev) else t)
                    gaps += int(np.count_nonzero((dt > 1.5 * model.h)
                                                 & (dt <= (args.max_gap_steps + 0.5) * model.h)))
                    for run in runner.feed(t, u, y, final=nxt is None):
                        emit(writer, run)
                    for r in runner.restart_rows:
                        if r not in restart_times:
                            restart_times[r] = float(t[r - rows_read]) if r >= rows_read else t_prev
                    t_prev = float(t[-1])
                    rows_read += t.size
                    chunk = nxt
            except IntervalError as exc:
                raise ConfigError([Problem(stream.file, stream.where(exc.row, "time_s"),
                                           f"a step of {exc.dt:.6g} s after line {stream.line_of(exc.row - 1)}",
                                           "finite times that increase (each row is fused at the filter period "
                                           f"nearest its time, h = {model.h:g} s)")],
                                  "log") from None
            if runner.restarts > 100:
                first = runner.restart_rows[0]
                raise ConfigError([Problem(str(args.log) if converted else stream.file,
                                           f"t = {restart_times[first] - t_first:.6g} s" if converted
                                           else stream.where(first, "time_s"),
                                           f"{runner.restarts} gaps longer than {args.max_gap_steps} filter samples",
                                           f"a log sampled near the configuration's sample time h = {model.h:g} s "
                                           f"({config.file}: sample_time); gaps are exceptions")], "log")
    except OSError as exc:  # a full disk: in the writer's thread, or at the end (CSV and sidecar)
        raise UserError(f"cannot write {args.out}: {exc.strerror or exc}") from None

    report = sys.stderr if args.out == "-" else sys.stdout
    span = t_last - t_first if n_rows > 1 else 0.0
    print(f"filtered {n_rows} samples ({span:g} s) of {args.log} with {vehicle.name}/{config.name}"
          + (f", estimator {estimator}" if estimator != "kf" else "")
          + ("" if args.out == "-" else f" -> {args.out}"), file=report)
    if absent:
        print(f"  {', '.join(absent)}: not in the log, taken as 0", file=report)
    if gaps:
        print(f"  {gaps} gap(s) in the log bridged by prediction", file=report)
    if runner.restarts:
        if converted:  # the times in the dive (from its first message the filter uses)
            where = ", ".join(f"t = {restart_times[r] - t_first:.6g} s" for r in runner.restart_rows)
        else:
            where = ", ".join(stream.where(r) for r in runner.restart_rows)
        print(f"  {runner.restarts} gap(s) longer than {args.max_gap_steps} samples "
              f"({args.max_gap_steps * model.h:g} s): the filter restarted from its prior at {where}"
              + (" ..." if runner.restarts > len(runner.restart_rows) else ""), file=report)
    if runner.absurd:
        print(f"  {runner.absurd} value(s) beyond +-1e6 treated as faulty samples (inputs held)", file=report)
    for j, c in enumerate(model.channels):
        print(f"  {c.name:16s} {samples[j]} samples, {used[j]} used, {rejected[j]} rejected by the gate"
              + (f", {stuck[j]} not used while stuck (lost-stuck)" if stuck[j] else "")
              + (f", {faulty[j]} not finite" if faulty[j] else "")
              + f"; lost {100.0 * lost[j] / max(n_rows, 1):.1f}% of the time", file=report)
    return 0
