"""The Monte Carlo fast paths give exactly what the plain per-run path gives (issue 16 part 2):
a prepared run reseeded equals one prepared from that seed, the campaign's runs equal
summarise(run_prepared(prepare(seed))), the chi-square bounds equal scipy.stats', and
--no-figures renders nothing."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from rovlab.interfaces.cli import main
from rovlab.sim.designs import DesignBook
from rovlab.sim.montecarlo import Campaign, run_many
from rovlab.sim.prepare import prepare, reseed
from rovlab.sim.results import summarise
from rovlab.sim.runner import run_prepared
from rovlab.sim.scenario import has_distributions, load_scenario_data


def _same_result(a, b):
    assert list(a.columns) == list(b.columns)
    for name in b.columns:
        np.testing.assert_array_equal(a.columns[name], b.columns[name], err_msg=name)
    np.testing.assert_array_equal(a.nees, b.nees)
    np.testing.assert_array_equal(a.nis, b.nis)
    assert a.meta["seed"] == b.meta["seed"]


@pytest.mark.parametrize("name", ["step-process-model", "step-observer-model", "dp-mocap-dropout"])
def test_reseed_equals_prepare_with_that_seed(name):
    data, file = load_scenario_data(name)
    assert not has_distributions(data)
    book = DesignBook()
    template = prepare(data, file=file, seed=3, book=book)
    for seed in (0, 41):
        fast = reseed(template, seed)
        plain = prepare(data, file=file, seed=seed, book=book)
        assert fast.scenario.seed == seed
        for field in ("plant_normals", "bias_normals", "sensor_normals", "dropout", "refs", "heave_force", "pset"):
            np.testing.assert_array_equal(getattr(fast.drive, field), getattr(plain.drive, field), err_msg=field)
        _same_result(run_prepared(fast), run_prepared(plain))
    # the template is not changed by reseeding or running
    _same_result(run_prepared(template), run_prepared(prepare(data, file=file, seed=3, book=book)))


def test_reseed_refuses_a_negative_seed():
    data, file = load_scenario_data("step-observer-model")
    with pytest.raises(ValueError, match="non-negative"):
        reseed(prepare(data, file=file), -1)


def test_a_campaign_gives_the_plain_per_run_metrics_with_and_without_distributions():
    data, file = load_scenario_data("step-process-model")
    drawn = copy.deepcopy(data)  # a scenario whose values are drawn from the seed
    drawn["initial"]["z"] = {"dist": "uniform", "low": 0.9, "high": 1.2}
    assert has_distributions(drawn) and not has_distributions(data)
    for d in (data, drawn):
        campaign = Campaign(d, file, 7)
        assert (campaign.template is None) == (d is drawn)
        for seed in (7, 8):
            got = campaign.run(seed)
            plain = run_prepared(prepare(d, file=file, seed=seed))
            assert got["metrics"] == summarise(plain)
            np.testing.assert_array_equal(got["nees"], plain.nees)
            np.testing.assert_array_equal(got["nis"], plain.nis)
    # the drawn scenario really differs between seeds (so it must not be reseeded)
    a, b = Campaign(drawn, file, 7).run(7), Campaign(drawn, file, 7).run(8)
    assert a["metrics"]["rms_error"] != b["metrics"]["rms_error"]


def test_parallel_runs_keep_seed_order_with_uneven_chunks():
    data, file = load_scenario_data("step-observer-model")
    seeds = [11, 3, 5, 9, 2, 4, 8]  # any order; results come back in it
    par = run_many(data, file, seeds, workers=2)
    seq = run_many(data, file, seeds, workers=1)
    assert [r["seed"] for r in par] == seeds == [r["seed"] for r in seq]
    for a, b in zip(par, seq):
        assert a["metrics"] == b["metrics"]
        np.testing.assert_array_equal(a["nees"], b["nees"])
    assert run_many(data, file, [], workers=2) == []


def test_chi_square_bounds_equal_scipy_stats():
    from scipy.stats import chi2

    from rovlab.estimation.consistency import check, chi2_interval

    a = (1.0 - 0.95) / 2.0  # as chi2_interval computes it (not exactly 0.025)
    for dof in (1, 4, 6):
        for runs in (1, 2, 40, 1000):
            assert chi2_interval(dof, runs) == (float(chi2.ppf(a, dof * runs) / runs),
                                                float(chi2.ppf(1 - a, dof * runs) / runs))
    stat = np.array([[1.0, np.nan, 3.0], [2.0, 2.0, np.nan]])
    lo, hi = check(stat, 4).bounds()
    count = np.array([2, 1, 1])
    np.testing.assert_array_equal(lo, chi2.ppf(a, 4 * count) / count)
    np.testing.assert_array_equal(hi, chi2.ppf(1.0 - a, 4 * count) / count)


def test_no_figures_renders_no_nees_plot(tmp_path):
    out = tmp_path / "mc"
    assert main(["simulate", "step-observer-model", "--out", str(out), "--runs", "3", "--workers", "1",
                 "--no-figures"]) == 0
    assert sorted(p.name for p in (out / "monte_carlo").iterdir()) == ["metrics.json"]
    mc = json.loads((out / "monte_carlo" / "metrics.json").read_text())["monte_carlo"]
    assert mc["runs"] == 3 and mc["seeds"] == [1, 2, 3]
