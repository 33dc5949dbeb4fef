"""``rovlab ... | head``: a reader that goes away ends the command quietly, status 0. A handler
for full disks (except OSError) placed before the one for BrokenPipeError (an OSError too) made
every such pipe print a traceback (found while checking issue 28's documented commands)."""

from __future__ import annotations

import os
import subprocess
import sys


def test_a_closed_pipe_ends_the_command_quietly():
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first line is written
    try:
        res = subprocess.run([sys.executable, "-m", "rovlab.interfaces.cli", "vehicle", "show", "udrone"],
                             stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert res.returncode == 0 and res.stderr == "", res.stderr
