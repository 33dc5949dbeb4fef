"""``rovlab filter`` on hostile logs (issue 15 item 12; issue 16 part 3): refusals name file,
line/column, value and expectation with exit status 2; absurd gaps, sample times and values get a
bounded, explained behaviour; and a seeded mutation fuzzer finds no traceback."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.estimation.filtering import DepthHeadingFilter
from rovlab.estimation.streaming import StreamingFilter, plan_steps, steps_between
from rovlab.interfaces.cli import main
from rovlab.io.logreader import read_log
from rovlab.params.design import packaged_config_path

HEADER = "time_s,tau_Z,tau_N,z_qualisys,z_pressure,psi_qualisys"


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def _rows(n, h=0.1):
    return [f"{k * h:.6f},0,0,1.0,1.05,0.5" for k in range(n)]


def _write(path, rows):
    path.write_text(HEADER + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_plan_steps_never_overflows_and_bounds_the_work():
    n, restart, bad = plan_steps(np.array([0.1, 0.2, 1e18, 1e8, np.inf, 0.1]), 0.1, max_steps=10_000)
    assert bad is None and n.tolist() == [1, 2, 0, 0, 0, 1] and restart.tolist() == [0, 0, 1, 1, 1, 0]
    n, bad = steps_between(np.array([0.0, 1e18]), 0.1)  # no limit: refused, not an int64 overflow
    assert bad == 1


def test_a_gap_of_1e18_s_restarts_from_the_prior(capsys, tmp_path):
    rows = _rows(30)
    rows[20:] = [f"{k}e18,0,0,1.0,1.05,0.5" for k in (1, 2, 3)]  # 1e18 s: an int64 overflow in ns
    path = _write(tmp_path / "big.csv", rows)
    code, out, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"))
    assert code == 0, err
    assert "3 gap(s) longer than 10000 samples" in out
    assert "restarted from its prior at line 22, line 23, line 24" in out and "bridged" not in out
    est = read_log(tmp_path / "est.csv")
    assert np.all(np.isfinite(est["est_z"])) and np.all(np.isfinite(est["var_z"]))


def test_a_gap_of_1e8_s_is_quick(capsys, tmp_path):
    path = _write(tmp_path / "gap.csv", _rows(10) + [f"{1e8 + k * 0.1:.1f},0,0,1.0,1.05,0.5" for k in range(10)])
    code, out, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"))
    assert code == 0 and "restarted from its prior at line 12" in out, err


def test_a_sample_time_of_1e_7_s_is_refused_not_a_hang(capsys, tmp_path):
    # 1e6 predictions per row: refused by the configuration's plausible range, or (within the
    # range, or with --max-gap-steps below the log's step) by the restart budget; never a hang
    text = packaged_config_path("default").read_text(encoding="utf-8")
    cfg = tmp_path / "h7.toml"
    cfg.write_text(text.replace("sample_time = 0.1", "sample_time = 1e-7", 1), encoding="utf-8")
    path = _write(tmp_path / "log.csv", _rows(300))
    code, _, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"), "--config", str(cfg))
    assert code == 2 and "Traceback" not in err and "h7.toml" in err and "sample_time" in err, err
    assert not (tmp_path / "est.csv").exists()


def test_a_log_sampled_far_slower_than_the_filter_is_refused(capsys, tmp_path):
    path = _write(tmp_path / "slow.csv", _rows(300, h=1.0))  # 10 filter samples a row
    code, _, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"), "--max-gap-steps", "5")
    assert code == 2 and "Traceback" not in err
    assert "slow.csv: line 3, column 'time_s'" in err and "299 gaps longer than 5 filter samples" in err
    assert "h = 0.1 s" in err and "sample_time" in err
    assert not (tmp_path / "est.csv").exists()
    code, out, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"))
    assert code == 0 and "299 gap(s) in the log bridged by prediction" in out, err


def test_a_stuck_1e308_sample_does_not_poison_the_estimate(capsys, tmp_path):
    rows = _rows(400)
    for k in range(100, 400):  # pressure stuck at 1e308 for 30 s (far beyond reacquire_after_s)
        rows[k] = f"{k * 0.1:.6f},0,0,,1e308,0.5"
    path = _write(tmp_path / "stuck.csv", rows)
    code, out, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"))
    assert code == 0, err
    assert "300 value(s) beyond +-1e6 treated as faulty" in out and "300 not finite" in out
    est = read_log(tmp_path / "est.csv")
    for col in ("est_z", "est_psi", "est_w", "est_b_w", "var_z", "var_w"):
        assert np.all(np.isfinite(est[col])), col
    assert est.text["status_z_pressure"][-1] == "lost-nonfinite"


def test_absurd_values_count_as_faulty_in_the_streaming_filter(udrone):
    filt = DepthHeadingFilter.from_files("udrone", "default")
    s = StreamingFilter(filt)
    t = np.arange(50) * 0.1
    y = np.tile([1.0, 1.05, 0.5], (50, 1))
    y[10:, 1] = -1e300
    u = np.zeros((50, 2))
    u[5, 0] = 1e200  # an absurd input: held like a non-finite one
    runs = s.feed(t[:25], u[:25], y[:25]) + s.feed(t[25:], u[25:], y[25:], final=True)
    x = np.concatenate([r.x for r in runs])
    assert x.shape == (50, 6) and np.all(np.isfinite(x)) and s.absurd == 41
    whole = filt.run(t, np.where(np.abs(u) > 1e6, np.nan, u), np.where(np.abs(y) > 1e6, np.inf, y))
    np.testing.assert_allclose(x, whole.x, rtol=0, atol=1e-12)  # chunking changes nothing


def test_an_initial_depth_of_1e308_is_refused(capsys, tmp_path):
    text = packaged_config_path("default").read_text(encoding="utf-8")
    cfg = tmp_path / "z.toml"
    cfg.write_text(text.replace("state = {}", "state = { z = 1e308 }", 1), encoding="utf-8")
    path = _write(tmp_path / "log.csv", _rows(20))
    code, _, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"), "--config", str(cfg))
    assert code == 2 and "z.toml: initial.state.z: got 1e+308" in err and "expected" in err


@pytest.mark.parametrize("chunk_rows", [3, 64, 4096])
def test_streaming_equals_one_run_with_gaps(chunk_rows):
    filt = DepthHeadingFilter.from_files("udrone", "thesis")
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.choice([1, 1, 1, 2, 5], 300)) * filt.model.h
    u = rng.normal(0, [5.0, 0.02], (300, 2))
    u[rng.random(u.shape) < 0.05] = np.nan
    y = np.column_stack([1 + 1e-3 * rng.normal(size=300), 1.05 + 1e-2 * rng.normal(size=300),
                         0.9 + 1e-3 * rng.normal(size=300)])
    y[rng.random(y.shape) < 0.2] = np.nan
    n_predict, bad = steps_between(t, filt.model.h)
    whole = filt.run(t, u, y, n_predict=n_predict)
    s = StreamingFilter(filt)
    runs = []
    for a in range(0, 300, chunk_rows):
        runs += s.feed(t[a:a + chunk_rows], u[a:a + chunk_rows], y[a:a + chunk_rows], final=a + chunk_rows >= 300)
    np.testing.assert_allclose(np.concatenate([r.x for r in runs]), whole.x, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.concatenate([r.status for r in runs]), whole.status)


# --------------------------------------------------------------------------------------------
# fuzz: seeded mutations of a valid log
# --------------------------------------------------------------------------------------------

_TOKENS = ["", "nan", "inf", "-inf", "1_000", "\uff11\uff12", "1e400", "-1e400", "1e308", "-1e308", "5e-324",
           "abc", "0x10", "1e", "--1", "1.2.3", " 7 ", '"3"', '"a,b"', "\x00", "\u00a0", "NaN", "Infinity",
           "1e18", "-0", "9" * 400, "#", ";", "\t"]


def _mutate(lines: list[str], rng: np.random.Generator) -> str:
    lines = list(lines)
    for _ in range(int(rng.integers(1, 4))):
        op = int(rng.integers(0, 9))
        k = int(rng.integers(0, len(lines))) if lines else 0
        if not lines:
            lines = [""]
            continue
        if op <= 2:  # replace a cell
            cells = lines[k].split(",")
            cells[int(rng.integers(0, len(cells)))] = str(rng.choice(_TOKENS))
            lines[k] = ",".join(cells)
        elif op == 3:  # delete a line
            del lines[k]
        elif op == 4:  # duplicate a line
            lines.insert(k, lines[k])
        elif op == 5:  # swap two lines
            j = int(rng.integers(0, len(lines)))
            lines[k], lines[j] = lines[j], lines[k]
        elif op == 6:  # scale a time
            cells = lines[k].split(",")
            try:
                cells[0] = repr(float(cells[0]) * float(rng.choice([1e-300, 1e8, 1e18, 1e154, -1.0, 1.25])))
            except ValueError:
                pass
            lines[k] = ",".join(cells)
        elif op == 7:  # add or drop a field
            lines[k] = lines[k] + ",1" if rng.random() < 0.5 else lines[k].rsplit(",", 1)[0]
        else:  # truncate the file
            lines = lines[:k]
    return "\n".join(lines) + ("\n" if rng.random() < 0.8 else "")


def _fuzz(capsys, tmp_path, n, seed):
    base = [HEADER] + _rows(40)
    rng = np.random.default_rng(seed)
    log = tmp_path / "fuzz.csv"
    out = tmp_path / "est.csv"
    refused = 0
    for i in range(n):
        text = _mutate(base, rng)
        log.write_bytes(text.encode("utf-8") if rng.random() < 0.95 else text.encode("utf-8")[:-3] + b"\xff\n")
        code, _, err = run(capsys, "filter", str(log), "--out", str(out))
        assert code in (0, 2), (i, text, err)
        assert "Traceback" not in err, (i, text, err)
        if code == 2:
            refused += 1
            assert str(log) in err and "expected" in err, (i, text, err)
            located = "line " in err or any(w in err for w in ("empty file", "no data rows"))
            assert located, (i, text, err)
            assert not out.exists(), (i, text)
        else:
            est = read_log(out)
            assert all(np.all(np.isfinite(est[c])) for c in ("est_z", "est_psi", "var_z")), (i, text)
            out.unlink()
    return refused


def test_fuzz_filter_logs_small_budget(capsys, tmp_path):
    refused = _fuzz(capsys, tmp_path, n=60, seed=20161)
    assert 10 <= refused <= 60  # most mutants are refused, some are still valid logs


@pytest.mark.slow
def test_fuzz_filter_logs_long(capsys, tmp_path):
    _fuzz(capsys, tmp_path, n=3000, seed=15)



def test_every_sample_is_used_at_any_rate_and_jittered_times_are_fused_at_their_period(capsys, tmp_path):
    """Issue 27: channels at 20 Hz with the filter at 10 Hz (two samples a period), one at 10 Hz, and
    time stamps jittered by up to 40 % of h: every sample is fused, at the filter period nearest its
    time (several in one period one after another), none dropped, none refused."""
    rng = np.random.default_rng(27)
    t = np.arange(0.0, 30.0, 0.05) + rng.uniform(-0.02, 0.02, 600)  # 20 Hz, jittered
    t[0] = 0.0
    rows = []
    for k, tk in enumerate(t):
        # noise within the default configuration's variances (motion capture 4.5e-5 m, 1.3e-3 rad; pressure 1.1 cm)
        zq = f"{1.0 + 2e-5 * rng.standard_normal():.7f}"
        zp = f"{0.9535 + 0.005 * rng.standard_normal():.6f}" if k % 2 == 0 else ""  # 10 Hz; lever arm -0.0465 m
        psi = f"{0.5 + 5e-4 * rng.standard_normal():.6f}"
        rows.append(f"{tk:.6f},0,0,{zq},{zp},{psi}")
    path = _write(tmp_path / "fast.csv", rows)
    code, out, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"))
    assert code == 0, err
    assert "qualisys.z       600 samples, 600 used" in out and "pressure.z       300 samples, 300 used" in out
    assert "qualisys.psi     600 samples, 600 used" in out
    est = read_log(tmp_path / "est.csv")
    np.testing.assert_array_equal(est.time, np.round(t, 6))  # one estimate per row, at the row's time
    assert abs(est["est_z"][-1] - 1.0) < 0.02


def test_rows_of_one_period_are_fused_one_after_another_without_a_prediction_between():
    from rovlab.estimation.streaming import period_steps

    n, restart, bad = period_steps(np.array([0.0, 0.04, 0.1, 0.16, 0.33, 2.0]), 0.1, 0.0, max_steps=10)
    assert n.tolist() == [0, 1, 1, 1, 0] and restart.tolist() == [False, False, False, False, True] and bad is None
    # the grid is the log's: 0.33 s lies in period 3, 2.0 s in period 20 (17 periods later: a restart)
    n, restart, bad = period_steps(np.array([0.0, np.nan]), 0.1, 0.0)
    assert bad == 0
