"""Mutation fuzzing of every input file type (issue 15): vehicle files, design configurations,
scenarios and the virtual lab's logs (thrust staircase, towing, yaw, step/relay, resting noise).

Each mutant is fed to the ``rovlab`` command in-process, as a user would. A mutant must either be
accepted (exit 0) or refused with exit status 2 and a message naming the file and saying what was
expected -- never a traceback, another exit status, a numpy warning or LAPACK noise on the
terminal. The mutations are seeded: the normal suite runs a small fixed budget per input type;
``make test-slow`` runs a longer one (``ROVLAB_FUZZ_BUDGET`` overrides both).

The filter-log reader (``rovlab filter``) has its own fuzz test next to its reader.
"""

from __future__ import annotations

import copy
import math
import os
import random
import re
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import tomlkit

from rovlab.interfaces.cli import main
from rovlab.params.design import packaged_config_path
from rovlab.params.vehicle import packaged_vehicle_path
from rovlab.sim.scenario import resolve_scenario_path

BUDGET = int(os.environ.get("ROVLAB_FUZZ_BUDGET", "0")) or None
SMALL, LARGE = 12, 300  # mutants per input type in the normal suite / with make test-slow

# Values a fuzzer (or a typo) puts into a file: edge cases of each type, absurd magnitudes,
# subnormals, control characters.
INTERESTING: list[Any] = [
    0, -1, 1, 2**70, -(2**63), 0.0, -0.0, 1e-308, 5e-324, 1e-29, 1e-9, 1e15, -9e18, 1.8e19, 1e154, 1e308, -1e308,
    math.inf, -math.inf, math.nan, "", "x", "evil\n", "a\x00b", "１２", "1_000", True, [], [1.0], [1e308, 0, 0],
    {}, {"dist": "normal", "mean": 1.0, "std": 1e308}, {"dist": "uniform", "low": 5e-324, "high": 1e-300},
]
SCALES = [1e-300, 1e-9, 1e-3, -1.0, 0.0, 1e3, 1e9, 1e154]


def _budget(small: int) -> int:
    return BUDGET or small


# --------------------------------------------------------------------------------------------
# mutation engines
# --------------------------------------------------------------------------------------------

