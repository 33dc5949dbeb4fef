"""Every band a figure shades says what it is (issue 28, a new user: the +-2 sigma band of the
bias estimates and the +-1 cm band of the controller comparison had no legend entry; the +-1
sigma lines of the noise figure neither). Each figure is caught as it is saved, and every shaded
area (fill_between, axhspan, axvspan) of every axis must be named in that axis's legend."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Polygon, Rectangle  # noqa: E402


@pytest.fixture
def saved(monkeypatch):
    """The figures saved while the test runs (nothing is drawn or written)."""
    figures: list[Figure] = []

    def savefig(self, *args, **kwargs):
        figures.append(self)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figures


def _legend_texts(ax) -> list[str]:
    legend = ax.get_legend()
    return [t.get_text() for t in legend.get_texts()] if legend is not None else []


def _unnamed_bands(fig: Figure) -> list[str]:
    """'<figure title> / <axis label>: <artist>' for every shaded area not named in its axis's legend."""
    out = []
    title = fig._suptitle.get_text() if fig._suptitle is not None else ""
    for ax in fig.axes:
        texts = _legend_texts(ax)
        bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
        bands += [p for p in ax.patches if isinstance(p, (Rectangle, Polygon))]
        for band in bands:
            label = band.get_label()
            if label.startswith("_") or label not in texts:
                out.append(f"{title or ax.get_title()} / {ax.get_ylabel()}: {type(band).__name__} {label!r}")
    return out


def test_run_figures_name_every_band(saved, tmp_path):
    from rovlab.io.report import write_figures
    from rovlab.sim.runner import simulate

    for name in ("dropout", "dp-mocap-dropout"):  # the depth-and-heading KF and the 4-DOF EKF
        result = simulate(name, seed=3)
        write_figures(tmp_path, result.columns, result.meta)
    assert len(saved) >= 4 + 6
    shaded = [f for f in saved if any(isinstance(c, PolyCollection) for ax in f.axes for c in ax.collections)]
    assert len(shaded) >= 4  # states, biases and planar of the EKF, states and biases of the KF
    problems = [p for f in saved for p in _unnamed_bands(f)]
    assert problems == []


def test_comparison_figure_names_its_settling_band(saved, tmp_path):
    from types import SimpleNamespace

    from rovlab.sim.compare import BAND_M, figure

    t = np.arange(0.0, 60.0, 0.1)
    zm = 0.7 + 0.35 * np.exp(-t / 5.0)
    cols = {"time_s": t, "ref_z": np.full_like(t, 0.7), "refmodel_z": zm, "true_z": zm + 0.005 * np.sin(t),
            "tau_Z": np.zeros_like(t), "est_b_w": np.zeros_like(t), "true_b_w": np.zeros_like(t)}
    figure(tmp_path / "c.png", {"change_s": 40.0, "scenario": "s", "seeds": [1]},
           {"lqg": [SimpleNamespace(columns=cols)]})
    (fig,) = saved
    assert _unnamed_bands(fig) == []
    error_axis = fig.axes[1]
    assert any(f"{100 * BAND_M:g} cm" in text for text in _legend_texts(error_axis))


def test_noise_figure_names_its_sigma_lines(saved, tmp_path):
    from rovlab.ident import noise, plots

    rng = np.random.default_rng(7)
    t = np.arange(600) * 0.1
    est = noise.noise_variances(t, {"z_pressure": 1.0 + 0.01 * rng.standard_normal(t.size),
                                    "r_imu": 0.002 * rng.standard_normal(t.size)})
    plots.plot_noise(est, tmp_path / "n.png")
    (fig,) = saved
    residual_axes = fig.axes[0::2]
    for ax in residual_axes:
        assert any("1σ" in text for text in _legend_texts(ax)), ax.get_ylabel()
    # and the yaw rate's variance is in rad^2/s^2 (it read rad/s², the square of the rate's unit wrongly placed)
    notes = [t.get_text() for ax in residual_axes for t in ax.texts]
    assert any("rad^2/s^2" in n for n in notes) and any(" m^2 " in n for n in notes), notes
