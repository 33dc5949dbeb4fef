"""The simulator as components (issue 9): slots, one call site, state as values, clear refusals."""

from __future__ import annotations

import subprocess
import sys
from typing import NamedTuple

import numpy as np
import pytest
from numba import njit

from rovlab.core.components import (
    _COMPONENTS,
    ComponentInfo,
    ControllerSpec,
    fresh,
    register_controller,
    restore,
    state_fields,
    state_of,
)
from rovlab.io.logreader import read_log
from rovlab.params.design import design_config_from_dict, packaged_config_path
from rovlab.params.validate import ConfigError, read_toml
from rovlab.sim.live import LiveSimulation
from rovlab.sim.montecarlo import run_many
from rovlab.sim.prepare import first_rows, prepare
from rovlab.sim.runner import PlantDiverged, Simulation, run_prepared
from rovlab.sim.scenario import load_scenario, load_scenario_data


class HoldDepth(NamedTuple):
    """A toy controller written the way docs/architecture.md says: a PID law on depth (the
    derivative from the estimated heave velocity) with its integrator as state, nothing on
    heading. (A PI alone leaves uDrone's heave with only its light hydrodynamic damping: it
    oscillates for minutes, and where it is at 60 s depends on the estimate's every detail.)"""

    kp: float
    ki: float
    kd: float
    h: float
    state: np.ndarray  # [integral of the depth error]


@njit(cache=False)
def _hold_step(ctrl, t, nav, ref, tau):
    e = ref[2] - nav[2]
    ctrl.state[0] += ctrl.h * e
    tau[0] = 0.0
    tau[1] = 0.0
    tau[2] = ctrl.kp * e + ctrl.ki * ctrl.state[0] - ctrl.kd * nav[6] - nav[10]
    tau[3] = 0.0


register_controller(HoldDepth, state=("state",), step=_hold_step)


def _build_hold(vehicle, config):
    return ControllerSpec(kernel=HoldDepth(40.0, 4.0, 60.0, config.sample_time, np.zeros(1)),
                          needs=("z", "w", "b_Z"),
                          references=("z",), outputs=("Z",), state_names=("depth_integral",))


@pytest.fixture
def hold_registered(monkeypatch):
    monkeypatch.setitem(_COMPONENTS["controller"], "hold", ComponentInfo("hold", "controller", _build_hold))


def test_a_new_controller_is_one_module_plus_its_registration(hold_registered):
    sc = load_scenario("step-process-model")
    from dataclasses import replace

    res = run_prepared(prepare(replace(sc, controller="hold")))
    c = res.columns
    assert abs(c["true_z"][-1] - 0.70) < 0.05  # the PID law brings the vehicle to the depth reference
    assert abs(c["true_z"][-1] - 0.70) < 0.5 * abs(c["true_z"][300] - 0.70)  # and keeps closing in
    assert "ctrl_depth_integral" in c and np.all(np.isfinite(c["ctrl_depth_integral"]))
    assert c["ctrl_depth_integral"][-1] != 0.0  # its state was advanced and logged
    assert "tau_Z" in c and "tau_N" not in c  # only the wrench entries it commands are logged
    # a component from outside rovlab is compiled per process: it must never enter the shared
    # on-disk cache index, which a process that cannot import this test module would fail to read
    other = subprocess.run([sys.executable, "-c", "from rovlab.sim.runner import simulate; "
                            "print(len(simulate('step-process-model').columns['time_s']))"],
                           capture_output=True, text=True, timeout=600, cwd="/")
    assert other.returncode == 0 and other.stdout.strip() == "601", other.stderr[-2000:]


class AllocatingDepth(NamedTuple):
    """A P law on depth written carelessly: it allocates a temporary array at every step."""

    kp: float
    state: np.ndarray


@njit(cache=False)
def _allocating_step(ctrl, t, nav, ref, tau):
    e = np.empty(4)  # not allowed inside the loop (compiled without reference counting)
    e[2] = ref[2] - nav[2]
    tau[0] = 0.0
    tau[1] = 0.0
    tau[2] = ctrl.kp * e[2]
    tau[3] = 0.0


