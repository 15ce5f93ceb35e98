"""The calibration report: a plain summary a user acts on (verdict, each parameter against
nominal in %, the multipliers, the sensor mounting in words) before the statistics, and noise
levels that sit at their floor printed as none."""

import dataclasses
import math
import re

import numpy as np
import pytest

from excite import Params, calibrate
from excite.calibration.report import WITHIN_STD, report, unsafe_reason, verdict
from excite.calibration.result import FitTest
from excite.core.information import DEFAULT_SIGMA
from excite.core.models import SensorPose
from excite.logs.synthetic import lesson_dataset
from tests.conftest import TRUTH, exact_segments


@pytest.fixture(scope="module")
def result():
    return calibrate(lesson_dataset(np.random.default_rng(5), 200, TRUTH))


def percent_lines(text: str) -> dict[str, tuple[float, str]]:
    """The parameter lines' change against nominal: {words: (percent, larger|smaller)}."""
    found = re.findall(r"^  (left wheel radius|right wheel radius|wheel separation) +\S+ m "
                       r"± \S+%: (\S+)% (larger|smaller) than nominal", text, re.M)
    return {words: (float(percent), how) for words, percent, how in found}


def test_the_report_leads_with_the_verdict_and_the_statistics_follow(result):
    lines = report(result).splitlines()
    assert lines[0].startswith("excite calibration: 200 segments")
    assert lines[1].startswith("verdict: calibrated: use these values")
    assert lines.index("statistics:") > 4
    statistics = "\n".join(lines[lines.index("statistics:"):])
    assert "sigma_min" in statistics and "sigma_min" not in "\n".join(lines[:5])
    assert result.summary() == report(result)


def test_each_parameter_against_nominal_in_percent_and_the_multipliers(result):
    # a nominal robot 3% larger in r_L, 2% smaller in r_R, b exactly the estimate
    estimate = result.params
    nominal = Params(estimate.r_L / 1.03, estimate.r_R / 0.98, estimate.b)
    text = result.summary(nominal)
    assert "verdict: calibrated: set these diff_drive_controller multipliers" in text
    changes = percent_lines(text)
    assert changes["left wheel radius"][1] == "larger"
    assert changes["left wheel radius"][0] == pytest.approx(3.0, abs=0.01)
    assert changes["right wheel radius"][1] == "smaller"
    assert changes["right wheel radius"][0] == pytest.approx(2.0, abs=0.01)
    assert re.search(r"wheel separation .*: as nominal to 0.01% \(\S+ m, within "
                     rf"{WITHIN_STD:g} std\)", text)
    radius = 0.5 * (nominal.r_L + nominal.r_R)  # the controller's one nominal radius
    multipliers = dict(re.findall(r"(\w+_multiplier) (\S+?)[,\s]", text))
    assert float(multipliers["left_wheel_radius_multiplier"]) == pytest.approx(
        estimate.r_L / radius, rel=1e-5)
    assert float(multipliers["right_wheel_radius_multiplier"]) == pytest.approx(
        estimate.r_R / radius, rel=1e-5)
    assert float(multipliers["wheel_separation_multiplier"]) == pytest.approx(1.0, rel=1e-5)


@pytest.mark.parametrize("pose, words", [
    (SensorPose(0.1234, -0.02, 0.5),
     ["12.34 ± ", "cm ahead of the axle midpoint", "2.00 ± ", "cm to the right",
      f"turned {math.degrees(0.5):.2f} ± ", "deg counter-clockwise (estimated)"]),
    (SensorPose(-0.05, 0.031, -1.2),
     ["5.00 ± ", "cm behind the axle midpoint", "3.10 ± ", "cm to the left",
      f"turned {math.degrees(1.2):.2f} ± ", "deg clockwise (estimated)"]),
])
def test_the_sensor_mounting_in_words(result, pose, words):
    moved = dataclasses.replace(result, model="sensor_pose", sensor_pose=pose,
                                sensor_pose_std=np.array([1e-4, 1e-4, 1e-3]))
    [line] = [line for line in moved.summary().splitlines() if "sensor mounting" in line]
    for word in words:
        assert word in line, line
    given = dataclasses.replace(moved, sensor_pose_std=None)
    assert "cm to the" in given.summary() and "(given)" in given.summary()
    assert "on the axle midpoint, facing forward" in result.summary()


def test_the_verdict_says_what_failed_and_the_export_is_unsafe(result):
    assert unsafe_reason(result) is None
    misfit = dataclasses.replace(result, fit=FitTest(ok=False, message="the wheels slip"))
    assert verdict(misfit).startswith("the model does not fit the data, do not use these")
    assert "the wheels slip" in verdict(misfit) and "the wheels slip" in unsafe_reason(misfit)
    weak = dataclasses.replace(result, identifiable=False,
                               unidentifiable_direction="b: no segment turns")
    assert verdict(weak).startswith("not determined (b: no segment turns)")
    assert "drive" in verdict(weak) and "b: no segment turns" in unsafe_reason(weak)
    assert report(misfit).splitlines()[1].startswith("verdict: the model does not fit")


def test_noise_levels_at_their_floor_print_as_none():
    """A noise-free log: every estimated level sits at its floor (1e-10 of the measured
    magnitudes), which the report prints as none and --json lists in levels_at_floor."""
    rng = np.random.default_rng(0)
    exact = calibrate(exact_segments(rng.normal(0, 8, 60), rng.normal(0, 8, 60)))
    assert exact.levels_at_floor == ("x", "y", "theta")
    assert "noise sigma     = x none, y none, theta none (estimated)" in exact.summary()
    assert exact.to_dict()["levels_at_floor"] == ["x", "y", "theta"]


def test_found_and_given_noise_levels_print_as_numbers(result):
    [noise] = [line for line in result.summary().splitlines() if "noise sigma" in line]
    assert result.levels_at_floor == () and "none" not in noise
    given = calibrate(lesson_dataset(np.random.default_rng(5), 200, TRUTH),
                      sigma=(2e-3, 2e-3, 1e-3))
    assert given.levels_at_floor == ()
    assert "noise sigma     = x 2.000e-03 m, y 2.000e-03 m, theta 1.000e-03 rad (given)" in (
        given.summary())


@pytest.mark.parametrize("n, words", [(4, "1 residual degree of freedom"),
                                      (12, "9 residual degrees of freedom")])
def test_a_calibration_from_few_segments_says_its_std_are_not_to_be_trusted(n, words):
    """With its noise levels estimated from fewer than 10 residual degrees of freedom per
    channel the std are themselves uncertain (4 segments: b 3.7 of its std off, reported as
    "calibrated"); given noise levels, or enough segments, the verdict is plain."""
    segments = lesson_dataset(np.random.default_rng(8), n, TRUTH, dphi_std=2.0)
    assert verdict(calibrate(segments, sensor_pose="axle")).startswith(
        f"calibrated from few segments: the noise levels, and the std with them, rest on "
        f"{words} per channel (at least 10 are needed")
    assert verdict(calibrate(segments, sigma=DEFAULT_SIGMA, sensor_pose="axle")) == (
        "calibrated: use these values (with the robot's nominal values, --init RL,RR,B, the "
        "report gives the diff_drive_controller multipliers to set)")
    enough = lesson_dataset(np.random.default_rng(8), 13, TRUTH, dphi_std=2.0)
    assert verdict(calibrate(enough, sensor_pose="axle")).startswith("calibrated: use")
