"""Issue 16, Monte Carlo: runs advanced together in the compiled loop (lanes over runs).

rovlab.sim.loop.run_loop_lanes runs up to LANES seeds of one scenario at once, the process
plant's RK4 vectorised over the lanes (rovlab.sim.plant.process_advance_lanes). Each lane must
give exactly -- bit for bit -- the logs of its run through the one-run loop, whatever the plant
(the observer plant has no lanes kernel: its lanes are advanced one by one), with truth events,
disturbances, a lane that turns too fast for the vectorised step and a lane whose plant diverges.
These compile the lanes loop through the JIT (the suite runs with ROVLAB_AOT=0); the module
built ahead of time is tested in tests/sim/test_prebuilt.py.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rovlab.core.components import LANES
from rovlab.sim import runner
from rovlab.sim.montecarlo import Campaign
from rovlab.sim.scenario import load_scenario_data


def _template(name: str):
    data, file = load_scenario_data(name)
    return Campaign(data, file, 0)


def _alone(preps):
    out = []
    for prep in preps:
        try:
            out.append(runner.Simulation(prep).advance(prep.drive))
        except runner.PlantDiverged as exc:
            out.append(exc)
    return out


def _assert_same(alone, lanes):
    for a, b in zip(alone, lanes, strict=True):
        for field in a._fields:
            assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field


@pytest.mark.parametrize("name", ["step-process-model", "heave-payload", "step-observer-model"])
def test_each_lane_gives_exactly_its_run_alone(name):
    """A full set of lanes and a partial one (the rest of the lanes unused)."""
    campaign = _template(name)
    for seeds in (range(LANES), range(100, 103)):
        preps = [runner.reseed(campaign.template, s) for s in seeds]
        _assert_same(_alone(preps), runner.run_lanes(preps, built=False))


def test_a_lane_that_turns_beyond_the_series_range_takes_the_exact_step():
    """|r| h / 2 > 0.1 rad: the vectorised RK4 step (heading increments by their series) is
    redone for all lanes by the one-run step, which evaluates sin and cos there."""
    campaign = _template("step-process-model")
    preps = [runner.reseed(campaign.template, s) for s in range(4)]
    x = preps[2].plant.x.copy()
    x[7] = 25.0  # yaw rate [rad/s]: 0.125 rad per half step of 0.01 s
    preps[2] = replace(preps[2], plant=preps[2].plant._replace(x=x))
    _assert_same(_alone(preps), runner.run_lanes(preps, built=False))


def test_a_lane_whose_plant_diverges_stops_alone():
    campaign = _template("step-process-model")
    preps = [runner.reseed(campaign.template, s) for s in range(3)]
    normals = preps[1].drive.plant_normals.copy()
    normals[200:210] = 1e30  # absurd force noise from row 20 on: the true state stops being finite
    preps[1] = replace(preps[1], drive=preps[1].drive._replace(plant_normals=normals))
    alone = _alone(preps)
    assert isinstance(alone[1], runner.PlantDiverged) and not isinstance(alone[0], Exception)
    with pytest.raises(runner.PlantDiverged) as stopped:
        runner.run_lanes(preps, built=False)
    assert stopped.value.rows == alone[1].rows and stopped.value.t == alone[1].t
    rows = alone[1].rows
    for field in alone[0]._fields:
        assert np.array_equal(getattr(alone[1].logs, field)[:rows], getattr(stopped.value.logs, field)[:rows],
                              equal_nan=True), field
    # the other lanes ran to the end with their own numbers
    logs = runner.run_lanes([preps[0], preps[2]], built=False)
    _assert_same([alone[0], alone[2]], logs)


def test_lanes_take_only_runs_of_one_prepared_scenario():
    a = _template("step-process-model")
    b = _template("step-process-model")  # designed again: not the same design object
    with pytest.raises(ValueError, match="differ only by their seed"):
        runner.lane_arguments([runner.reseed(a.template, 0), runner.reseed(b.template, 1)])
    with pytest.raises(ValueError, match=f"1 to {LANES} runs"):
        runner.lane_arguments([runner.reseed(a.template, s) for s in range(LANES + 1)])


def test_a_monte_carlo_in_lanes_has_the_statistics_of_runs_one_by_one(monkeypatch):
    """Campaign.run_all goes through the lanes when their loop is there (here the JIT's, as if
    built); each run's metrics and NEES/NIS series are those of the run alone."""
    campaign = _template("step-process-model")
    seeds = list(range(1, 1 + LANES + 5))  # a full group and a partial one
    alone = [campaign.run(s) for s in seeds]
    calls = []
    run_lanes = runner.run_lanes

    def jit_lanes(preps, **kw):
        calls.append(len(preps))
        return run_lanes(preps, built=False)

    monkeypatch.setattr(runner, "run_lanes", jit_lanes)
    together = campaign.run_all(seeds)
    assert calls == [LANES, 5]
    for a, b in zip(alone, together, strict=True):
        assert a["seed"] == b["seed"] and a["metrics"] == b["metrics"] and a["flat"] == b["flat"]
        assert b["lanes"] and not a["lanes"]
        assert np.array_equal(a["nees"], b["nees"], equal_nan=True)
        assert np.array_equal(a["nis"], b["nis"], equal_nan=True)


def test_without_the_built_loop_the_runs_go_one_by_one():
    """The suite runs with ROVLAB_AOT=0: nothing built, nothing requested, same results."""
    campaign = _template("step-process-model")
    assert runner.run_lanes([runner.reseed(campaign.template, s) for s in (0, 1)]) is None
    assert campaign.request_lanes() is None
    seeds = [3, 4, 5]
    assert [r["metrics"] for r in campaign.run_group(seeds)] == [campaign.run(s)["metrics"] for s in seeds]
    assert [r["seed"] for r in campaign.run_all(list(range(LANES + 2)))] == list(range(LANES + 2))