register_controller(AllocatingDepth, state=("state",), step=_allocating_step)


def test_a_kernel_that_allocates_inside_the_loop_is_refused_with_the_line_and_the_remedy(monkeypatch):
    def build(vehicle, config):
        return ControllerSpec(kernel=AllocatingDepth(40.0, np.zeros(0)), needs=("z",), references=("z",),
                              outputs=("Z",), state_names=())

    monkeypatch.setitem(_COMPONENTS["controller"], "allocating", ComponentInfo("allocating", "controller", build))
    from dataclasses import replace

    prep = prepare(replace(load_scenario("step-process-model"), controller="allocating"))
    with pytest.raises(TypeError) as err:
        Simulation(prep).advance(first_rows(prep.drive, 2))
    text = str(err.value)
    assert "AllocatingDepth allocates memory" in text and "inside the closed loop" in text
    assert f"{__file__}, line" in text  # where: numba's report, made readable
    assert "WITH_NRT" in text and "fields of the component" in text and "returns no array" in text  # what to do


def test_unknown_components_and_missing_estimates_are_refused_by_name():
    data = read_toml(packaged_config_path("thesis"))
    data["controller"] = "pid-of-my-dreams"
    with pytest.raises(ConfigError) as err:  # refused when the file is read, with the names there are
        design_config_from_dict(data, file="my.toml")
    msg = str(err.value)
    assert "my.toml" in msg and "controller" in msg and "pid-of-my-dreams" in msg and "lqg" in msg
    # and when a scenario names one
    from dataclasses import replace

    with pytest.raises(ConfigError) as err:
        prepare(replace(load_scenario("step-process-model"), controller="pid-of-my-dreams"))
    assert "controller" in str(err.value) and "mrac" in str(err.value)


def test_a_controller_needing_what_the_estimator_lacks_is_refused(monkeypatch):
    def needs_x(vehicle, config):
        spec = _build_hold(vehicle, config)
        return ControllerSpec(kernel=spec.kernel, needs=("x", "z"), references=("z",), outputs=("Z",))

    monkeypatch.setitem(_COMPONENTS["controller"], "needs-x", ComponentInfo("needs-x", "controller", needs_x))
    from dataclasses import replace

    with pytest.raises(ConfigError, match="estimates x"):
        prepare(replace(load_scenario("step-process-model"), controller="needs-x"))


def test_state_is_a_value_that_can_be_saved_and_restored():
    prep = prepare(load_scenario("dropout"))
    sim = Simulation(prep)
    n = 100
    from rovlab.sim.loop import Drive

    def chunk(a, b):
        d = prep.drive
        return Drive(d.plant_normals[a * 10:b * 10], d.bias_normals[a:b], d.sensor_normals[a:b], d.dropout[a:b],
                     d.refs[a:b], d.heave_force[a:b], d.pset[a:b])

    sim.advance(chunk(0, n))
    saved = {slot: state_of(c) for slot, c in sim.components().items()}
    first = sim.advance(chunk(n, 2 * n))
    for slot, comp in sim.components().items():  # rewind and run the same chunk again
        assert restore(comp, saved[slot]) == list(state_fields(comp))
    sim.k = n
    again = sim.advance(chunk(n, 2 * n))
    np.testing.assert_array_equal(first.x, again.x)
    np.testing.assert_array_equal(first.truth, again.truth)
    # a Prepared is never changed by running it: fresh() copies the state
    assert fresh(prep.design.estimator.kernel).x is not prep.design.estimator.kernel.x


def test_batch_monte_carlo_and_live_go_through_the_same_loop_and_columns():
    prep = prepare(load_scenario("step-process-model"))
    batch = run_prepared(prep)
    live = LiveSimulation("step-process-model")
    live.advance(prep.n_ctrl)  # one chunk: the same draws in the same order as the batch run
    for name, col in batch.columns.items():
        np.testing.assert_array_equal(live.last_columns[name], col, err_msg=name)
    assert list(live.last_columns) == list(batch.columns)
    data, file = load_scenario_data("step-process-model")
    mc = run_many(data, file, [prep.scenario.seed], workers=1)
    np.testing.assert_array_equal(mc[0]["nees"], batch.nees)


