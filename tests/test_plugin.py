"""Components from outside rovlab (issue 26): examples/plugin, an installable package with a
complementary filter and a PD law, found through its entry points ("rovlab.estimators",
"rovlab.controllers"). `make test` installs it (pip install -e examples/plugin); without it these
tests skip with the reason.

What a contributor gets without touching rovlab: the design file's [complementary] and [pd]
tables read and checked by rovlab's loader, a scenario, a Monte Carlo and the HMI's session.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

try:
    import rovlab_example_plugin as plugin
except ImportError:  # a user's own pytest run; under make test (and CI) it is installed and must import
    if os.environ.get("CI"):
        raise
    pytest.skip("the plugin example is not installed (pip install -e examples/plugin; make test does)",
                allow_module_level=True)

from rovlab.core.components import component, component_names  # noqa: E402
from rovlab.params.design import design_config_from_dict, load_design_config  # noqa: E402
from rovlab.params.validate import ConfigError, read_toml  # noqa: E402

SCENARIO = plugin.EXAMPLES / "pd-depth-step.toml"
CONFIG = plugin.EXAMPLES / "complementary-pd.toml"


def test_its_components_are_found_through_entry_points_without_a_line_of_rovlab():
    assert "complementary" in component_names("estimator") and "pd" in component_names("controller")
    assert component("estimator", "complementary").measurable == ("z", "psi", "w", "r")
    assert component("controller", "pd").build.__module__ == "rovlab_example_plugin.pd"


def test_its_tables_are_read_by_the_loader_with_the_loaders_errors():
    cfg = load_design_config(CONFIG)
    assert cfg.estimator == "complementary" and cfg.controller == "pd"
    assert cfg.table("pd").kp_z == 40.0 and cfg.table("complementary").k_vel == 1.0
    assert "pd" in cfg.sources and "complementary" in cfg.sources
    data = read_toml(CONFIG)
    data["pd"] = {**data["pd"], "kp_z": -1.0, "gain_of_my_dreams": 3.0}
    with pytest.raises(ConfigError) as err:
        design_config_from_dict(data, file="mine.toml")
    text = str(err.value)
    assert "mine.toml" in text and "pd.kp_z" in text and "-1" in text  # file, key, value, expected
    assert "pd.gain_of_my_dreams" in text and "unknown keys are errors" in text
    # a configuration without the tables gets the components' defaults
    del data["pd"], data["complementary"]
    cfg = design_config_from_dict(data, file="mine.toml")
    assert cfg.table("pd") == type(cfg.table("pd"))()


def test_rovlab_design_shows_them_by_their_tables(capsys):
    """`rovlab design` asks each component for its summary; a component without one (the plugin's)
    is shown by its table's values, in the text and in --json."""
    from rovlab.interfaces.cli import main

    assert main(["design", "--config", str(CONFIG)]) == 0
    out = capsys.readouterr().out
    assert "estimator complementary: complementary depth-and-heading filter" in out
    assert "controller pd:" in out and "kp_z 40" in out and "k_vel = 1" in out
    assert main(["design", "--config", str(CONFIG), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["estimator"] == "complementary" and info["controller"] == "pd"
    assert info["pd"]["kp_z"] == 40.0 and info["complementary"]["k_pos"] == 0.5
    assert main(["design", "--config", str(CONFIG), "--allow-unobservable"]) == 2
    assert "estimator 'complementary' has no such option" in capsys.readouterr().err


def test_a_scenario_runs_with_them_and_holds_the_depth(tmp_path):
    res = subprocess.run([sys.executable, "-m", "rovlab.interfaces.cli", "simulate", str(SCENARIO), "--out",
                          str(tmp_path / "run"), "--no-figures"], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    # its loop is compiled in every process (components from outside rovlab never enter numba's
    # shared cache), and the command says so rather than promise a cache
    assert "compiled in every process" in res.stderr and "numba caches it" not in res.stderr
    from rovlab.sim.compile import needs_compiling

    assert needs_compiling("process-complementary-pd", shipped=False)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["rms_error"]["z"] < 0.05 and metrics["rms_error"]["psi"] < np.radians(3.0)
    from rovlab.io.logreader import read_log

    log = read_log(tmp_path / "run" / "timeseries.csv")
    assert abs(float(np.mean(log["true_z"][-100:])) - 0.70) < 0.08  # the 0.70 m step is held by the PD law
    assert abs(float(np.mean(log["true_psi"][-50:]))) < np.radians(3.0)  # and the heading step to 0 deg
    assert set(log.text["status_z_qualisys"]) == {"ok"}  # rovlab's channel bookkeeping, kept by the filter


def test_a_monte_carlo_of_40_runs_with_them(tmp_path):
    from rovlab.sim.montecarlo import run_many, summarise_runs
    from rovlab.sim.scenario import load_scenario_data

    data, file = load_scenario_data(str(SCENARIO))
    runs = run_many(data, file, list(range(40)), workers=2)
    summary = summarise_runs(runs)
    assert summary["runs"] == 40 and summary["metrics"]["rms_error.z"]["count"] == 40
    assert summary["metrics"]["rms_error.z"]["max"] < 0.05


def test_the_hmi_session_runs_them():
    pytest.importorskip("aiohttp", reason="the HMI needs the 'hmi' extra (aiohttp)")
    from rovlab.interfaces.hmi.session import Session

    session = Session.simulation(str(SCENARIO), running=False)
    msgs = session.advance(20)
    estimates = [payload for topic, _, payload in msgs if topic == "/rovlab/estimate"]
    assert len(estimates) == 20 and all(np.isfinite(float(e["state"]["z"])) for e in estimates)
    summary = session.source.loop_summary()
    assert summary["controller"] == "pd" and set(summary["R"]) == {"qualisys.z", "pressure.z", "qualisys.psi"}
    # its table is tuned like any rovlab table: the loader refuses a bad value, a good one redesigns
    from rovlab.interfaces.hmi.session import CommandError

    with pytest.raises(CommandError) as err:
        session.handle({"cmd": "set", "target": "config", "key": "pd.kp_z", "value": -5})
    assert "pd.kp_z" in str(err.value)
    session.handle({"cmd": "set", "target": "config", "key": "pd.kp_z", "value": 30})
    assert session.source.sim.prep.design.controller.kernel.kp_z == 30.0


def test_rovlab_filter_replays_a_log_with_the_plugins_estimator(tmp_path):
    from rovlab.interfaces.cli import main
    from rovlab.io.logreader import read_log

    run = tmp_path / "run"
    assert main(["simulate", str(SCENARIO), "--out", str(run), "--no-figures"]) == 0
    est = tmp_path / "est.csv"
    assert main(["filter", str(run / "timeseries.csv"), "--config", str(CONFIG), "--out", str(est)]) == 0
    a, b = read_log(run / "timeseries.csv"), read_log(est)
    for s in ("z", "psi", "w", "r"):  # the in-loop estimates, to the log's 10 significant digits
        np.testing.assert_allclose(b[f"est_{s}"], a[f"est_{s}"], rtol=1e-7, atol=1e-8, err_msg=s)


def test_the_vehicle_nodes_tune_its_tables_at_run_time():
    """The ROS 1/2 nodes' parameters (rovlab.interfaces.node.ros_common.ParameterTable) include the
    numbers of every component table the design file has: here [pd] and [complementary]."""
    from rovlab.interfaces.node.runtime import load_node

    core, table = load_node("udrone", str(CONFIG))
    assert table.values["pd.kp_z"] == 40.0 and table.values["complementary.k_vel"] == 1.0
    reason = table.set({"pd.kp_z": -1.0})
    assert reason is not None and "pd.kp_z" in reason  # refused by the loader, with the key
    assert core.design.config.table("pd").kp_z == 40.0  # and nothing changed
    assert table.set({"pd.kp_z": 30.0}) is None
    assert core.design.config.table("pd").kp_z == 30.0 and core.controller.kp_z == 30.0  # redesigned, running


def test_a_plugin_cannot_take_a_shipped_name_or_a_key_of_every_design_file():
    from rovlab.core.components import ComponentInfo, register_component

    build = component("controller", "pd").build
    with pytest.raises(ValueError, match="rovlab's own"):
        register_component(ComponentInfo("lqg", "controller", build))
    with pytest.raises(ValueError, match="key of every design file"):
        register_component(ComponentInfo("lqr", "controller", build))
