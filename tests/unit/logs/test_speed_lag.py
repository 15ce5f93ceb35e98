"""Integrated wheel speeds that a driver low-pass filtered (excite.logs.speed_lag): the lag
undone exactly, told apart from a clock offset, and calibrate right by default."""

from __future__ import annotations

import json

import numpy as np
import pytest

from excite import Params
from excite.cli import main
from excite.logs.speed_lag import lag_corrected, speed_lag
from excite.logs.synthetic import synthetic_log
from excite.logs.timeseries import TimeSeries, integrated_speed

TRUTH = Params(0.0495, 0.0506, 0.318)


def _moving_average(t: np.ndarray, w: np.ndarray, tau: float) -> tuple[np.ndarray, float]:
    """A driver's exponential moving average of the speeds ``w`` at their samples, of time
    constant ``tau`` (s), and its lag (1 - a) / a times the period (s)."""
    a = 1.0 - np.exp(-np.diff(t) / tau)
    out = np.empty_like(w)
    out[0] = w[0]
    for k in range(1, w.size):
        out[k] = out[k - 1] + a[k - 1] * (w[k] - out[k - 1])
    return out, float(np.median((1.0 - a) / a * np.diff(t)))


def _speed_log(seed: int, tau: float = 0.0, delay: float = 0.0) -> tuple[TimeSeries, float]:
    """A two-minute log of smooth driving (1 mm / 2 mrad pose noise) whose wheel angles are
    wheel speeds integrated: the angles' central differences, filtered with ``tau`` (s; 0:
    not), stamped ``delay`` s late; and the filter's lag (s)."""
    s = synthetic_log(np.random.default_rng(seed), 120.0, TRUTH, pose_noise=(1e-3, 2e-3)).series
    lag, wheels = 0.0, []
    for phi in (s.phi_L, s.phi_R):
        w = np.gradient(phi, s.t_enc)
        if tau:
            w, lag = _moving_average(s.t_enc, w, tau)
        wheels.append(integrated_speed(s.t_enc, w))
    return TimeSeries(s.t_enc + delay, *wheels, s.t_pose, s.x, s.y, s.theta,
                      speeds=True), lag


def test_the_correction_undoes_a_moving_average_at_the_samples_rate_exactly():
    s = synthetic_log(np.random.default_rng(0), 30.0, TRUTH).series
    w = np.gradient(s.phi_L, s.t_enc)
    filtered, lag = _moving_average(s.t_enc, w, 0.2)
    series = TimeSeries(s.t_enc, integrated_speed(s.t_enc, filtered),
                        integrated_speed(s.t_enc, filtered), s.t_pose, s.x, s.y, s.theta)
    corrected = lag_corrected(series, lag)
    np.testing.assert_allclose(np.diff(corrected.phi_L)[1:],
                               np.diff(integrated_speed(s.t_enc, w))[1:], rtol=0, atol=1e-9)
    assert not np.allclose(np.diff(series.phi_L), np.diff(integrated_speed(s.t_enc, w)),
                           rtol=0, atol=1e-3)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_lag_is_found_and_a_late_stamp_is_left_to_the_clock_offset(seed):
    for tau in (0.05, 0.2):
        series, lag = _speed_log(seed, tau)
        assert speed_lag(series) == pytest.approx(lag, rel=0.02)
    for delay in (0.0, 0.05, 0.2, -0.2):  # speeds not filtered: no lag
        assert speed_lag(_speed_log(seed, delay=delay)[0]) is None


def test_filtered_speeds_calibrate_right_by_default(capsys, tmp_path):
    """A log of speeds a driver filtered (0.2 s): calibrated right by default, with a note;
    a clock offset in its place (the only model before) leaves b several of its std off."""
    s = synthetic_log(np.random.default_rng(1), 120.0, TRUTH, pose_noise=(1e-3, 2e-3)).series
    speeds = [_moving_average(s.t_enc, np.gradient(phi, s.t_enc), 0.2)[0]
              for phi in (s.phi_L, s.phi_R)]
    rows = np.column_stack([s.t_enc, *speeds])
    np.savetxt(tmp_path / "filtered.csv", rows, delimiter=",", header="t,omega_L,omega_R",
               comments="", fmt="%.12g")
    np.savetxt(tmp_path / "poses.csv", np.column_stack([s.t_pose, s.x, s.y, s.theta]),
               delimiter=",", header="t,x,y,theta", comments="", fmt="%.12g")
    files = [str(tmp_path / "filtered.csv"), str(tmp_path / "poses.csv")]

    def z(options: list[str]) -> tuple[np.ndarray, dict, str]:
        code = main(["calibrate", *files, "--json", *options])
        captured = capsys.readouterr()
        assert code == 0, captured.err
        out = json.loads(captured.out)
        names = ("r_L", "r_R", "b")
        return (np.array([(out["params"][k] - getattr(TRUTH, k)) / out["std"][k]
                          for k in names]), out, captured.err)

    default, out, err = z([])
    assert np.all(np.abs(default) < 3), default
    assert "the wheel speeds lag the motion as a low-pass filter of time constant 0.19" in err
    assert "wheel speeds' lag 0.19" in out["inputs"][0]
    offset_only, _, _ = z(["--time-offset", "estimate"])
    assert abs(offset_only[2]) > 3, offset_only
