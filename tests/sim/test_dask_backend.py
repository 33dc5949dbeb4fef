"""Monte Carlo on Dask (issue 15, item 4): a local cluster of worker processes and a scheduler
started by the test, on 127.0.0.1, bounded in time. The runs must equal the process pool's."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.sim.montecarlo import run_many
from rovlab.sim.scenario import load_scenario_data

pytest.importorskip("dask.distributed")

SEEDS = [3, 4, 5]


@pytest.fixture(scope="module")
def reference():
    data, file = load_scenario_data("step-observer-model")
    return data, file, run_many(data, file, SEEDS, workers=1)


def _same(a, b):
    assert [r["seed"] for r in a] == [r["seed"] for r in b] == SEEDS
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x["nees"], y["nees"])
        assert x["metrics"]["rms_error"] == y["metrics"]["rms_error"]


def test_local_cluster_of_processes(reference):
    data, file, ref = reference
    done = []
    out = run_many(data, file, SEEDS, backend="dask", progress=lambda d, n: done.append((d, n)))
    _same(out, ref)
    assert done[-1] == (3, 3)


def test_pointed_at_a_running_scheduler_by_address(reference):
    """What `--scheduler tcp://host:8786` does with a real cluster: a scheduler and worker
    processes started here (on 127.0.0.1), reached only through their address."""
    from dask.distributed import LocalCluster

    data, file, ref = reference
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert address.startswith("tcp://127.0.0.1:")
        out = run_many(data, file, SEEDS, backend="dask", scheduler=address)
    _same(out, ref)


def test_without_dask_simulate_refuses_before_running(tmp_path, monkeypatch):
    from rovlab.interfaces.cli import main
    from rovlab.sim import montecarlo

    monkeypatch.setattr(montecarlo, "dask_available", lambda: False)
    out = tmp_path / "run"
    assert main(["simulate", "step-observer-model", "--runs", "3", "--backend", "dask", "--out", str(out)]) == 2
    assert not out.exists()  # nothing was run or written
