"""Sub-commands ``simulate`` (one scenario, optionally Monte Carlo) and ``demo`` (the main job:
the three thesis case studies on uDrone, with a report). Interfaces hold no maths."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any


def register(sub: argparse._SubParsersAction) -> None:
    sim = sub.add_parser("simulate", help="run a closed-loop scenario (packaged name or TOML file)")
    sim.add_argument("scenario", help="packaged scenario name or TOML path (rovlab scenarios lists them)")
    sim.add_argument("--out", default=None, help="output folder (default: out/<scenario>)")
    sim.add_argument("--seed", type=int, default=None, help="seed (default: the scenario's); replays one run")
    sim.add_argument("--runs", type=int, default=1, help="Monte Carlo: number of runs (seeds seed .. seed+N-1)")
    sim.add_argument("--workers", type=int, default=None, help="parallel worker processes (default: all cores)")
    sim.add_argument("--backend", choices=("processes", "dask"), default="processes",
                     help="where Monte Carlo runs go (dask needs rovlab[dask])")
    sim.add_argument("--scheduler", default=None, help="Dask scheduler address (default: a local cluster)")
    sim.add_argument("--no-figures", action="store_true", help="skip PNGs and report.html (faster)")
    sim.set_defaults(func=_cmd_simulate)

    comp = sub.add_parser("compile", help="compile the loops of scenarios into numba's cache ahead of their runs",
                          description="Compile the closed loop of each scenario's combination of components "
                                      "(plant, estimator, controller) into numba's disk cache, so that later runs "
                                      "load it instead of compiling it (e.g. in a Dockerfile). Nothing else ever "
                                      "compiles ahead or in the background.")
    comp.add_argument("scenarios", nargs="*", metavar="SCENARIO", help="packaged scenario names or TOML paths")
    comp.add_argument("--all", action="store_true",
                      help="every combination the packaged scenarios run (and rovlab compare's MRAC and LQG), the "
                           "control step of every packaged configuration and the real-time simulated vehicle")
    comp.add_argument("--node", action="store_true",
                      help="the control step a vehicle node runs (rovlab ros2/ros1 node, rovlab mavlink bridge, the "
                           "HMI on a live source) for --vehicle and --config")
    comp.add_argument("--vehicle", default="bluerov2_heavy",
                      help="with --node: vehicle name or TOML file (default bluerov2_heavy, the bridge's)")
    comp.add_argument("--config", default="bluerov2_heavy",
                      help="with --node: configuration name or TOML file (default bluerov2_heavy, the bridge's)")
    comp.add_argument("--realtime", action="store_true",
                      help="the plant of the real-time simulated vehicle (rovlab mavlink sim, rovlab ros2/ros1 sim)")
    comp.set_defaults(func=_cmd_compile)

    lst = sub.add_parser("scenarios", help="list the packaged scenarios")
    lst.set_defaults(func=_cmd_list)

    demo = sub.add_parser("demo", help="the main job: the thesis case studies on uDrone, with a report")
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.add_argument("--runs", type=int, default=200, help="Monte Carlo runs for the consistency check (default 200)")
    demo.add_argument("--workers", type=int, default=None, help="parallel worker processes (default: all cores)")
    demo.add_argument("--compare-runs", type=int, default=50,
                      help="runs per controller of the MRAC/LQG heave comparisons (default 50; 0 skips them)")
    demo.set_defaults(func=_cmd_demo)


def _cmd_list(args: argparse.Namespace) -> int:
    from rovlab.sim.scenario import load_scenario, packaged_scenario_names

    for name in packaged_scenario_names():
        sc = load_scenario(name)
        print(f"{name:22s} {sc.description}")
    return 0


def _cmd_compile(args: argparse.Namespace) -> int:
    from rovlab.interfaces.cli import UserError
    from rovlab.sim.compile import needs_compiling
    from rovlab.sim.prepare import prepare
    from rovlab.sim.runner import compile_loop, shipped_components
    from rovlab.sim.scenario import load_scenario_data, packaged_scenario_names

    if args.all and args.scenarios:
        raise UserError("name the scenarios to compile, or --all (not both)")
    if not (args.scenarios or args.all or args.node or args.realtime):
        raise UserError("name the scenarios to compile, or --all, --node or --realtime")
    total = time.perf_counter()
    if args.node or args.all:
        _compile_node_steps(args)
    if args.realtime or args.all:
        _compile_realtime()
    if not (args.scenarios or args.all):
        print(f"ready in {time.perf_counter() - total:.1f} s")
        return 0
    jobs: list[tuple[str, str | None]] = [(name, None) for name in args.scenarios]
    if args.all:
        jobs = [(name, None) for name in packaged_scenario_names()]
        jobs += [(name, c) for name in _COMPARISONS for c in ("lqg", "mrac")]
    loaded = [(ref, controller, *load_scenario_data(ref)) for ref, controller in jobs]  # every file checked first
    seen: set[str] = set()
    for ref, controller, data, file in loaded:
        prep = prepare({**data, "controller": controller} if controller else data, file=file)
        key = prep.loop_key
        if key in seen:
            continue
        seen.add(key)
        if not shipped_components(prep):
            print(f"{key:24s} not cached: components from outside rovlab are compiled in every process ({ref})")
            continue
        if not needs_compiling(key):
            print(f"{key:24s} cached ({ref})")
            continue
        print(f"{key:24s} compiling ({ref}) ...", end="", flush=True)
        try:
            print(f" {compile_loop(prep):.1f} s")
        except TypeError as exc:  # a component kernel that allocates (rovlab.sim.loop.allocation_error)
            raise UserError(f"{ref}: {exc}") from None
    print(f"{len(seen)} loop{'s' if len(seen) != 1 else ''} ready in {time.perf_counter() - total:.1f} s")
    return 0


def _compile_node_steps(args: argparse.Namespace) -> None:
    """The control step of NodeCore for --vehicle/--config (with --all: of every packaged
    configuration's estimator and controller), compiled into numba's cache by building the node."""
    from rovlab.interfaces.node.core import NodeCore
    from rovlab.params.design import load_design_config, packaged_config_names
    from rovlab.params.vehicle import load_vehicle

    pairs = [(args.vehicle, args.config)] if args.node else []
    if args.all:
        pairs += [(args.vehicle, name) for name in packaged_config_names()]
    seen: set[tuple[str, str]] = set()
    for vehicle, config in pairs:
        v, c = load_vehicle(vehicle), load_design_config(config)
        key = (c.estimator, c.controller)
        if key in seen:
            continue
        seen.add(key)
        started = time.perf_counter()
        print(f"node control step {c.estimator} + {c.controller} ({c.name}) ...", end="", flush=True)
        core = NodeCore(v, c, log=lambda msg: print(f"\n  {msg}", end="", flush=True))
        core.prepare_flight()  # and the step that flies a dive plan (--fly) with this estimator
        print(f" {time.perf_counter() - started:.1f} s")


def _compile_realtime() -> None:
    """The real-time simulated vehicle's plant (rovlab.sim.realtime), for both plant kinds' scenarios
    the simulators default to."""
    from rovlab.sim.realtime import SimulatedVehicle

    for scenario in ("bluerov2-heavy-step", "step-observer-model"):  # the process plant, the observer plant
        started = time.perf_counter()
        print(f"real-time simulated vehicle, plant of {scenario} ...", end="", flush=True)
        SimulatedVehicle(scenario).compile()
        print(f" {time.perf_counter() - started:.1f} s")


def _check_counts(args: argparse.Namespace) -> None:
    from rovlab.interfaces.cli import UserError

    if args.runs < 1:
        raise UserError(f"--runs must be at least 1, got {args.runs}")
    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers must be at least 1, got {args.workers}")
    if getattr(args, "seed", None) is not None and args.seed < 0:
        raise UserError(f"--seed must be >= 0, got {args.seed}")


def _cmd_simulate(args: argparse.Namespace) -> int:
    from rovlab.sim.scenario import load_scenario_data

    _check_counts(args)
    if args.backend == "dask":
        from rovlab.interfaces.cli import UserError
        from rovlab.sim.montecarlo import dask_available

        if not dask_available():  # say so before anything runs or is written
            raise UserError("--backend dask needs Dask: pip install 'rovlab[dask]' (or use --backend processes)")
    data, file = load_scenario_data(args.scenario)
    name = str(data.get("name") or Path(file).stem)
    out = Path(args.out or Path("out") / name)
    return _simulate(args, data, file, out)


def _simulate(args: argparse.Namespace, data, file, out: Path) -> int:
    figures = not args.no_figures
    interrupted = False
    if args.runs > 1:  # the single run's files are written while the Monte Carlo workers run
        result, metrics = _run(data, file, args.seed)
        notes: list[str] = []
        sc = result.scenario
        written: list[bool] = []

        def meanwhile() -> None:
            _write(out, result, metrics, notes, figures=figures)
            written.append(True)

        summary = _monte_carlo(data, file, sc.seed, args.runs, args.workers, args.backend, args.scheduler, out,
                               result, metrics, notes, figures=figures, meanwhile=meanwhile)
        print(f"{sc.name} (seed {sc.seed}, {sc.plant} plant, {sc.duration_s:g} s) -> {out}/")
        _print_mc(summary)
        interrupted = bool(summary.get("interrupted"))
        if interrupted and not written:
            notes.append(f"Ctrl-C came while seed {sc.seed}'s own files were being written: its figures and "
                         f"report.html may be missing (rovlab simulate {sc.name} --seed {sc.seed} writes them)")
    else:
        result, metrics, notes = _run_and_write(data, file, args.seed, out, figures=figures)
        sc = result.scenario
        print(f"{sc.name} (seed {sc.seed}, {sc.plant} plant, {sc.duration_s:g} s) -> {out}/")
    _print_summary([(sc.name, metrics)])
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    return 130 if interrupted else 0  # Ctrl-C: the finished runs are written, the status says it stopped


def _run_and_write(data, file, seed, out: Path, *, figures: bool = True, compiled: list[float] | None = None):
    result, metrics = _run(data, file, seed, compiled)
    notes: list[str] = []
    _write(out, result, metrics, notes, figures=figures)
    return result, metrics, notes


def _run(data, file, seed, compiled: list[float] | None = None):
    """One run of the scenario and its metrics."""
    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.compiling import ensure_compiled
    from rovlab.sim.prepare import prepare
    from rovlab.sim.results import summarise
    from rovlab.sim.runner import PlantDiverged, run_prepared

    prep = prepare(data, file=file, seed=seed)
    try:
        seconds = ensure_compiled(prep, say=compiled is None)  # the demo says it on its own line
        if seconds is not None and compiled is not None:
            compiled.append(seconds)
        result = run_prepared(prep)
    except PlantDiverged as exc:
        raise UserError(f"{file}: {exc}") from None
    except TypeError as exc:
        if "allocates memory" not in str(exc):  # (rovlab.sim.loop.allocation_error's explanation)
            raise
        raise UserError(f"{file}: {exc}") from None  # a component kernel that allocates
    return result, summarise(result)


def _write(out: Path, result, metrics, notes: list[str], *, figures: bool = True) -> None:
    """The run's files (what cannot be written goes into ``notes``)."""
    from rovlab.interfaces.cli import UserError
    from rovlab.sim.output import write_run

    try:
        write_run(out, result, metrics, figures=figures, report=figures, notes=notes)
    except OSError as exc:
        raise UserError(f"cannot write the results to {out}/: {exc.strerror or exc} "
                        f"({exc.filename or out}); choose another --out") from None


def _monte_carlo(data, file, seed, runs, workers, backend, scheduler, out: Path, result, metrics, notes, *,
                 figures: bool = True, meanwhile=None):
    from rovlab.sim.metrics import with_units
    from rovlab.sim.montecarlo import Progress, run_many, summarise_runs
    from rovlab.sim.output import write_json, write_monte_carlo

    seeds = list(range(seed, seed + runs))
    t0 = time.perf_counter()
    done = run_many(data, file, seeds, workers=workers, backend=backend, scheduler=scheduler,
                    progress=Progress(f"Monte Carlo {result.scenario.name}"), meanwhile=meanwhile)
    wall = time.perf_counter() - t0
    if len(done) < runs:  # Ctrl-C: run_many ended the workers and kept the runs that had finished
        print(f"\ninterrupted: {len(done)} of {runs} runs finished; writing their statistics"
              + (" and figures" if figures else "") + f" to {out}/", file=sys.stderr, flush=True)
    summary = summarise_runs(done)
    summary["wall_time_s"] = wall
    summary["runs_requested"] = runs
    summary["interrupted"] = len(done) < runs
    n_plant = len(result.columns["time_s"]) * int(result.meta["sample_time_s"] / result.meta["plant_step_s"] + 0.5)
    summary["vehicle_steps_per_s"] = len(done) * n_plant / wall if wall > 0 else None
    metrics = dict(metrics)
    metrics["monte_carlo"] = summary
    write_json(out / "metrics.json", with_units(metrics))  # the numbers first: a Ctrl-C while the figure is drawn keeps them
    write_monte_carlo(out / "monte_carlo", result.scenario.name, summary, done, result.columns["time_s"], notes=notes,
                      figures=figures)
    return summary


def _print_mc(summary: dict[str, Any]) -> None:
    n = summary["runs"]
    asked = summary.get("runs_requested", n)
    print(f"Monte Carlo: {n if n == asked else f'{n} of {asked}'} runs in {summary['wall_time_s']:.2f} s"
          + (f" ({summary['vehicle_steps_per_s'] / 1e6:.3g} M vehicle-steps/s)" if summary.get("vehicle_steps_per_s") else "")
          + (" -- interrupted (Ctrl-C): the statistics are those of the finished runs" if summary.get("interrupted") else ""))
    nees = summary.get("nees")
    if nees:
        print(f"  NEES: average {nees['mean']:.2f} for {nees['dof']} states (95 % bounds "
              f"{nees['mean_bounds'][0]:.2f}-{nees['mean_bounds'][1]:.2f}); "
              f"{100 * nees['share_inside']:.0f} % of time steps inside the per-step bounds")
        if summary.get("consistency_note"):
            print(f"    ({summary['consistency_note']})")
    deg = 180.0 / math.pi
    for key, label, unit, k in (("rms_error.z", "estimation error RMS, z", "m", 1.0),
                                ("rms_error.psi", "estimation error RMS, psi", "deg", deg),
                                ("settling_time_s.z", "settling time z", "s", 1.0),
                                ("overshoot.z", "overshoot z", "%", 100.0),
                                ("tracking_rms.x", "tracking error RMS, x", "m", 1.0),
                                ("tracking_rms.y", "tracking error RMS, y", "m", 1.0),
                                ("tracking_horizontal_max_m", "largest horizontal excursion", "m", 1.0)):
        st = summary["metrics"].get(key)
        if st and st.get("count"):
            print(f"  {label + ' [' + unit + ']':36s} mean {st['mean'] * k:.4g}  std {st['std'] * k:.3g}  "
                  f"[p5 {st['p5'] * k:.4g}, p95 {st['p95'] * k:.4g}]")


def _fmt(v: Any, k: float = 1.0, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v * k:.{digits}g}"


def _cell(values: dict[str, Any], axis: str, width: int, *, percent: bool = False) -> str:
    """A step-response cell: 'n/a' when the axis had no step, '-' when it did not settle."""
    if axis not in values:
        return f"{'n/a':>{width}s}"
    if percent:
        return f"{_fmt(values[axis], 100.0):>{width - 1}s}%"
    return f"{_fmt(values[axis]):>{width}s}"


def _print_summary(rows: list[tuple[str, dict[str, Any]]]) -> None:
    """One line per case: the estimation error (what the filter got wrong), the step response
    where the case has set-point changes, the drop-out drift and the NEES; then, for a case that
    holds or follows x/y set-points, its positioning numbers."""
    deg = 180.0 / math.pi
    steps = any(m.get("settling_time_s") is not None for _, m in rows)
    head = f"{'case':22s} {'est.err z [m]':>13s} {'est.err psi [deg]':>17s} {'est.err w [m/s]':>15s}"
    if steps:
        head += f" {'settle z [s]':>12s} {'overshoot z':>11s} {'settle psi [s]':>14s}"
    head += f" {'drop-out drift [deg]':>20s} {'NEES/dof':>9s}"
    print(head)
    unsettled = False
    for name, m in rows:
        rms = m["rms_error"]
        drift = m["dropouts"][0]["heading_drift_rad"] if m.get("dropouts") else None
        nees = m["nees"]["mean"] / m["nees"]["dof"] if m.get("nees") else None
        line = f"{name:22s} {_fmt(rms.get('z')):>13s} {_fmt(rms.get('psi'), deg):>17s} {_fmt(rms.get('w')):>15s}"
        if steps:
            settle, over = m.get("settling_time_s"), m.get("overshoot") or {}
            if settle is None:  # station keeping: no step to settle from
                line += f" {'n/a':>12s} {'n/a':>11s} {'n/a':>14s}"
            else:
                unsettled = unsettled or any(v is None for v in settle.values())
                line += (f" {_cell(settle, 'z', 12)} {_cell(over, 'z', 11, percent=True)}"
                         f" {_cell(settle, 'psi', 14)}")
        line += f" {_fmt(drift, deg):>20s} {_fmt(nees):>9s}"
        print(line)
    notes = ["est.err: RMS of estimate - truth, the filter's error (not the control error)"]
    if unsettled:
        notes.append("'-' under settle: not within 2 % of the step (at least 5 mm, 0.5 deg) before the next "
                     "set-point change or the end")
    notes.append("NEES/dof near 1: the filter's covariance matches its errors"
                 + (" (expected only where the plant is the filter's model, the observer plant)"
                    if any(m.get("plant") not in (None, "observer") for _, m in rows) else ""))
    print("(" + "; ".join(notes) + ")")
    for name, m in rows:  # dynamic positioning: how well the controller held or followed its reference
        tr, top = m.get("tracking_rms"), m.get("tracking_max") or {}
        if not tr:
            continue
        sat = _fmt((m.get("saturation") or {}).get("time_s"))
        rms_text = (f"RMS x {_fmt(tr.get('x'))} m, y {_fmt(tr.get('y'))} m, z {_fmt(tr.get('z'))} m, "
                    f"psi {_fmt(tr.get('psi'), deg)} deg")
        if m.get("task") == "station keeping":
            print(f"{name}: station keeping, truth against the controller's reference: {rms_text}; largest "
                  f"excursion horizontal {_fmt(m.get('tracking_horizontal_max_m'))} m, depth {_fmt(top.get('z'))} m, "
                  f"heading {_fmt(top.get('psi'), deg)} deg; thrusters saturated {sat} s")
        else:
            print(f"{name}: tracking, truth against the controller's reference: {rms_text}; "
                  f"thrusters saturated {sat} s")


_COMPARISONS = ("heave-buoyancy-step", "heave-payload", "heave-tether", "heave-heavy-payload")
_DEMO_CONTROLLERS = ("lqg", "lqg-matched", "mrac")  # the thesis LQG, an LQG as stiff as MRAC, MRAC (docs/mrac.md)


def _demo_comparisons(out: Path, runs: int) -> list[dict[str, Any]]:
    """MRAC against the thesis LQG and against an LQG of MRAC's stiffness on the heave scenarios
    (issues 12 and 28), for the report."""
    from rovlab.interfaces.cli_compare import run_comparison

    sections = []
    for i, name in enumerate(_COMPARISONS, 1):
        t0 = time.perf_counter()
        print(f"[compare {i}/{len(_COMPARISONS)}] {name}: {', '.join(_DEMO_CONTROLLERS)}, {runs} runs each ...",
              end="", flush=True)
        comparison, folder, notes = run_comparison(name, list(_DEMO_CONTROLLERS), runs, None,
                                                   out / f"compare-{name}", quiet=True)
        print(f" done in {time.perf_counter() - t0:.1f} s -> {folder}/")
        from rovlab.sim.compare import table

        print(table(comparison))
        for n in notes:
            print(f"  note: {n}")
        png = folder / "comparison.png"
        sections.append({"title": f"MRAC vs LQG: {name}",
                         "description": f"{comparison['description']}. {comparison['source']}. The controllers "
                                        "meet the same seeds; the error is the true depth against the MRAC "
                                        "reference model (rovlab.sim.compare). lqg is the thesis's LQG, "
                                        "lqg-matched an LQG with MRAC's stiffness and integral action (what is "
                                        "left is what adaptation buys: docs/mrac.md).",
                         "metrics": comparison, "figures": [png] if png.exists() else [],
                         "text": table(comparison),
                         "extra": f"{runs} runs per controller; files in compare-{name}/"})
    return sections


def _cmd_demo(args: argparse.Namespace) -> int:
    from rovlab.interfaces.compiling import announce_compile, loop_of
    from rovlab.io.report import write_report_html
    from rovlab.sim.scenario import load_scenario_data

    _check_counts(args)
    if args.compare_runs < 0:
        from rovlab.interfaces.cli import UserError

        raise UserError(f"--compare-runs must be >= 0, got {args.compare_runs}")
    out = Path(args.out)
    cases = ("step-observer-model", "step-process-model", "dropout")
    loops = [loop_of(*load_scenario_data(name)) for name in cases]
    if args.compare_runs > 0:
        loops += [loop_of(*load_scenario_data(name), controller=c) for name in _COMPARISONS for c in ("lqg", "mrac")]
    announce_compile(loops)
    print(f"rovlab demo: the thesis case studies (Sandøy 2016, figs. 5.2-5.4) on uDrone -> {out}/")
    sections = []
    rows = []
    for i, name in enumerate(cases, 1):
        t0 = time.perf_counter()
        print(f"[{i}/{len(cases) + 1}] {name} ...", end="", flush=True)
        data, file = load_scenario_data(name)
        compiled: list[float] = []
        result, metrics, notes = _run_and_write(data, file, None, out / name, compiled=compiled)
        print(f" done in {time.perf_counter() - t0:.1f} s" + (f" (compiling its loop {compiled[0]:.1f} s)" if compiled else "")
              + f" -> {out / name}/")
        for n in notes:
            print(f"  note: {n}")
        rows.append((name, metrics))
        figs = [out / name / f for f in ("states.png", "errors.png", "biases.png", "control.png")
                if (out / name / f).exists()]
        sections.append({"title": name, "description": f"{result.scenario.description}. {result.scenario.source}.",
                         "metrics": metrics, "figures": figs,
                         "extra": f"seed {result.scenario.seed}; details in {name}/report.html, "
                                  f"logs in {name}/timeseries.csv, timeseries.mcap (ROS 2 bag) and "
                                  f"timeseries.rovlab.mcap"})
    mc_name = "step-observer-model"
    interrupted = False
    if args.runs > 1:
        print(f"[{len(cases) + 1}/{len(cases) + 1}] filter consistency: {args.runs} Monte Carlo runs of {mc_name}")
        data, file = load_scenario_data(mc_name)
        result, metrics, notes = _run_and_write(data, file, None, out / mc_name, figures=False)
        summary = _monte_carlo(data, file, result.scenario.seed, args.runs, args.workers, "processes", None,
                               out / mc_name, result, metrics, notes)
        _print_mc(summary)
        interrupted = bool(summary.get("interrupted"))
        nees_png = out / mc_name / "monte_carlo" / "nees.png"
        ran = f"{summary['runs']}" + (f" of {args.runs} (interrupted)" if interrupted else "")
        sections.append({"title": f"Monte Carlo: {mc_name} x {ran}",
                         "description": "Average NEES over independent runs against its chi-square bounds: a "
                                        "consistent filter keeps it inside (Bar-Shalom et al. 2001, sec. 5.4).",
                         "metrics": {"nees": summary.get("nees"), "rms_error": {
                             k.split(".")[1]: v["mean"] for k, v in summary["metrics"].items()
                             if k.startswith("rms_error.")},
                             **({"consistency_note": summary["consistency_note"]}
                                if summary.get("consistency_note") else {})},
                         "figures": [nees_png] if nees_png.exists() else [],
                         "extra": f"seeds {summary['seeds'][0]}..{summary['seeds'][-1]}; {summary['wall_time_s']:.2f} s"})
    if args.compare_runs > 0 and not interrupted:  # Ctrl-C: the report of what ran, and stop
        sections += _demo_comparisons(out, args.compare_runs)
    report = write_report_html(out / "report.html", "rovlab demo: uDrone case studies", sections,
                               intro="Depth and heading LQG (Kalman filter + LQR) of uDrone, reproducing the "
                                     "simulation case studies of Sandøy (2016), ch. 5, with the numbers of "
                                     "the thesis's sec. 5.3.1.")
    print()
    _print_summary(rows)
    print(f"\nreport: {report}")
    return 130 if interrupted else 0