def _leaves(node: Any, path: tuple = ()) -> list[tuple]:
    out: list[tuple] = []
    if isinstance(node, dict):
        for k, v in node.items():
            out.append(path + (k,))
            out += _leaves(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out.append(path + (i,))
            out += _leaves(v, path + (i,))
    return out


def _get_parent(node: Any, path: tuple) -> Any:
    for p in path[:-1]:
        node = node[p]
    return node


def mutate_toml(data: dict, rnd: random.Random) -> dict:
    """One to three structural or value mutations of a parsed TOML document."""
    data = copy.deepcopy(data)
    for _ in range(rnd.randint(1, 3)):
        paths = _leaves(data)
        if not paths:
            break
        path = rnd.choice(paths)
        parent = _get_parent(data, path)
        key = path[-1]
        op = rnd.random()
        if op < 0.45:
            parent[key] = copy.deepcopy(rnd.choice(INTERESTING))
        elif op < 0.7 and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
            parent[key] = parent[key] * rnd.choice(SCALES)
        elif op < 0.8:
            if isinstance(parent, dict):
                del parent[key]
            elif isinstance(parent, list) and parent:
                parent.pop(key)
        elif op < 0.9 and isinstance(parent, dict):
            parent[rnd.choice(["extra", "name", "source", "x", "dist"])] = copy.deepcopy(rnd.choice(INTERESTING))
        elif isinstance(parent, list):
            parent.append(copy.deepcopy(parent[key]) if rnd.random() < 0.5 else rnd.choice(INTERESTING))
        else:
            parent[key] = [parent[key]]
    return data


def dump_toml(data: dict) -> str:
    return tomlkit.dumps(data)


def mutate_text(text: str, rnd: random.Random) -> str:
    """A line-level mutation (for syntax-level damage): drop, duplicate, truncate, flip a byte."""
    lines = text.splitlines()
    op = rnd.random()
    i = rnd.randrange(len(lines)) if lines else 0
    if op < 0.3 and lines:
        del lines[i]
    elif op < 0.5 and lines:
        lines.insert(i, lines[i])
    elif op < 0.7:
        return text[: rnd.randrange(len(text) + 1)]
    elif lines:
        line = lines[i]
        j = rnd.randrange(len(line) + 1)
        lines[i] = line[:j] + rnd.choice(["\x00", "=", "[", '"', "é", "\ufeff", "9e999", ","]) + line[j:]
    return "\n".join(lines) + "\n"


def mutate_csv(text: str, rnd: random.Random) -> str:
    """Mutations of a numeric CSV log: scale or offset a column, odd cells, row damage."""
    lines = text.splitlines()
    comments = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    header, rows = body[0].split(","), [r.split(",") for r in body[1:]]
    for _ in range(rnd.randint(1, 2)):
        op = rnd.random()
        col = rnd.randrange(len(header))
        if op < 0.35 and rows:  # a column scaled (times or positions x 1e-300 ... 1e154)
            k = rnd.choice(SCALES)
            for r in rows:
                if col < len(r):
                    try:
                        r[col] = repr(float(r[col]) * k)
                    except ValueError:
                        pass
        elif op < 0.5 and rows:  # one odd cell
            r = rnd.choice(rows)
            if col < len(r):
                r[col] = rnd.choice(["1_000", "１２", "1e400", "nan", "", "abc", "0x10", "-0", "1e-320", "1e18",
                                     " 7 ", "+inf", "1,5"])
        elif op < 0.6 and rows:  # a huge gap in time, or a jump in a value
            i = rnd.randrange(len(rows))
            for r in rows[i:]:
                if col < len(r):
                    try:
                        r[col] = repr(float(r[col]) + rnd.choice([1e8, 1e18, -5.0]))
                    except ValueError:
                        pass
        elif op < 0.7:  # keep only a few rows
            rows = rows[: rnd.choice([0, 1, 2, 3, 10])]
        elif op < 0.8 and rows:  # a constant column
            v = rows[0][col] if col < len(rows[0]) else "0"
            for r in rows:
                if col < len(r):
                    r[col] = v
        elif op < 0.85:  # rename or drop a column
            if rnd.random() < 0.5:
                header[col] = rnd.choice(["", "time_s", "x", "pwm_us", "force_n"])
            else:
                header.pop(col)
                for r in rows:
                    if col < len(r):
                        r.pop(col)
        elif op < 0.92 and rows:  # shuffled or reversed rows
            if rnd.random() < 0.5:
                rnd.shuffle(rows)
            else:
                rows.reverse()
        else:
            return mutate_text(text, rnd)
    return "\n".join(comments + [",".join(header)] + [",".join(r) for r in rows]) + "\n"


# --------------------------------------------------------------------------------------------
# the oracle
# --------------------------------------------------------------------------------------------

def run_cli(argv: list[str], capfd) -> tuple[int, str, str]:
    """Run ``rovlab argv`` in-process; any escaping exception (a traceback) fails the test."""
    capfd.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse: usage errors exit 2
        code = exc.code if isinstance(exc.code, int) else 2
    out, err = capfd.readouterr()
    return code, out, err


def check_outcome(argv: list[str], path: Path, capfd, *, mutant: str, needs_expected: bool = True) -> int:
    code, out, err = run_cli(argv, capfd)
    context = f"rovlab {' '.join(argv)}\n--- mutant ---\n{mutant[:3000]}\n--- stderr ---\n{err[-3000:]}"
    assert code in (0, 2), f"exit status {code}\n{context}"
    assert "Traceback" not in err, context
    for noise in ("LAPACK", "** On entry", "RuntimeWarning", "DLASCL", "DGESDD"):
        assert noise not in out + err, context
    if code == 2:
        text = err + out
        # the file at fault: the mutant, or for a cross-file problem (a vehicle that lacks what the
        # configuration asks for) the other file, named with its key
        names_file = str(path) in text or path.name in text or (
            path.suffix == ".toml" and re.search(r"\.toml: [\w\[\]().=-]+:", text) is not None)
        assert names_file, f"the refusal does not name the file\n{context}"
        if needs_expected:
            assert "expected" in text or "expect" in text, f"the refusal does not say what was expected\n{context}"
    return code


# --------------------------------------------------------------------------------------------
# TOML inputs
# --------------------------------------------------------------------------------------------

def _fuzz_toml(base: Path, n: int, seed: int, tmp_path: Path, capfd, argv_for: Callable[[Path], list[list[str]]]):
    text = base.read_text(encoding="utf-8")
    data = tomllib.loads(text)
    rnd = random.Random(seed)
    accepted = 0
    for i in range(n):
        if rnd.random() < 0.8:
            try:
                mutant = dump_toml(mutate_toml(data, rnd))
            except Exception:  # tomlkit cannot write every Python value (e.g. a NUL key): skip
                continue
        else:
            mutant = mutate_text(text, rnd)
        path = tmp_path / f"mutant{i}.toml"
        path.write_text(mutant, encoding="utf-8", errors="surrogatepass")
        for argv in argv_for(path):
            if check_outcome(argv, path, capfd, mutant=mutant) != 0:
                break
        else:
            accepted += 1
    return accepted


def _vehicle_argv(path: Path, config: str = "default") -> list[list[str]]:
    return [["vehicle", "check", str(path)], ["vehicle", "show", str(path), "--json"],
            ["design", "--vehicle", str(path), "--config", config, "--allow-unobservable"]]


def _config_argv(path: Path) -> list[list[str]]:
    return [["design", "--config", str(path), "--json"]]


@pytest.mark.parametrize("seed", [1])
def test_fuzz_vehicle_files(tmp_path, capfd, seed):
    _fuzz_toml(packaged_vehicle_path("udrone"), _budget(SMALL), seed, tmp_path, capfd, _vehicle_argv)


@pytest.mark.parametrize("seed", [2])
def test_fuzz_design_configurations(tmp_path, capfd, seed):
    _fuzz_toml(packaged_config_path("thesis"), _budget(SMALL), seed, tmp_path, capfd, _config_argv)


def _short_scenario(tmp_path: Path) -> Path:
    """The dropout scenario shortened to 3 s (drop-out 1-2 s) so that accepted mutants run fast."""
    text = resolve_scenario_path("dropout").read_text(encoding="utf-8")
    text = (text.replace("duration_s = 60.0", "duration_s = 3.0").replace("t_s = 22.0", "t_s = 1.5")
            .replace("start_s = 20.0", "start_s = 1.0").replace("end_s = 40.0", "end_s = 2.0"))
    path = tmp_path / "short.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _scenario_argv(tmp_path: Path) -> Callable[[Path], list[list[str]]]:
    def argv(path: Path) -> list[list[str]]:
        try:  # run only mutants that stay short (a mutated duration of 1e5 s is valid, just slow)
            data = tomllib.loads(path.read_text(encoding="utf-8"))
            duration = float(data.get("duration_s", 0.0))
            step = float(data.get("plant_step_s", 0.01))
            short = duration <= 5.0 and step >= 1e-3
        except Exception:
            short = True
        if not short:
            return [["scenarios"]]  # loading is checked by the scenario's own tests below
        return [["simulate", str(path), "--out", str(tmp_path / "out"), "--no-figures"]]
    return argv


@pytest.mark.parametrize("seed", [3])
def test_fuzz_scenarios(tmp_path, capfd, seed):
    base = _short_scenario(tmp_path)
    _fuzz_toml(base, _budget(SMALL), seed, tmp_path, capfd, _scenario_argv(tmp_path))


@pytest.mark.parametrize("seed", [4])
def test_fuzz_scenario_loading(tmp_path, seed):
    """The loader alone (fast, so more mutants): a ConfigError naming the file, or a Scenario."""
    from rovlab.params.validate import ConfigError
    from rovlab.sim.scenario import load_scenario

    base = _short_scenario(tmp_path)
    data = tomllib.loads(base.read_text(encoding="utf-8"))
    rnd = random.Random(seed)
    for i in range(4 * _budget(SMALL)):
        try:
            mutant = dump_toml(mutate_toml(data, rnd))
        except Exception:
            continue
        path = tmp_path / f"load{i}.toml"
        path.write_text(mutant, encoding="utf-8")
        try:
            sc = load_scenario(path)
        except ConfigError as exc:
            assert exc.problems and all(str(path) in str(p) and "expected" in str(p) for p in exc.problems), exc
            continue
        assert sc.duration_s / sc.plant_step_s <= 1e7
        assert all(math.isfinite(x) for x in sc.initial)


# --------------------------------------------------------------------------------------------
# lab logs
# --------------------------------------------------------------------------------------------

LAB = {
    # experiment: (lab arguments, identify arguments after the file)
    "thrust": (["--pwm-step", "50", "--step-s", "8", "--rate-hz", "20"], ["--window", "4"]),
    "towing": (["--dof", "heave", "--speeds", "0.1,-0.1,0.3,-0.3,0.5,-0.5", "--hold-s", "8"], ["--dof", "heave"]),
    "yaw": (["--moments", "0.25,0.5,1,2", "--duration-s", "15"], []),
    "step": (["--duration-s", "30"], ["--mass", "7.31"]),
    "noise": (["--samples", "400"], []),
}


@pytest.fixture(scope="module")
def lab_logs(tmp_path_factory) -> dict[str, str]:
    folder = tmp_path_factory.mktemp("lab")
    out = {}
    for name, (lab_args, _) in LAB.items():
        path = folder / f"{name}.csv"
        assert main(["lab", name, "--seed", "7", "--out", str(path), *lab_args]) == 0
        out[name] = path.read_text(encoding="utf-8")
    return out


@pytest.mark.parametrize("experiment", list(LAB))
def test_fuzz_lab_logs(tmp_path, capfd, lab_logs, experiment):
    text = lab_logs[experiment]
    rnd = random.Random(f"lab-{experiment}")
    for i in range(_budget(SMALL)):
        mutant = mutate_csv(text, rnd)
        path = tmp_path / f"{experiment}{i}.csv"
        path.write_text(mutant, encoding="utf-8", errors="surrogatepass")
        argv = ["identify", experiment, str(path), "--no-plot", "--json", *LAB[experiment][1]]
        check_outcome(argv, path, capfd, mutant=mutant, needs_expected=False)


# --------------------------------------------------------------------------------------------
# the longer runs (make test-slow)
# --------------------------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("seed", [101, 102])
def test_fuzz_long(tmp_path, capfd, lab_logs, seed, monkeypatch):
    n = BUDGET or LARGE
    _fuzz_toml(packaged_vehicle_path("bluerov2_heavy"), n, seed, tmp_path, capfd,
               lambda path: _vehicle_argv(path, "bluerov2_heavy"))
    _fuzz_toml(packaged_config_path("default"), n, seed, tmp_path, capfd, _config_argv)
    _fuzz_toml(_short_scenario(tmp_path), n // 3, seed, tmp_path, capfd, _scenario_argv(tmp_path))
    for experiment, text in lab_logs.items():
        rnd = random.Random(f"lab-{experiment}-{seed}")
        for i in range(n):
            mutant = mutate_csv(text, rnd)
            path = tmp_path / f"{experiment}{i}.csv"
            path.write_text(mutant, encoding="utf-8", errors="surrogatepass")
            argv = ["identify", experiment, str(path), "--no-plot", "--json", *LAB[experiment][1]]
            check_outcome(argv, path, capfd, mutant=mutant, needs_expected=False)
