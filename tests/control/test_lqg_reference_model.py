"""The LQG law's optional depth reference model (rovlab.control.lqg, the [lqg] table; issue 28, item 3).

Without the table the law is the thesis's (Sandøy 2016, sec. 5.2) to the bit. With it the depth
set-point goes through MRAC's second-order reference model and the law follows its state with the
model's force, so on the exact model a stiff LQR follows z_m up to the sampling error instead of
jumping the step.
"""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.control import lqg, mrac
from rovlab.core.components import fresh
from rovlab.models.discretise import zoh
from rovlab.params.design import design_config_from_dict, load_design_config, packaged_config_path
from rovlab.params.validate import ConfigError, read_toml


def _config(lqg_table: dict | None, **top) -> object:
    data = read_toml(packaged_config_path("thesis"))
    if lqg_table is not None:
        data["lqg"] = lqg_table
    data.update(top)
    return design_config_from_dict(data, file="cfg.toml")


ON = {"source": "test", "reference_model": True, "bandwidth": 0.6, "damping": 1.0}


def test_without_the_table_the_law_is_the_thesis_law(udrone, rng):
    """The component's step equals lqg_tau (tau = P r - K x - b) at random estimates and references."""
    spec = lqg.build(udrone, load_design_config("thesis"))
    assert spec.state_names == () and spec.kernel.state.shape == (0,)
    ctrl = fresh(spec.kernel)
    for _ in range(20):
        nav = rng.normal(0.0, 1.0, 12)
        ref = rng.normal(0.0, 1.0, 4)
        tau = np.zeros(4)
        lqg._lqg_step(ctrl, 0.0, nav, ref, tau)
        x6 = nav[[2, 3, 6, 7, 10, 11]]
        expect = np.zeros(2)
        lqg.lqg_tau(spec.model.K, spec.model.P, x6, ref[[2, 3]], expect)
        assert tau[2] == expect[0] and tau[3] == expect[1]


def _track(udrone, cfg, h: float, n_s: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """Depth step 1.05 -> 0.70 m on the design's own linear heave model (m - Z_wdot, Z_w), the law
    sampled at h (ZOH) on the true z and w (no bias): (z, z_m) at every sample."""
    spec = lqg.build(udrone, cfg)
    ctrl = fresh(spec.kernel)
    mv = cfg.model_values(udrone)
    M, D = mv["m"] - mv["Z_wdot"], -mv["Z_w"]
    Phi, G = zoh(np.array([[0.0, 1.0], [0.0, -D / M]]), np.array([[0.0], [1.0 / M]]), h)
    Phi_m, G_m = zoh(*lqg.reference_model(0.6, 1.0), h)  # z_m, computed apart from the component
    x = np.array([1.05, 0.0])
    xm = x.copy()
    ref = np.array([0.0, 0.0, 0.70, 0.0])
    tau = np.zeros(4)
    zs, zms = [], []
    for k in range(int(round(n_s / h))):
        nav = np.zeros(12)
        nav[2], nav[6] = x
        zms.append(xm[0])
        zs.append(x[0])
        lqg._lqg_step(ctrl, k * h, nav, ref, tau)
        x = Phi @ x + G[:, 0] * tau[2]
        xm = Phi_m @ xm + G_m[:, 0] * 0.70
    return np.array(zs), np.array(zms)


def test_a_stiff_lqr_follows_the_reference_model_up_to_the_sampling_error(udrone):
    """The thesis's LQR made as stiff as MRAC (Q_z, Q_w of rovlab compare's lqg-matched) follows
    z_m within 1 cm at 10 Hz and more than 5x closer at 100 Hz; without the reference model the
    same LQR leaves z_m by more than 10 cm (it jumps the 0.35 m step)."""
    Q = np.array(load_design_config("thesis").lqr_Q)
    Q[0], Q[2] = 59.61, 17.87  # K = [160, 111.7] (tests/sim/test_compare_matched.py solves them)
    q = {"Q_diag": Q.tolist(), "R_diag": [1e-3, 10.132118364233778], "source": "test",
         "reference_gain": "continuous"}
    err = {}
    for h in (0.1, 0.01):
        cfg = _config(ON, sample_time=h, lqr=q)
        z, zm = _track(udrone, cfg, h)
        err[h] = float(np.max(np.abs(z - zm)))
    assert err[0.1] < 0.01
    assert err[0.01] < err[0.1] / 5.0
    z, zm = _track(udrone, _config(None, lqr=q), 0.1)
    assert float(np.max(np.abs(z - zm))) > 0.10


def test_the_reference_model_is_mracs(udrone):
    """Same omega and zeta: the LQG's z_m is MRAC's z_m (both start at the first estimate)."""
    cfg = _config({**ON, "bandwidth": 1.2, "damping": 0.7})
    a = fresh(lqg.build(udrone, cfg).kernel)
    data = read_toml(packaged_config_path("thesis"))
    data["mrac"] = {**data["mrac"], "bandwidth": 1.2, "damping": 0.7, "hedge": False, "max_step": 0.1}
    b = fresh(mrac.build(udrone, design_config_from_dict(data, file="m.toml")).kernel)
    nav = np.zeros(12)
    nav[2] = 1.0
    ref = np.array([0.0, 0.0, 1.3, 0.0])
    tau = np.zeros(4)
    for k in range(100):
        mrac._mrac_step(b, k * 0.1, nav, ref, tau)
        mrac._mrac_actuated(b, k * 0.1, tau, tau)
        lqg._lqg_step(a, k * 0.1, nav, ref, tau)
        assert a.state[0] == pytest.approx(b.state[4], abs=1e-12)
        assert a.state[1] == pytest.approx(b.state[5], abs=1e-12)


def test_summary_names_the_reference_model(udrone):
    from rovlab.core.components import component

    info = component("controller", "lqg")
    spec = lqg.build(udrone, _config(ON))
    s = info.summary(spec)
    assert s["reference_model"]["bandwidth"] == pytest.approx(0.6)
    assert s["reference_model"]["feedforward_M"] == pytest.approx(7.31 + 11.13)  # thesis appendix A.3
    assert "reference_model" not in info.summary(lqg.build(udrone, load_design_config("thesis")))
    assert spec.state_names == ("z_m", "w_m")


@pytest.mark.parametrize(("table", "key", "expected"), [
    ({**ON, "bandwith": 0.6}, "lqg.bandwith", "unknown"),
    ({**ON, "bandwidth": -1.0}, "lqg.bandwidth", "positive"),
    ({**ON, "reference_model": "yes"}, "lqg.reference_model", "true or false"),
    ({"reference_model": True}, "lqg.source", "a value"),
])
def test_bad_lqg_table_is_refused_with_its_key(table, key, expected):
    with pytest.raises(ConfigError) as info:
        _config(table)
    hits = [p for p in info.value.problems if p.key == key]
    assert hits and expected in hits[0].expected and hits[0].file == "cfg.toml"
