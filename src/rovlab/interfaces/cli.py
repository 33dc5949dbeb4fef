"""The ``rovlab`` command. Each sub-command lives in its own module with a ``register``
function; this file only assembles them and turns user errors into clean messages."""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

# Modules providing sub-commands: each has register(subparsers) -> None.
_COMMAND_MODULES = (
    "rovlab.interfaces.cli_vehicle",
    "rovlab.interfaces.cli_ident",
    "rovlab.interfaces.cli_sim",
    "rovlab.interfaces.cli_design",
    "rovlab.interfaces.cli_hmi",
    "rovlab.interfaces.cli_compare",
)


class UserError(Exception):
    """An error caused by the user's input: printed without a traceback, exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rovlab",
        description="Model, identify, estimate, control and simulate small underwater vehicles.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from rovlab.params.validate import ConfigError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ConfigError, UserError) as exc:
        print(f"rovlab {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rovlab {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
