"""A disk that fills, or Ctrl-C, while a command writes its output (issue 28, fuzzing campaign):
`rovlab filter` printed a traceback from its writer thread and left a half-written `.tmp` and a
`.json` sidecar for a CSV that did not exist; Ctrl-C left the sidecar without the CSV;
`rovlab identify --plot` on a full disk left a 0-byte PNG. Now: exit status 2 with the file and the
reason (130 for Ctrl-C), no temporary file, and the files of an earlier run untouched.

A full disk is simulated two ways without root: in-process, the atomic writer's fsync raising
ENOSPC (rovlab.core.files, as tests/ident/test_cli_ident.py does); in a child process, a file-size
limit (RLIMIT_FSIZE, SIGXFSZ ignored), so the real writes fail part-way with EFBIG, in the writer
thread, as on a disk that fills."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from rovlab.interfaces.cli import main


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    """A simulation's timeseries.csv (601 rows of step-observer-model) as the filter's input."""
    folder = tmp_path_factory.mktemp("log")
    assert main(["simulate", "step-observer-model", "--out", str(folder / "run"), "--no-figures"]) == 0
    return folder / "run" / "timeseries.csv"


def _earlier_run(folder: Path) -> dict[str, bytes]:
    """The output of an earlier run, to check that a failed one leaves it as it was."""
    (folder / "est.csv").write_text("time_s\n0\n", encoding="utf-8")
    (folder / "est.csv.json").write_text('{"what": "an earlier run"}\n', encoding="utf-8")
    return _files(folder)


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_filter_on_a_full_disk_at_the_end(tmp_path, capsys, monkeypatch, log):
    import rovlab.core.files as files

    out = tmp_path / "out"
    out.mkdir()
    before = _earlier_run(out)

    def full_disk(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(files.os, "fsync", full_disk)
    code = main(["filter", str(log), "--out", str(out / "est.csv")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert f"cannot write {out / 'est.csv'}: No space left on device" in err, err
    assert _files(out) == before  # no .tmp, the earlier CSV and its sidecar as they were


def test_ctrl_c_during_filter_leaves_the_earlier_output(tmp_path, capsys, monkeypatch, log):
    from rovlab.estimation import streaming

    out = tmp_path / "out"
    out.mkdir()
    before = _earlier_run(out)
    feed = streaming.StreamingFilter.feed
    calls = []

    def interrupted(self, *a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return feed(self, *a, **k)

    monkeypatch.setattr(streaming.StreamingFilter, "feed", interrupted)
    code = main(["filter", str(log), "--out", str(out / "est.csv")])
    err = capsys.readouterr().err
    assert code == 130 and "interrupted" in err and "Traceback" not in err, err
    assert len(calls) == 2  # it was interrupted while writing, after a first chunk
    assert _files(out) == before


def test_filter_writes_its_csv_and_sidecar_together(tmp_path, capsys, log):
    out = tmp_path / "out"
    out.mkdir()
    assert main(["filter", str(log), "--out", str(out / "est.csv")]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["est.csv", "est.csv.json"]


def _limited(code: str, limit: int, cwd: Path) -> subprocess.CompletedProcess:
    """Run Python ``code`` with files limited to ``limit`` bytes (writes beyond fail with EFBIG)."""
    prelude = ("import resource, signal, sys\n"
               "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
               f"resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))\n")
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run([sys.executable, "-c", prelude + code], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=600)


def test_filter_when_the_disk_fills_while_the_writer_thread_writes(tmp_path, log):
    out = tmp_path / "out"
    out.mkdir()
    before = _earlier_run(out)
    # 601 rows of about 300 bytes: the limit is reached part-way, in the writer thread
    res = _limited(f"from rovlab.interfaces.cli import main\nsys.exit(main(['filter', {str(log)!r}, "
                   f"'--out', {str(out / 'est.csv')!r}]))", 40_000, tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert f"cannot write {out / 'est.csv'}: File too large" in res.stderr, res.stderr
    assert _files(out) == before


def test_identify_plot_on_a_full_disk_leaves_no_empty_figure(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    lab = tmp_path / "rest.csv"
    assert main(["lab", "noise", "--seed", "3", "--samples", "300", "--out", str(lab)]) == 0
    png = tmp_path / "fig" / "noise.png"
    png.parent.mkdir()
    png.write_bytes(b"an earlier figure")
    res = _limited(f"from rovlab.interfaces.cli import main\nsys.exit(main(['identify', 'noise', {str(lab)!r}, "
                   f"'--plot', {str(png)!r}]))", 2_000, tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert f"cannot write the figure {png}" in res.stderr, res.stderr
    assert sorted(p.name for p in png.parent.iterdir()) == ["noise.png"]
    assert png.read_bytes() == b"an earlier figure"


def test_compare_on_a_full_disk_leaves_no_partial_file(tmp_path):
    """rovlab compare wrote comparison.json with a plain write (300 bytes of it, then a traceback)."""
    out = tmp_path / "cmp"
    res = _limited("from rovlab.interfaces.cli import main\nsys.exit(main(['compare', 'heave-buoyancy-step', "
                   f"'--controllers', 'lqg', '--runs', '1', '--out', {str(out)!r}, '--no-figure']))", 300, tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert f"cannot write the comparison to {out}/: File too large" in res.stderr, res.stderr
    assert not out.exists() or list(out.iterdir()) == []


def test_an_uncaught_write_failure_is_a_message_not_a_traceback(capsys, monkeypatch):
    """The last net in rovlab.interfaces.cli.main: a command that does not catch a full disk itself."""
    from rovlab.interfaces import cli_vehicle

    def full(args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "somewhere.csv")

    monkeypatch.setattr(cli_vehicle, "_cmd_list", full, raising=True)
    parser_calls = main(["vehicle", "list"])
    err = capsys.readouterr().err
    assert parser_calls == 2 and "rovlab vehicle: error: cannot write somewhere.csv: No space left on device" in err
    assert "Traceback" not in err