def test_a_diverging_plant_stops_the_run_with_a_clear_message():
    from dataclasses import replace

    sc = load_scenario("step-process-model")
    prep = prepare(sc)
    bad = prep.plant._replace(p_sets=prep.plant.p_sets.copy())
    bad.p_sets[:, :16] *= 1e12  # an absurd inverse mass matrix: the state explodes
    with pytest.raises(PlantDiverged, match="diverged at t ="):
        run_prepared(replace(prep, plant=bad))


def test_simulate_writes_sensor_status_as_words_and_refuses_an_unwritable_out(tmp_path):
    out = tmp_path / "run"
    exe = [sys.executable, "-c", "import sys; from rovlab.interfaces.cli import main; sys.exit(main())"]
    done = subprocess.run(exe + ["simulate", "dropout", "--out", str(out), "--no-figures"], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    log = read_log(out / "timeseries.csv")
    words = set(log.text["status_z_qualisys"])
    assert {"ok", "lost-timeout"} <= words  # the words `rovlab filter` writes
    blocker = tmp_path / "a-file"  # --out below a file: no folder can be made there (root or not)
    blocker.write_text("x")
    done = subprocess.run(exe + ["simulate", "dropout", "--out", str(blocker / "run"), "--no-figures"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 2, done.stderr
    assert "cannot write" in done.stderr and "Traceback" not in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file", "run"]  # nothing half-written


def test_an_interrupted_monte_carlo_keeps_its_finished_runs():
    data, file = load_scenario_data("step-observer-model")
    calls = []

    def progress(done, total):
        calls.append(done)
        if done == 2:
            raise KeyboardInterrupt

    out = run_many(data, file, [0, 1, 2, 3], workers=1, progress=progress)
    assert [r["seed"] for r in out] == [0, 1]


def test_a_simulations_timeseries_feeds_rovlab_filter_directly(tmp_path):
    """Issue 15: timeseries.csv (meas_<quantity>_<sensor>, tau_Z, tau_N) goes into `rovlab filter`
    as it is, and the offline filter with the same configuration reproduces the loop's estimate."""
    from rovlab.interfaces.cli import main

    run_dir = tmp_path / "run"
    assert main(["simulate", "step-process-model", "--out", str(run_dir), "--no-figures"]) == 0
    est = tmp_path / "est.csv"
    assert main(["filter", str(run_dir / "timeseries.csv"), "--config", "thesis", "--out", str(est)]) == 0
    sim, off = read_log(run_dir / "timeseries.csv"), read_log(est)
    np.testing.assert_allclose(off["est_z"], sim["est_z"], atol=1e-6)
    np.testing.assert_allclose(off["est_b_w"], sim["est_b_w"], atol=1e-4)
    assert (tmp_path / "est.csv.json").exists() and "#" not in est.read_text(encoding="utf-8")[:200]


def test_actuators_skip_the_real_thrust_only_where_nothing_feels_it():
    """The observer plant takes the achieved wrench, so its runs skip the thrust the PWM commands
    really give (make_actuators(real=False)); the process plant keeps it. With the real thrust
    skipped, tau_real is the achieved wrench; the achieved wrench and the PWM are the same."""
    from rovlab.sim.actuators import actuate
    from rovlab.sim.prepare import prepare
    from rovlab.sim.scenario import load_scenario

    assert prepare(load_scenario("step-process-model")).actuators.real
    obs = prepare(load_scenario("step-observer-model")).actuators
    assert not obs.real
    a = obs._replace(real=True)
    tau = np.array([0.0, 0.0, 12.0, 0.8])
    out = {}
    for name, act in (("real", a), ("skip", obs)):
        tc, tr, pwm = np.zeros(4), np.full(4, np.nan), np.zeros(act.rows.shape[0])
        actuate(act, tau, tc, tr, pwm)
        out[name] = (tc, tr, pwm)
    np.testing.assert_array_equal(out["real"][0], out["skip"][0])
    np.testing.assert_array_equal(out["real"][2], out["skip"][2])
    np.testing.assert_array_equal(out["skip"][1], out["skip"][0])
    assert np.all(np.isfinite(out["real"][1])) and not np.array_equal(out["real"][1], out["real"][0])  # PWM quantised


def test_no_compiled_function_in_sim_takes_more_than_15_parameters():
    """Issue 9: components travel as NamedTuples, so the loop, the node's step and the plants
    keep short signatures (the monolithic loop took 52 positional arguments)."""
    import importlib
    import inspect
    import pkgutil

    import rovlab.sim

    checked = {}
    for info in pkgutil.iter_modules(rovlab.sim.__path__):
        module = importlib.import_module(f"rovlab.sim.{info.name}")
        for name, obj in vars(module).items():
            fn = getattr(obj, "py_func", None)
            if fn is not None and fn.__module__ == module.__name__:
                checked[f"{module.__name__}.{name}"] = len(inspect.signature(fn).parameters)
    assert "rovlab.sim.loop.run_loop" in checked and "rovlab.sim.step.control_step" in checked
    too_many = {k: v for k, v in checked.items() if v > 15}
    assert not too_many, too_many


def test_the_observer_plant_comes_from_an_estimator_that_offers_its_model():
    """plant = "observer" simulates an estimator's own linear model (Sandøy 2016, sec. 5.3: the
    observer-model case study). The KF declares it (ComponentInfo.observer_model); the EKF does not,
    and a scenario asking for both is refused by name, saying which estimators would do."""
    from rovlab.core.components import component

    assert component("estimator", "kf").observer_model is not None
    assert component("estimator", "ekf").observer_model is None
    data, file = load_scenario_data("step-observer-model")
    prepare(data, file=file)  # the packaged observer-model case: kf
    data, file = load_scenario_data("dp-station-keeping")  # ekf + dp
    prepare(data, file=file)
    with pytest.raises(ConfigError) as info:
        prepare({**data, "plant": "observer"}, file=file)
    p = info.value.problems[0]
    assert p.key == "plant" and "estimator 'ekf' does not offer" in p.expected and "that do: kf" in p.expected


@pytest.mark.parametrize("spec, says", [
    (dict(state_names=("a", "b")), "state_names has 2 names for a state array of 1 entries"),
    (dict(needs=("z", "depth")), "ControllerSpec.needs names 'depth', not in TRUTH"),
    (dict(references=("depth",)), "ControllerSpec.references names 'depth', not in REFERENCE"),
    (dict(outputs=("Z", "K")), "ControllerSpec.outputs names 'K', not in WRENCH"),
])
def test_a_components_specs_are_checked_by_name_before_anything_runs(monkeypatch, spec, says):
    """A new component's mistakes in what its build returns are named when the design is made (the
    state names once ran a whole run and then raised an IndexError in the results)."""
    from rovlab.sim.designs import make_design

    def build(vehicle, config):
        base = dict(kernel=HoldDepth(40.0, 4.0, 60.0, config.sample_time, np.zeros(1)), needs=("z", "w", "b_Z"),
                    references=("z",), outputs=("Z",), state_names=("depth_integral",))
        return ControllerSpec(**{**base, **spec})

    monkeypatch.setitem(_COMPONENTS["controller"], "bad", ComponentInfo("bad", "controller", build))
    from rovlab.params.vehicle import load_vehicle

    cfg = design_config_from_dict(read_toml(packaged_config_path("thesis")), file="thesis.toml")
    with pytest.raises(TypeError, match="controller 'bad'") as info:
        make_design(load_vehicle("udrone"), cfg, plant="process", plant_step=0.01, controller="bad")
    assert says in str(info.value) and "docs/architecture.md" in str(info.value)


def test_an_unregistered_component_type_says_how_to_register_it():
    class Stray(NamedTuple):
        state: np.ndarray

    with pytest.raises(TypeError, match="register_controller"):
        state_fields(Stray(np.zeros(0)))
