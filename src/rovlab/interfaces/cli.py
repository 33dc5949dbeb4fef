"""The ``rovlab`` command. Each sub-command lives in its own module with a ``register``
function; this file only assembles them and turns user errors into clean messages."""

from __future__ import annotations

import argparse
import errno
import gc
import importlib
import os
import sys
from collections.abc import Sequence

# Modules providing sub-commands: each has register(subparsers) -> None.
_COMMAND_MODULES = (
    "rovlab.interfaces.cli_vehicle",
    "rovlab.interfaces.cli_ident",
    "rovlab.interfaces.cli_sim",
    "rovlab.interfaces.cli_design",
    "rovlab.interfaces.cli_hmi",
    "rovlab.interfaces.cli_compare",
    "rovlab.interfaces.cli_ros",
    "rovlab.interfaces.cli_mavlink",
)


# Which module provides each sub-command, so that a command imports only its own module (a
# one-shot command should not pay for the HMI's asyncio or the identification tools). A command
# missing here still works: the full parser is built (tests check that this table is complete).
_COMMAND_MODULE = {
    "vehicle": "rovlab.interfaces.cli_vehicle",
    "thruster": "rovlab.interfaces.cli_vehicle",
    "allocate": "rovlab.interfaces.cli_vehicle",
    "identify": "rovlab.interfaces.cli_ident",
    "added-mass": "rovlab.interfaces.cli_ident",
    "lab": "rovlab.interfaces.cli_ident",
    "simulate": "rovlab.interfaces.cli_sim",
    "scenarios": "rovlab.interfaces.cli_sim",
    "compile": "rovlab.interfaces.cli_sim",
    "demo": "rovlab.interfaces.cli_sim",
    "design": "rovlab.interfaces.cli_design",
    "filter": "rovlab.interfaces.cli_design",
    "hmi": "rovlab.interfaces.cli_hmi",
    "compare": "rovlab.interfaces.cli_compare",
    "ros2": "rovlab.interfaces.cli_ros",
    "ros1": "rovlab.interfaces.cli_ros",
    "mavlink": "rovlab.interfaces.cli_mavlink",
}


class UserError(Exception):
    """An error caused by the user's input: printed without a traceback, exit status 2."""


def build_parser(modules: Sequence[str] = _COMMAND_MODULES) -> argparse.ArgumentParser:
    """The ``rovlab`` parser with the sub-commands of ``modules`` (default: all)."""
    parser = argparse.ArgumentParser(
        prog="rovlab",
        description="Model, identify, estimate, control and simulate small underwater vehicles.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in modules:
        importlib.import_module(name).register(sub)
    return parser


def _parser_for(argv: Sequence[str]) -> argparse.ArgumentParser:
    """Only the module of the command named first (all of them for --help or an unknown one)."""
    command = next((a for a in argv if not a.startswith("-")), None)
    if command in _COMMAND_MODULE and not any(a in ("-h", "--help") for a in argv[:argv.index(command)]):
        return build_parser((_COMMAND_MODULE[command],))
    return build_parser()


# errno values of a file system that refuses a write: full, over quota, file too large, read-only, I/O
_FILESYSTEM_REFUSALS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO})


def main(argv: Sequence[str] | None = None) -> int:
    """The ``rovlab`` command: ``argv`` (default: this process's command line)."""
    from rovlab.params.validate import ConfigError

    command_line = argv is None  # the rovlab command itself, not a call from a script or notebook
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = _parser_for(argv)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ConfigError, UserError) as exc:
        print(f"rovlab {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rovlab {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went away (rovlab ... | head): nothing more to say
        if command_line:  # and nothing at exit either: Python's flush of stdout would fail again
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # (after BrokenPipeError, an OSError too)
        if exc.errno not in _FILESYSTEM_REFUSALS:
            raise
        # a write the commands do not catch themselves: the disk or the file system said no
        # (the atomic writers leave no partial file: rovlab.core.files)
        what = str(exc.filename) if exc.filename else "its output"
        print(f"rovlab {args.command}: error: cannot write {what}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    finally:
        if command_line:
            # The process ends now: move what it made (numba's ~100 000 objects) out of the garbage
            # collector's sight, so that the interpreter's final collection does not walk them all
            # (0.13 s of every command that ran a compiled kernel, measured on the 2-core machine).
            gc.freeze()


if __name__ == "__main__":  # pragma: no cover
    # `python -m rovlab.interfaces.cli`: run the imported module's main, whose UserError is the
    # class the sub-commands raise (this __main__ copy has its own, which would not catch it)
    from rovlab.interfaces.cli import main as _main

    sys.exit(_main())
