"""The dead band's hysteresis in the PWM commands (issue 28: T4/T5 alternated ~1475/1525 us every
0.1 s on step-process-model, the dead-band inverse driven by noise on the heading demand).

rovlab.models.thruster_kernels.bank_pwm_hold_into keeps a thruster on its side of the dead band
until the other side's demand, summed while it waits, needs ``hold_us`` beyond that side's edge.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rovlab.models import thruster_kernels as tk
from rovlab.models.thrusters import ThrusterBank
from rovlab.params.design import design_config_from_dict, load_design_config
from rovlab.params.validate import ConfigError, read_toml
from rovlab.params.vehicle import load_vehicle
from rovlab.sim.prepare import prepare, reseed
from rovlab.sim.runner import run_prepared
from rovlab.sim.scenario import load_scenario


def _bank(name: str = "udrone") -> ThrusterBank:
    return ThrusterBank.from_vehicle(load_vehicle(name))


def _hold(bank: ThrusterBank, forces: np.ndarray, hold_us: float) -> tuple[np.ndarray, np.ndarray]:
    """PWM and the force each gives for a sequence of demands (rows), from neutral."""
    n = len(bank.names)
    side, sum_f = np.zeros(n), np.zeros(n)
    pwm, given = np.empty_like(forces), np.empty_like(forces)
    for k, f in enumerate(forces):
        f = f.copy()
        tk.bank_pwm_hold_into(bank.rows, bank.grid_pwm, bank.grid_force, f, side, sum_f, hold_us, pwm[k])
        given[k] = f
    return pwm, given


def sign_changes_per_s(pwm: np.ndarray, neutral: float, seconds: float) -> float:
    """Sign changes of a command's offset from neutral per second (neutral samples skipped)."""
    s = np.sign(np.asarray(pwm) - neutral)
    s = s[s != 0]
    return float(np.sum(s[1:] != s[:-1])) / seconds


@pytest.mark.parametrize("vehicle", ["udrone", "bluerov2_heavy"])  # quadratic fit and T200 table
def test_no_hysteresis_is_the_plain_inverse(vehicle):
    bank = _bank(vehicle)
    rng = np.random.default_rng(1)
    forces = rng.normal(0.0, 2.0, (200, len(bank.names))) * (rng.random((200, len(bank.names))) > 0.1)
    pwm, given = _hold(bank, forces, 0.0)
    for k in range(len(forces)):
        np.testing.assert_array_equal(pwm[k], tk.bank_pwm(bank.rows, bank.grid_pwm, bank.grid_force, forces[k]))
    np.testing.assert_array_equal(given, forces)


@pytest.mark.parametrize("vehicle", ["udrone", "bluerov2_heavy"])
def test_noise_about_zero_does_not_cross_the_dead_band(vehicle):
    """Demands alternating +-0.1 N: the plain inverse crosses the dead band at every step; with
    20 us of hysteresis the thruster stays on its first side, at its edge (no thrust) when the
    demand is for the other side, and says it gives nothing there."""
    bank = _bank(vehicle)
    forces = np.tile(np.array([[0.1], [-0.1]]), (50, len(bank.names)))
    neutral = bank.rows[:, tk.K_NEUTRAL]
    plain, _ = _hold(bank, forces, 0.0)
    held, given = _hold(bank, forces, 20.0)
    for i in range(len(bank.names)):
        assert sign_changes_per_s(plain[:, i], neutral[i], 1.0) == 99
        assert sign_changes_per_s(held[:, i], neutral[i], 1.0) == 0
    assert np.all(held[1::2] > neutral) and np.all(given[1::2] == 0.0)  # waits at the + edge
    edge = tk.bank_pwm(bank.rows, bank.grid_pwm, bank.grid_force, np.full(len(bank.names), tk.EDGE_FORCE))
    np.testing.assert_allclose(held[1::2], np.broadcast_to(edge, held[1::2].shape), atol=1e-6)
    real = tk.bank_force(bank.rows, bank.grid_pwm, bank.grid_force, held[1])
    assert np.all(np.abs(real) < 1e-6)  # the edge gives no thrust


def test_a_steady_small_demand_for_the_other_side_gets_through():
    """Summed while it waits, a steady -0.05 N (uDrone T4: 1.4 us beyond the reverse edge) switches
    the thruster once the sum needs 20 us (0.78 N: the 16th sample) and is then given in full;
    noise about zero would have to add up that far by chance."""
    bank = _bank("udrone")
    n = len(bank.names)
    forces = np.vstack([np.full((1, n), 0.5), np.full((40, n), -0.05)])
    pwm, given = _hold(bank, forces, 20.0)
    i = bank.names.index("T4")
    row = bank.rows[i]
    sums = -0.05 * np.arange(1, 41)
    beyond = np.array([abs(tk._quad_pwm(row, s) - (row[tk.K_NEUTRAL] - row[tk.K_DEAD])) for s in sums])
    first = int(np.argmax(beyond >= 20.0)) + 1  # row of forces where the sum first needs 20 us
    assert first == 16
    assert np.all(given[1:first, i] == 0.0) and np.all(given[first:, i] == -0.05)
    assert np.all(pwm[first:, i] < row[tk.K_NEUTRAL] - row[tk.K_DEAD])


