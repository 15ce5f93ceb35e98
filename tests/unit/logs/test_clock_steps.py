"""Clock steps at a log's gaps (excite.logs.clock_steps): a stream's clock set while
recording, found from the motion on either side and corrected; what is no step left alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from excite.core.kinematics import Params
from excite.core.models import SensorPose
from excite.logs.clock_steps import STRETCH, corrected_clock_steps
from excite.logs.synthetic import synthetic_log


@pytest.fixture(scope="module")
def series():
    """90 s: 100 Hz encoders, 50 Hz poses with 2 mm / 2 mrad noise, the sensor off the axle,
    the clocks in step."""
    return synthetic_log(np.random.default_rng(3), 90.0, Params(0.05, 0.051, 0.3),
                         SensorPose(0.1, -0.03, 0.4), pose_noise=(0.002, 0.002)).series


def stepped(series, stream: str, at: float, step: float):
    """The log with the stamps of ``stream`` from ``at`` s after its start on moved by
    ``step`` s."""
    field = "t_enc" if stream == "encoder" else "t_pose"
    t = getattr(series, field).copy()
    t[t > series.t_enc[0] + at] += step
    return dataclasses.replace(series, **{field: t})


@pytest.mark.parametrize("stream, step", [("encoder", 0.3), ("pose", 0.2), ("encoder", 0.08),
                                          ("encoder", 2.0)])
def test_a_step_at_a_gap_is_found_and_corrected(series, stream, step):
    """Without the correction every segment after the step paired angles and poses of
    different times (a log with the encoders' clock 0.3 s ahead from half-way on moved the
    wheel radii by 6%, with a clean fit)."""
    corrected, notes = corrected_clock_steps(stepped(series, stream, 45.0, step))
    for name in ("t_enc", "t_pose"):
        np.testing.assert_allclose(getattr(corrected, name), getattr(series, name), atol=0.005)
    (note,) = notes
    found = float(note.split("step by ")[1].split(" s")[0])
    assert found == pytest.approx(step, abs=0.005)
    assert note.endswith(f"the later {stream} stamps are corrected by {-found:+.3f} s")


def test_what_is_no_clock_step(series):
    """The clocks in step; a gap of one stream with no step (a dropout); a pause of the
    recording (both streams) across which the clock jumps; a step too near the log's end to
    measure the offset after it: none is corrected."""
    assert corrected_clock_steps(series) == (series, [])
    enc = series.t_enc
    dropout = (enc < enc[0] + 40) | (enc > enc[0] + 40.5)
    gap = dataclasses.replace(series, t_enc=enc[dropout], phi_L=series.phi_L[dropout],
                              phi_R=series.phi_R[dropout])
    assert corrected_clock_steps(gap)[1] == []
    paused = stepped(stepped(series, "encoder", 45.0, 0.3), "pose", 45.0, 0.3)
    assert corrected_clock_steps(paused)[1] == []
    late = stepped(series, "encoder", 90.0 - STRETCH / 2, 0.3)
    assert corrected_clock_steps(late)[1] == []
    back = stepped(gap, "encoder", 40.5, -0.2)  # would widen the gap: not a forward step
    assert corrected_clock_steps(back)[1] == []
