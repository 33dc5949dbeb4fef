"""Every ``rovlab ...`` command in README.md and docs/*.md parses with the command's own argparse
parser (issue 28, a new user: docs said ``rovlab hmi dp-square`` for ``rovlab hmi --scenario
dp-square`` and ``rovlab filter --log`` for an option that does not exist). Nothing is run: the
parser only reads the words.

* A line of a code block that starts with ``rovlab`` (continued by a trailing backslash) must
  parse completely. Synopsis notation is read as a reader would: ``[...]`` is optional and taken
  in, ``a|b`` takes ``a``, ``...`` and ``VALUE`` placeholders stand for values (a placeholder in
  capitals where a number is expected is given as 1).
* An inline code span that starts with ``rovlab`` is a mention, which may leave out what the
  command requires; its sub-command and every option it names must exist.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from rovlab.interfaces.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^\s*(```|~~~)")
INLINE = re.compile(r"`(rovlab [^`]+)`")
_BAD_VALUE = re.compile(r"(?:invalid \w+ value: |got )'([A-Z][A-Z0-9_]*)'")  # argparse's, or a type's own


def _code_commands(text: str) -> list[tuple[int, str]]:
    """(line number, command) of every rovlab command line in the file's code blocks."""
    out: list[tuple[int, str]] = []
    inside = False
    pending: tuple[int, str] | None = None
    for number, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            inside = not inside
            pending = None
            continue
        if not inside:
            continue
        stripped = line.strip()
        if pending is not None:
            start, so_far = pending
            so_far += " " + stripped.rstrip("\\").strip()
            pending = (start, so_far) if stripped.endswith("\\") else None
            if pending is None:
                out.append((start, so_far))
            continue
        stripped = re.sub(r"^\$\s+", "", stripped)
        if stripped.startswith("rovlab ") or stripped == "rovlab":
            if stripped.endswith("\\"):
                pending = (number, stripped.rstrip("\\").strip())
            else:
                out.append((number, stripped))
    return out


def _inline_commands(text: str) -> list[tuple[int, str]]:
    out = []
    inside = False
    for number, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            inside = not inside
            continue
        if not inside:
            out.extend((number, m.group(1)) for m in INLINE.finditer(line))
    return out


def _words(command: str) -> list[str]:
    """The arguments after ``rovlab``, synopsis notation resolved (see the module docstring)."""
    command = command.split(" #", 1)[0]  # a shell comment
    command = re.split(r"\s(?:&&|;|\|(?=\s))\s", command, maxsplit=1)[0]  # the first command of a chain
    command = command.rstrip(" &")
    command = re.sub(r"(\S+)\|\S+", lambda m: m.group(1).split("|")[0], command)  # a|b|c -> a
    command = command.replace("[", " ").replace("]", " ")
    command = re.sub(r"(?<!\S)(-[\w-]+)\s+\.\.\.?(?!\S)", r"\1 VALUE", command)  # "--config ...": any value
    command = command.replace("...", " ")  # "SCENARIO...": one or more; "node|sim ...": and its options
    words = shlex.split(command)
    assert words[0] == "rovlab"
    return words[1:]


def _parse(parser: argparse.ArgumentParser, words: list[str]) -> tuple[int, str]:
    """(exit status, stderr) of parsing ``words``; placeholders in capitals where a number is
    expected become 1, one at a time."""
    for _ in range(12):
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                parser.parse_args(words)
        except SystemExit as exc:
            message = err.getvalue()
            bad = _BAD_VALUE.search(message)
            if bad and bad.group(1) in words:
                words = [("1" if w == bad.group(1) else w) for w in words]
                continue
            return int(exc.code or 0), message
        return 0, ""
    return 2, "too many placeholders"


def _commands() -> list[tuple[str, int, str, bool]]:
    out = []
    for path in FILES:
        text = path.read_text(encoding="utf-8")
        rel = str(path.relative_to(ROOT))
        out.extend((rel, n, c, True) for n, c in _code_commands(text))
        out.extend((rel, n, c, False) for n, c in _inline_commands(text))
    return out


COMMANDS = _commands()


def test_the_documents_have_commands_to_check():
    blocks = [c for c in COMMANDS if c[3]]
    assert len(blocks) > 60 and {c[0] for c in blocks} >= {"README.md", "docs/identification.md",
                                                             "docs/simulation.md", "docs/mavlink.md"}


@pytest.fixture(scope="module")
def parser() -> argparse.ArgumentParser:
    return build_parser()


def test_every_documented_command_parses(parser):
    problems = []
    for file, line, command, complete in COMMANDS:
        words = _words(command)
        if any(w in ("-h", "--help") for w in words):
            continue
        status, message = _parse(parser, words)
        if status == 0:
            continue
        if not complete and "the following arguments are required" in message:
            continue  # a mention in the prose, not a command to copy
        last = message.strip().splitlines()[-1] if message.strip() else f"exit {status}"
        problems.append(f"{file}:{line}: {command}\n    -> {last}")
    assert not problems, "documented commands the parser refuses:\n" + "\n".join(problems)


@pytest.mark.parametrize("command, complete", [
    ("rovlab hmi dp-square", True),  # the HMI takes its scenario as --scenario
    ("rovlab filter --log run.mcap --out est.csv", True),  # no such option
    ("rovlab simulate dp-square --no-such-flag", False),
])
def test_the_check_refuses_what_the_parser_refuses(parser, command, complete):
    status, message = _parse(parser, _words(command))
    assert status == 2 and ("unrecognized arguments" in message or "invalid choice" in message), message


def test_synopsis_notation_is_read_as_a_reader_would():
    assert _words("rovlab vehicle show [udrone|FILE] [--json]   # parameters") == ["vehicle", "show", "udrone", "--json"]
    assert _words("rovlab compile SCENARIO... | --all") == ["compile", "SCENARIO"]
    assert _words("rovlab filter LOG.csv [--config ...]") == ["filter", "LOG.csv", "--config", "VALUE"]
    assert _words("rovlab ros1 node|sim ...   # the same on ROS 1") == ["ros1", "node"]
    assert _words("rovlab mavlink sim --depth 1 &") == ["mavlink", "sim", "--depth", "1"]


def test_readme_python_example_runs_with_the_hull_under_water():
    """The README's Python example, as written: it placed the hull at z = 0, the free surface,
    where half of it is out of the water (buoyancy and heave added mass halved) without saying so."""
    from rovlab.params import load_vehicle

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    code = re.search(r"## Python\n\n```python\n(.*?)```", text, re.S).group(1)
    scope: dict = {}
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(code, "README.md (Python)", "exec"), scope)
    v = load_vehicle("udrone")
    assert scope["eta"][2] > v.geometry.height  # below the surface, with margin
    assert scope["acc"][2] < 0 and v.buoyancy > v.weight  # what its comment says: it floats up


def test_readme_vehicle_list_names_packaged_vehicles():
    from rovlab.params.vehicle import packaged_vehicle_names

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    line = next(line for line in text.splitlines() if line.startswith("rovlab vehicle list"))
    named = re.findall(r"[a-z][a-z0-9]*_?[a-z0-9_]*", line.split("(", 1)[1])
    assert named and set(named) <= set(packaged_vehicle_names()), line
