"""`rovlab hmi`: prints its address, serves the page, stops cleanly on Ctrl-C writing the log."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import urllib.request

from rovlab.interfaces.cli import main


def test_bad_arguments_are_user_errors(capsys, tmp_path):
    assert main(["hmi", "--port", "70000", "--out", str(tmp_path)]) == 2
    assert "--port" in capsys.readouterr().err
    assert main(["hmi", "--speed", "0", "--port", "0", "--out", str(tmp_path)]) == 2
    assert main(["hmi", "--scenario", "no-such-scenario", "--port", "0", "--out", str(tmp_path)]) == 2
    assert "packaged scenario name" in capsys.readouterr().err


def test_start_serve_and_stop_with_ctrl_c(tmp_path):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "rovlab.interfaces.cli", "hmi", "--port", "0", "--speed", "10",
                             "--out", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    try:
        url = None
        deadline = time.monotonic() + 120
        while url is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            m = re.search(r"http://127\.0\.0\.1:\d+/", line)
            url = m.group(0) if m else None
        assert url, proc.stderr.read()
        with urllib.request.urlopen(url, timeout=10) as r:
            assert b"rovlab HMI" in r.read()
        time.sleep(0.5)  # let it log a few steps
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    logs = sorted(p.name for p in tmp_path.glob("session-*.csv"))
    assert len(logs) == 1 and str(tmp_path) in err  # the log's path is printed
    assert (tmp_path / logs[0]).read_text().count("\n") > 2


def test_a_busy_port_writes_no_empty_session_log(capsys, tmp_path):
    # issue 15: the error came after an empty session log had been written
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        assert main(["hmi", "--port", str(port), "--paused", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"cannot listen on 127.0.0.1:{port}" in err and "--port 0" in err
    assert list(tmp_path.iterdir()) == []  # no session log, no events file
