"""Pose samples a source held while it lost the body (excite.logs.continuity.stale_poses):
exact repeats while the wheels turned; a robot standing still may repeat its pose."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from excite.core.kinematics import Params
from excite.core.models import SensorPose
from excite.logs.continuity import stale_poses
from excite.logs.inputs import LogOptions, group_inputs, read_log
from excite.logs.synthetic import synthetic_log
from excite.logs.timeseries_csv import write_timeseries


@pytest.fixture(scope="module")
def series():
    """60 s of driving: 100 Hz encoders, 50 Hz poses with 2 mm / 2 mrad noise."""
    return synthetic_log(np.random.default_rng(5), 60.0, Params(0.05, 0.051, 0.3),
                         SensorPose(0.1, -0.03, 0.4), pose_noise=(0.002, 0.002)).series


def held(series, start: int, stop: int, value=None):
    """The log with pose samples start..stop-1 all equal to ``value`` (x, y, theta), or to the
    sample before them (a frozen source)."""
    x, y, theta = series.x.copy(), series.y.copy(), series.theta.copy()
    hold = value if value is not None else (x[start - 1], y[start - 1], theta[start - 1])
    x[start:stop], y[start:stop], theta[start:stop] = hold
    return dataclasses.replace(series, x=x, y=y, theta=theta)


def test_a_frozen_source_and_a_placeholder_are_stale(series):
    """Frozen for 0.5 s (the last pose held): the repeats go, the last real sample stays. A
    placeholder at the origin for 1 s (the pose jumped there): all of it goes."""
    frozen = held(series, 1000, 1025)
    np.testing.assert_array_equal(stale_poses(frozen), np.arange(1000, 1025))
    origin = held(series, 1500, 1550, (0.0, 0.0, 0.0))
    np.testing.assert_array_equal(stale_poses(origin), np.arange(1500, 1550))
    assert stale_poses(series).size == 0


def test_a_robot_standing_still_may_repeat_its_pose(series):
    """A noise-free pose source while the wheels stand still repeats its pose exactly: kept."""
    phi_L, phi_R = series.phi_L.copy(), series.phi_R.copy()
    t0, t1 = series.t_pose[999], series.t_pose[1025]
    still = (series.t_enc >= t0) & (series.t_enc <= t1)
    phi_L[still], phi_R[still] = phi_L[still][0], phi_R[still][0]
    standing = dataclasses.replace(held(series, 1000, 1026), phi_L=phi_L, phi_R=phi_R)
    assert stale_poses(standing).size == 0


def test_read_log_leaves_stale_poses_out_with_a_note(tmp_path, series):
    path = tmp_path / "frozen.csv"
    write_timeseries(path, held(series, 1000, 1025))
    notes = []
    log = read_log(group_inputs([str(path)])[0], LogOptions(), on_note=notes.append)
    assert log.series.t_pose.size == series.t_pose.size - 25
    assert notes[0] == (f"{path}: 25 pose samples repeat the one before them exactly while the "
                        "wheels turned (a pose source that froze, or held a placeholder while it "
                        "lost the body): left out")


def test_a_coarse_pose_source_that_repeats_while_creeping_is_not_stale(tmp_path):
    """A logger that writes cm (or mm) at 50 Hz while the robot creeps at 0.1 m/s repeats its
    pose for several samples: its resolution, not a frozen source (a review found 3397 of
    6001 such poses dropped, r_L 20 std off). Nothing is left out, and a full-row file of it
    is read as it is (no held values either)."""
    for rate, decimals in ((50, 2), (100, 3)):  # 100 Hz: every row full
        log = synthetic_log(np.random.default_rng(5), duration=120, speed=0.1, turn_rate=0.2,
                            pose_rate=rate).series
        coarse = dataclasses.replace(log, x=np.round(log.x, decimals),
                                     y=np.round(log.y, decimals),
                                     theta=np.round(log.theta, decimals))
        assert stale_poses(coarse).size == 0
        path = tmp_path / f"coarse{decimals}.csv"
        write_timeseries(path, coarse)
        notes = []
        read = read_log(group_inputs([str(path)])[0], LogOptions(), on_note=notes.append)
        assert read.series.t_pose.size == coarse.t_pose.size and notes == []
