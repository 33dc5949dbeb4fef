"""The middleware-free vehicle node (issue 13): the simulator's estimates and commands from the
simulator's samples, and every kind of bad, late or missing input handled without stopping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.interfaces.node.core import NodeCore
from rovlab.params.design import design_config_from_dict, load_design_config, packaged_config_path
from rovlab.params.validate import ConfigError, read_toml
from rovlab.params.vehicle import load_vehicle
from rovlab.sim.prepare import prepare
from rovlab.sim.runner import run_prepared
from rovlab.sim.scenario import load_scenario


@pytest.fixture(scope="module")
def udrone():
    return load_vehicle("udrone"), load_design_config("thesis")


@pytest.fixture()
def core(udrone):
    return NodeCore(*udrone, log=lambda msg: None)


def _sample_all(core, k, values=None):
    h = core.h
    values = values or {"z": 0.5, "psi": 0.2}
    for c in core.channels:
        core.push(c.sensor, c.quantity, values[c.quantity] + c.offset, k * h)


def test_node_reproduces_the_simulator_from_its_samples():
    """Fed the samples the simulator's sensors gave (meas_* columns), with the scenario's
    references, the node computes the simulator's estimates, covariances and PWM commands: the
    same kernels through the same slots (rovlab.sim.step.control_step vs rovlab.sim.loop)."""
    sc = load_scenario("dropout")  # a drop-out window: steps without samples too
    prep = prepare(sc)
    res = run_prepared(prep)
    cols = res.columns
    core = NodeCore(prep.vehicle, prep.config, pwm_resolution_us=sc.pwm_resolution_us, log=lambda msg: None)
    h = core.h
    n = len(cols["time_s"])
    est = np.empty((n, len(core.states)))
    var = np.empty_like(est)
    pwm = np.empty((n, len(core.thrusters)))
    for k in range(n):
        core.set_reference(x=float(sc.initial[0]), y=float(sc.initial[1]), z=float(cols["ref_z"][k]),
                           psi=float(cols["ref_psi"][k]))
        for c in core.channels:
            v = cols[f"meas_{c.column}"][k]
            if not math.isnan(v):
                assert core.push(c.sensor, c.quantity, v, k * h) == "accepted"
        outs = core.tick(k * h + core.collect_s + 1e-9)
        assert [o.k for o in outs] == [k]
        est[k], var[k], pwm[k] = outs[0].x, np.diag(outs[0].P), outs[0].pwm_us
    for i, s in enumerate(core.states):
        np.testing.assert_allclose(est[:, i], cols[f"est_{s}"], rtol=0, atol=1e-9, err_msg=s)
        np.testing.assert_allclose(var[:, i], cols[f"var_{s}"], rtol=1e-9, atol=1e-15, err_msg=s)
    for i, name in enumerate(core.thrusters):
        np.testing.assert_allclose(pwm[:, i], cols[f"pwm_{name}"], rtol=0, atol=1e-9, err_msg=name)
    statuses = res.status_words()
    last = core.last
    assert last is not None
    for c, label in zip(core.channels, last.channel_status):
        assert statuses[f"status_{c.column}"][-1] == label


def test_a_step_runs_as_soon_as_every_channel_has_its_sample(core):
    _sample_all(core, 0)
    outs = core.tick(0.0)
    assert [o.k for o in outs] == [0]
    assert np.all(np.isfinite(outs[0].y))
    assert core.tick(0.01) == []  # nothing new: the next step waits for its samples or its deadline


def test_missing_samples_mean_dead_reckoning_then_timeout(core):
    _sample_all(core, 0)
    core.tick(0.0)
    outs = core.tick(3.0)  # nothing for 3 s: the overdue steps run without samples
    assert len(outs) == int(math.floor((3.0 - core.collect_s) / core.h)) - 1 + 1
    assert all(np.all(np.isnan(o.y)) for o in outs)
    assert all(s.startswith("lost") for s in outs[-1].channel_status)
    assert np.all(np.isfinite(outs[-1].x)) and np.all(np.diag(outs[-1].P) > np.diag(outs[0].P))


def test_late_out_of_order_future_and_invalid_samples_are_refused_by_name(core):
    h = core.h
    qz = core.channels[0]
    assert core.push(qz.sensor, qz.quantity, 0.5, 0.0) == "accepted"
    assert core.push(qz.sensor, qz.quantity, 0.5, 0.0) == "out-of-order"  # same stamp again
    assert core.push(qz.sensor, qz.quantity, 0.5, -0.05) == "out-of-order"
    core.tick(10 * h + core.collect_s)  # steps 0 .. 10 done
    other = core.channels[1]
    assert core.push(other.sensor, other.quantity, 0.5, 2 * h) == "late"
    assert core.push(other.sensor, other.quantity, 0.5, 10 * h) == "accepted"  # just missed its step: still used
    assert core.push(other.sensor, other.quantity, 0.5, 1e6) == "future"
    assert core.push(other.sensor, other.quantity, float("nan"), 11 * h) == "invalid"
    assert "not finite" in core.last_problem and other.name.split(".")[0] in core.last_problem
    assert core.push(other.sensor, other.quantity, "abc", 11 * h) == "invalid"
    assert core.push(other.sensor, other.quantity, 0.5, float("inf")) == "invalid"
    assert core.push(qz.sensor, "x", 1.0, 11 * h) == "unused"
    assert core.push("sonar", "z", 1.0, 11 * h) == "unused"
    out = core.tick(11 * h + core.collect_s)
    assert len(out) == 1 and not math.isnan(out[0].y[1])
    assert core.counters["late"] == 1 and core.counters["invalid"] == 3 and core.counters["out-of-order"] == 2


def test_a_long_stall_rebases_the_clock_and_keeps_the_filter(core):
    _sample_all(core, 0)
    core.tick(0.0)
    P_before = core.last.P.copy()
    outs = core.tick(1e5)  # a stall of a day: one step (dead reckoning) on a new time base
    assert [o.k for o in outs] == [1] and core.counters["rebased"] == 1
    assert outs[0].stamp == pytest.approx(1e5 - core.collect_s)
    assert np.all(np.diag(outs[0].P) >= np.diag(P_before))  # one prediction, not 10^6 of them
    assert [o.k for o in core.tick(1e5 + core.h)] == [2]


def test_not_engaged_until_a_reference_neutral_thrusters(core):
    _sample_all(core, 0)
    out = core.tick(0.0)[0]
    assert not out.engaged and np.all(out.tau == 0.0)
    assert np.allclose(out.tau_achieved, 0.0, atol=1e-9)
    core.set_reference(z=1.0)  # heading: holds the estimated heading
    _sample_all(core, 1, {"z": 0.5, "psi": 0.2})
    out = core.tick(core.h)[0]
    assert out.engaged and out.tau[2] > 0.0  # too shallow: push down
    assert out.reference[2] == 1.0
    with pytest.raises(ValueError, match="depth"):
        core.set_reference(z=-1.0)
    with pytest.raises(ValueError, match="finite"):
        core.set_reference(psi=float("nan"))
    with pytest.raises(ValueError, match="two turns"):  # 1e308 rad used to wrap to an arbitrary heading
        core.set_reference(psi=1e308)
    core.set_reference(psi=math.radians(370.0))  # a full turn and a bit: wrapped
    assert core.reference[3] == pytest.approx(math.radians(10.0))
    assert core.reference[2] == 1.0


def test_sensor_switch_and_filter_mode(core):
    sensor = core.channels[0].sensor
    core.set_sensor_enabled(sensor, False)
    assert core.push(sensor, core.channels[0].quantity, 0.5, 0.0) == "disabled"
    assert core.tick(0.0) == []  # no sample yet: the time base starts here, step 0 is due at collect_s
    out = core.tick(core.collect_s)[0]
    assert out.sensor_status[sensor] == "disabled"
    with pytest.raises(ValueError, match="unknown sensor"):
        core.set_sensor_enabled("sonar", False)
    core.set_filter_mode(core.channels[1].name, "off")
    assert core.filter_modes()[core.channels[1].name] == "off"
    with pytest.raises(ValueError, match="mode"):
        core.set_filter_mode(core.channels[1].name, "sometimes")


def test_apply_keeps_the_state_and_refuses_a_bad_design(core, udrone):
    for k in range(5):
        _sample_all(core, k)
        core.tick(k * core.h)
    x, P, k = core.estimator.x.copy(), core.estimator.P.copy(), core.k
    data = read_toml(packaged_config_path("thesis"))
    data["lqr"]["input_weight"] = {"Z": 1.0, "N": 0.1}
    tuned = design_config_from_dict(data, file="tuned.toml")
    K_before = core.design.controller.model.K.copy()
    core.apply(config=tuned)
    assert not np.allclose(core.design.controller.model.K, K_before)
    assert np.array_equal(core.estimator.x, x) and np.array_equal(core.estimator.P, P) and core.k == k
    bad = dict(data, measurements=[{"kind": "pressure", "quantity": "z"}])  # heading unobservable
    with pytest.raises(ConfigError, match="psi"):
        core.apply(config=design_config_from_dict(bad, file="bad.toml"))
    assert core.config is tuned
    slow = dict(data, sample_time=0.2)
    with pytest.raises(ConfigError, match="sample_time"):
        core.apply(config=design_config_from_dict(slow, file="slow.toml"))


def test_messages_are_the_simulators_topics(core):
    core.set_reference(z=0.5, psi=0.0)
    _sample_all(core, 0)
    out = core.tick(0.0)[0]
    topics = [m[0] for m in out.messages()]
    assert topics == ["/rovlab/estimate", "/rovlab/measurement", "/rovlab/reference", "/rovlab/command"]
    est = out.messages()[0][2]
    assert set(est["state"]) == set(core.states) and set(est["sensors"]) == {c.column for c in core.channels}
    assert set(out.messages()[3][2]["pwm_us"]) == set(core.thrusters)


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def _wrap(a):
    return np.remainder(np.asarray(a) + np.pi, 2 * np.pi) - np.pi


def test_node_closing_the_loop_on_a_simulated_vehicle_tracks_like_the_simulator():
    """Case study 2 (Sandøy 2016, sec. 5.3.1; scenario step-process-model): the node stepping a
    SimulatedVehicle (PWM in, samples out, as over a middleware) holds depth and heading as the
    compiled closed loop does: the same plant, sensors and components, split in two halves."""
    from rovlab.sim.realtime import SimulatedVehicle
    from rovlab.sim.runner import simulate

    sim = SimulatedVehicle("step-process-model")
    core = NodeCore(sim.prep.vehicle, sim.prep.config, pwm_resolution_us=sim.scenario.pwm_resolution_us,
                    log=lambda msg: None)
    n = int(round(sim.scenario.duration_s / sim.h)) + 1
    err = np.empty((n, 2))
    for k in range(n):
        s = sim.step()
        core.set_reference(z=s.reference[0], psi=s.reference[1])
        for sensor, quantity, value in s.samples:
            core.push(sensor, quantity, value, s.t)
        outs = core.tick(s.t + core.collect_s)
        assert [o.k for o in outs] == [k]
        sim.set_pwm(outs[-1].pwm_us)
        err[k] = s.truth["z"] - s.reference[0], _wrap(s.truth["psi"] - s.reference[1])
    c = simulate("step-process-model").columns
    batch = np.column_stack([c["true_z"] - c["ref_z"], _wrap(c["true_psi"] - c["ref_psi"])])
    for i in range(2):
        assert _rms(err[:, i]) == pytest.approx(_rms(batch[:, i]), rel=0.05)
        assert _rms(err[-100:, i]) < 2 * _rms(batch[-100:, i]) + 1e-3


def test_simulated_vehicle_refuses_bad_pwm():
    from rovlab.sim.realtime import SimulatedVehicle

    sim = SimulatedVehicle("step-process-model")
    with pytest.raises(ValueError, match="6 thrusters"):
        sim.set_pwm([1500.0] * 3)
    with pytest.raises(ValueError, match="finite"):
        sim.set_pwm([1500.0] * 5 + [float("nan")])
    assert np.array_equal(sim.pwm, sim.neutral_pwm)
    s = sim.step()
    assert s.k == 0 and {q for _, q, _ in s.samples} == {"z", "psi"}


def test_the_clock_can_wait_for_the_first_sample(udrone):
    """A node started before its sensors (wait_for_samples_s) runs no steps until the first sample
    or the wait is over, so its sensors are not timed out before they ever spoke."""
    core = NodeCore(*udrone, log=lambda msg: None, wait_for_samples_s=5.0)
    assert core.tick(0.0) == [] and core.tick(3.0) == []
    _sample_all(core, 0)  # stamps at 0: the first sample starts the clock
    outs = core.tick(0.0)
    assert [o.k for o in outs] == [0] and all(s == "ok" for s in outs[0].channel_status)
    late = NodeCore(*udrone, log=lambda msg: None, wait_for_samples_s=5.0)
    late.tick(100.0)
    assert late.tick(104.9) == [] and late.tick(105.0) == []  # no sensor: the clock starts after 5 s ...
    assert [o.k for o in late.tick(105.0 + late.collect_s)] == [0]  # ... and runs from there


def test_every_sample_is_used_when_several_arrive_in_one_period(udrone):
    """Issue 27 (real rates): ArduSub sends ATTITUDE at 20 Hz, the filter runs at 10 Hz. Fed two
    heading samples per period and one depth sample, the node fuses the older heading sample
    first (a correction only), then runs the step with the newest of each channel: exactly what
    the offline filter computes from the same samples as rows of one period
    (rovlab.estimation.offline.ComponentFilter with no prediction between the two rows)."""
    from rovlab.estimation.offline import ComponentFilter

    core = NodeCore(*udrone, log=lambda msg: None)
    h, m = core.h, len(core.channels)
    jz = next(j for j, c in enumerate(core.channels) if c.quantity == "z")
    jp = next(j for j, c in enumerate(core.channels) if c.quantity == "psi")
    rng = np.random.default_rng(7)
    n = 60
    psi = 0.3 + 0.002 * rng.standard_normal((n, 2))
    z = 1.0 + 0.003 * rng.standard_normal(n)
    rows_t, rows_y, npred = [], [], []
    node_x = np.empty((n, len(core.states)))
    for k in range(n):
        cz, cp = core.channels[jz], core.channels[jp]
        assert core.push(cz.sensor, cz.quantity, z[k] + cz.offset, k * h) == "accepted"  # the clock starts here
        assert core.push(cp.sensor, cp.quantity, psi[k, 0] + cp.offset, k * h - 0.25 * h) == "accepted"
        assert core.push(cp.sensor, cp.quantity, psi[k, 1] + cp.offset, k * h + 0.25 * h) == "accepted"
        outs = core.tick(k * h + core.collect_s + 1e-9)
        assert [o.k for o in outs] == [k]
        node_x[k] = outs[0].x
        first, second = np.full(m, np.nan), np.full(m, np.nan)
        first[jp] = psi[k, 0] + cp.offset
        second[jz], second[jp] = z[k] + cz.offset, psi[k, 1] + cp.offset
        rows_t += [k * h, k * h]
        rows_y += [first, second]
        npred += [0, 1]
    assert core.counters["extra_corrections"] == n and core.counters["replaced"] == 0
    offline = ComponentFilter(core.design.estimator)
    run = offline.run(np.array(rows_t), np.zeros((2 * n, offline.p)), np.array(rows_y), n_predict=np.array(npred))
    np.testing.assert_allclose(node_x, run.x[1::2], rtol=0, atol=1e-12)
    # and it is not what fusing only the newest heading sample gives
    alone = NodeCore(*udrone, log=lambda msg: None)
    for k in range(n):
        for j, v in ((jz, z[k]), (jp, psi[k, 1])):
            c = alone.channels[j]
            alone.push(c.sensor, c.quantity, v + c.offset, k * h)
        alone.tick(k * h + alone.collect_s + 1e-9)
    assert alone.last is not None and np.max(np.abs(alone.last.P - core.last.P)) > 1e-9


def test_a_flood_of_samples_for_one_step_keeps_the_newest(udrone):
    """More than ``max_queue`` samples of a channel for one step (a sensor stamping in a burst):
    the oldest are dropped and counted, the step still runs once with the newest."""
    core = NodeCore(*udrone, log=lambda msg: None, max_queue=4)
    c = core.channels[0]
    for i in range(10):
        assert core.push(c.sensor, c.quantity, 0.5 + c.offset, 0.001 * i) == "accepted"
    outs = core.tick(core.collect_s + 1e-9)
    assert [o.k for o in outs] == [0]
    assert core.counters["replaced"] == 6 and core.counters["extra_corrections"] == 3
    with pytest.raises(ValueError, match="max_queue"):
        NodeCore(*udrone, log=lambda msg: None, max_queue=0)


def test_a_late_sample_is_replaced_by_a_newer_one_not_fused_a_period_late(udrone):
    """A sample that arrived after its step ran is used at the next step only when no newer sample
    of its channel came (the real-time ROS nodes under load); samples of one period are all used."""
    core = NodeCore(*udrone, log=lambda msg: None)
    h = core.h
    _sample_all(core, 0)
    core.tick(0.0)
    c = core.channels[0]
    assert core.push(c.sensor, c.quantity, 0.5 + c.offset, 1 * h) == "accepted"  # step 1, not yet run
    core.tick(1 * h + core.collect_s + 1e-9)  # step 1 runs with it
    assert core.push(c.sensor, c.quantity, 0.5 + c.offset, 1.2 * h) == "accepted"  # late: period 1 ran
    assert core.push(c.sensor, c.quantity, 0.5 + c.offset, 2 * h) == "accepted"
    before = core.counters["extra_corrections"]
    core.tick(2 * h + core.collect_s + 1e-9)
    assert core.counters["replaced"] == 1 and core.counters["extra_corrections"] == before