def test_a_large_demand_switches_at_once_and_zero_is_neutral():
    bank = _bank("udrone")
    n = len(bank.names)
    forces = np.vstack([np.full((1, n), 0.5), np.full((1, n), -3.0), np.zeros((1, n)), np.full((1, n), 0.01)])
    pwm, given = _hold(bank, forces, 20.0)
    np.testing.assert_array_equal(given, forces)
    np.testing.assert_array_equal(pwm[2], bank.rows[:, tk.K_NEUTRAL])  # zero: neutral, the side forgotten


def _step_process(hold_us: float | None, seed: int):
    prep = reseed(prepare(load_scenario("step-process-model")), seed)
    if hold_us is not None:
        prep = replace(prep, actuators=prep.actuators._replace(hold_us=hold_us))
    return run_prepared(prep)


def test_step_process_model_chatter_reproducer():
    """Issue 28's reproducer: with the thesis design's 20 us, uDrone's surge pair changes sign
    under 1 time per second (without: > 4 per second, a square wave of ~50 us) and the depth and
    heading tracking over 6 seeds stays within 3 % of the plain inverse's (50 runs in
    docs/simulation.md: 5.35 -> 0.17 per second, psi tracking 15.56 -> 15.42 deg)."""
    assert load_design_config("thesis").pwm_hysteresis_us == 20.0
    ms: dict[str, list[float]] = {"z0": [], "z1": [], "psi0": [], "psi1": []}
    for seed in range(2000, 2006):
        before, after = _step_process(0.0, seed), _step_process(None, seed)
        t = after.columns["time_s"]
        for name in ("T4", "T5"):
            assert sign_changes_per_s(before.columns[f"pwm_{name}"], 1500.0, t[-1]) > 4.0
            assert sign_changes_per_s(after.columns[f"pwm_{name}"], 1500.0, t[-1]) < 1.0
        for axis in ("z", "psi"):
            for tag, run in (("0", before), ("1", after)):
                e = run.columns[f"true_{axis}"] - run.columns[f"ref_{axis}"]
                ms[axis + tag].append(float(np.sqrt(np.mean(e ** 2))))
    for axis in ("z", "psi"):
        assert np.mean(ms[axis + "1"]) < 1.03 * np.mean(ms[axis + "0"]), (axis, ms)


def test_each_run_starts_at_neutral():
    """A Monte Carlo shares one Prepared between its runs: the thrusters' dead-band side is each
    run's own (rovlab.sim.actuators.fresh_actuators), so a run does not depend on the one before."""
    prep = prepare(load_scenario("step-process-model"))
    a, b = run_prepared(prep), run_prepared(prep)
    np.testing.assert_array_equal(a.columns["pwm_T4"], b.columns["pwm_T4"])
    np.testing.assert_array_equal(prep.actuators.side, 0.0)


def test_observer_plant_and_dp_designs_have_none():
    """The observer plant (the thesis's perfect model) has no ESCs; the DP designs keep the plain
    inverse (the hysteresis cost uDrone's station keeping 4.5 -> 15 mm at 20 us)."""
    assert prepare(load_scenario("step-observer-model")).actuators.hold_us == 0.0
    assert prepare(load_scenario("step-process-model")).actuators.hold_us == 20.0
    assert prepare(load_scenario("dp-station-keeping")).actuators.hold_us == 0.0


def test_a_vehicle_node_commands_what_the_simulator_does():
    """The node builds its actuators from the design (rovlab.interfaces.node.core): the design's
    allocator carries the hysteresis, so the node's PWM is the simulator's
    (tests/interfaces/test_node_core.py compares them sample by sample on the dropout scenario)."""
    from rovlab.interfaces.node.core import NodeCore

    core = NodeCore(load_vehicle("udrone"), load_design_config("thesis"), log=lambda msg: None)
    assert core.actuators.hold_us == 20.0
    core = NodeCore(load_vehicle("udrone_dvl"), load_design_config("udrone_dp"), log=lambda msg: None)
    assert core.actuators.hold_us == 0.0


@pytest.mark.parametrize("value", [-1.0, 1e6, "20"])
def test_bad_hysteresis_is_refused_with_the_key(value):
    data = read_toml(load_design_config("thesis").file)
    data["pwm_hysteresis_us"] = value
    with pytest.raises(ConfigError, match="pwm_hysteresis_us"):
        design_config_from_dict(data, file="mine.toml")
