"""The thesis's filter tuning on the nonlinear plant, and the packaged consistent one (issue 28,
item 6: on step-process-model the thesis's W gives an average NEES of ~3.1 for 4 states against
the 95 % band [3.62, 4.40] of 200 runs, and NIS ~0.8).

NEES/NIS bands: Bar-Shalom, Li & Kirubarajan (2001), sec. 5.4 -- the run-average of N runs times N
is chi-square with N * dof degrees of freedom, per time step.
"""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.params.design import load_design_config
from rovlab.params.validate import read_toml
from rovlab.sim.metrics import consistency
from rovlab.sim.montecarlo import run_many, summarise_runs
from rovlab.sim.scenario import load_scenario_data

RUNS = 50
SEEDS = range(2, 2 + RUNS)


def test_it_is_the_thesis_design_but_for_the_noise_and_the_biases_start():
    """Everything but [process_noise] psd and [initial] std is thesis.toml's, number for number (a
    change of the thesis design not made here too fails this test)."""
    thesis = read_toml(load_design_config("thesis").file)
    mine = read_toml(load_design_config("thesis_consistent").file)
    for d in (thesis, mine):
        for key in ("name", "description", "source"):
            d.pop(key)
        for table, key in (("process_noise", "source"), ("process_noise", "psd"), ("initial", "source"),
                           ("initial", "std")):
            d[table].pop(key)
    assert mine == thesis
    cfg = load_design_config("thesis_consistent")
    np.testing.assert_allclose(cfg.psd[2:], [1e-2, 1e-6, 3e-3, 3e-6])
    np.testing.assert_allclose(cfg.initial_std, [0, 0, 0, 0, 7.0, 0.01])


@pytest.fixture(scope="module")
def monte_carlo():
    """50 runs of step-process-model with each design (the packaged step-process-model-consistent
    is step-process-model with design thesis_consistent)."""
    out = {}
    for scenario in ("step-process-model", "step-process-model-consistent"):
        data, file = load_scenario_data(scenario)
        runs = run_many(data, file, SEEDS, workers=1)
        out[scenario] = (summarise_runs(runs), np.array([r["nees"] for r in runs]), np.array([r["nis"] for r in runs]))
    return out


def test_the_consistent_tuning_stays_inside_the_bands(monte_carlo):
    """thesis_consistent over 50 runs: the average NEES inside the per-step 95 % band of 50 runs,
    at least 80 % of the steps inside it (a consistent filter: 95 %; 200 runs in
    docs/estimation.md: 3.95, 89 %), the NIS average within 10 % of 1 and 90 % of the steps inside."""
    summary, nees, nis = monte_carlo["step-process-model-consistent"]
    n, s = summary["nees"], summary["nis"]
    lo, hi = n["bounds_per_step"]
    assert lo <= n["mean"] <= hi and n["share_inside"] >= 0.80, n
    assert abs(s["mean"] - 1.0) < 0.10 and s["share_inside"] >= 0.90, s
    after = consistency(nees[:, 30:], 4)  # after the 3 s start-up too
    assert lo <= after["mean"] <= hi, after


def test_the_thesis_tuning_is_what_the_issue_measured(monte_carlo):
    """The thesis's tuning on the same runs fails the same check (so the check can fail): its
    NEES is below the band at nearly every step; after the start-up its average is ~3.1 and its
    NIS ~0.8 (issue 28, item 6)."""
    summary, nees, nis = monte_carlo["step-process-model"]
    n = summary["nees"]
    assert n["share_inside"] < 0.5, n
    after_nees, after_nis = np.nanmean(nees[:, 30:]), np.nanmean(nis[:, 30:])
    assert after_nees < n["bounds_per_step"][0] and 2.9 < after_nees < 3.3, after_nees
    assert 0.7 < after_nis < 0.9, after_nis
