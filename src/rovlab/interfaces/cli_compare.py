"""Sub-command ``compare``: one scenario run with several controllers from the same seeds
(comparison.json, a text table and an overlay figure). Interfaces hold no maths: the runs and
the numbers are rovlab.sim.compare's."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def register(sub: argparse._SubParsersAction) -> None:
    cmp = sub.add_parser("compare", help="run a scenario with several controllers from the same seeds "
                                         "(e.g. MRAC against LQG)")
    cmp.add_argument("scenario", help="packaged scenario name or TOML path (rovlab scenarios lists them)")
    cmp.add_argument("--controllers", default="lqg,lqg-matched,mrac",
                     help="comma-separated controller names or comparison variants: lqg-matched (the LQG as "
                          "stiff as MRAC), mrac-f-only (MRAC adapting the net force only); default "
                          "lqg,lqg-matched,mrac")
    cmp.add_argument("--runs", type=int, default=1, help="runs per controller (seeds seed .. seed+N-1)")
    cmp.add_argument("--seed", type=int, default=None, help="first seed (default: the scenario's)")
    cmp.add_argument("--out", default=None, help="output folder (default: out/compare-<scenario>)")
    cmp.add_argument("--no-figure", action="store_true", help="skip the overlay figure")
    cmp.set_defaults(func=_cmd_compare)


def run_comparison(scenario: str, controllers: list[str], runs: int, seed: int | None, out: Path | None, *,
                   figure: bool = True, quiet: bool = False) -> tuple[dict[str, Any], Path, list[str]]:
    """Run, write DIR/comparison.json, comparison.txt and comparison.png; returns (comparison, DIR, notes)."""
    from rovlab.interfaces.cli import UserError
    from rovlab.sim.compare import compare, component_of, controller_names, table
    from rovlab.sim.compare import figure as draw
    from rovlab.sim.montecarlo import Progress
    from rovlab.sim.output import write_json
    from rovlab.sim.scenario import load_scenario_data

    known = controller_names()  # the controller components and rovlab.sim.compare's variants
    unknown = [c for c in controllers if c not in known]
    if not controllers or unknown:
        raise UserError(f"--controllers: unknown {', '.join(unknown) or '(none given)'}; expected a comma-separated "
                        "list of: " + ", ".join(known))
    if len(set(controllers)) != len(controllers):
        raise UserError(f"--controllers: each controller at most once, got {','.join(controllers)}")
    if runs < 1:
        raise UserError(f"--runs must be at least 1, got {runs}")
    if seed is not None and seed < 0:
        raise UserError(f"--seed must be >= 0, got {seed}")
    data, file = load_scenario_data(scenario)
    name = str(data.get("name") or Path(file).stem)
    if not quiet:
        from rovlab.interfaces.compiling import announce_compile, loop_of

        announce_compile([loop_of(data, file, controller=component_of(c)) for c in controllers])
    out = Path(out) if out is not None else Path("out") / f"compare-{name}"
    first = seed if seed is not None else int(data.get("seed", 0)) if isinstance(data.get("seed", 0), int) else 0
    seeds = list(range(first, first + runs))
    progress = None if quiet or runs * len(controllers) < 4 else Progress(f"compare {name}")
    comparison, kept = compare(data, file, controllers, seeds, progress=progress)
    from rovlab.core.files import atomic_write_text

    notes: list[str] = []
    try:  # each file whole or not at all (a full disk: the message, no partial file)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "comparison.json", comparison)
        atomic_write_text(out / "comparison.txt", table(comparison) + "\n")
        if figure:
            try:
                draw(out / "comparison.png", comparison, kept)
            except ImportError:
                notes.append("no figure: matplotlib is not installed (pip install 'rovlab[plot]')")
    except OSError as exc:
        raise UserError(f"cannot write the comparison to {out}/: {exc.strerror or exc}; choose another --out") from None
    return comparison, out, notes


def _cmd_compare(args: argparse.Namespace) -> int:
    controllers = [c.strip() for c in str(args.controllers).split(",") if c.strip()]
    comparison, out, notes = run_comparison(args.scenario, controllers, args.runs, args.seed,
                                            Path(args.out) if args.out else None, figure=not args.no_figure)
    from rovlab.sim.compare import table

    print(table(comparison))
    print(f"-> {out}/comparison.json, comparison.txt" + ("" if args.no_figure or notes else ", comparison.png"))
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    return 0
