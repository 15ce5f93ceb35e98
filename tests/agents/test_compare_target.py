"""``excite compare --target``: episodes end at the stopping rule's stop or at the budget, the
record, resume and summary of the time to target, the false stops and the error at the stop."""

import contextlib
import io
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from agents.catalog import make_protocol
from agents.compare import (
    COLUMNS,
    CompareError,
    CompareSettings,
    columns_of,
    make_env,
    read_complete_rows,
    run_comparison,
    run_protocol_episode,
    settings_dict,
)
from agents.metrics import rate_interval
from agents.segment_record import by_episode
from agents.summary import summarize
from agents.target_record import BATCH_ERRORS, TARGET_COLUMNS, false_stops, stops_of, target_fields
from agents.target_summary import add_target
from excite.cli import main
from excite.core.kinematics import Params
from excite.core.models import SensorPose
from excite.stopping import StoppingRule

IDEAL = "excite/DiffDriveCalibIdeal-v0"
TARGET, BUDGET, EPISODES = 0.02, 20, 3


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    """One ``excite compare --target`` of arcs (stops within a few segments on the ideal env)
    and spin (never determines the scale of r_L, r_R, b: censored at the budget)."""
    out = tmp_path_factory.mktemp("target")
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(io.StringIO()):
        code = main(["compare", "--protocols", "arcs,spin", "--episodes", str(EPISODES),
                     "--segments", str(BUDGET), "--env", IDEAL, "--target", str(TARGET),
                     "--workers", "1", "--seed", "3", "--out", str(out)])
    assert code == 0
    rows = read_complete_rows(out / "segments.csv", BUDGET, target=True)
    return SimpleNamespace(out=out, table=stdout.getvalue(), rows=rows,
                           summary=json.loads((out / "summary.json").read_text()))


def _episodes(rows, protocol):
    by = {}
    for row in rows:
        if row["protocol"] == protocol:
            by.setdefault(row["episode"], []).append(row)
    return [sorted(group, key=lambda r: r["segment"]) for _, group in sorted(by.items())]


@pytest.mark.slow
def test_episodes_end_at_their_stop_or_at_the_budget(cli_run):
    header = (cli_run.out / "segments.csv").read_text().splitlines()[0].split(",")
    assert tuple(header) == COLUMNS + TARGET_COLUMNS
    arcs, spin = _episodes(cli_run.rows, "arcs"), _episodes(cli_run.rows, "spin")
    assert len(arcs) == len(spin) == EPISODES
    for episode in arcs:  # stopped: once, at the last segment, before the budget
        assert [r["stop"] for r in episode] == [0] * (len(episode) - 1) + [1]
        assert len(episode) < BUDGET
    for episode in spin:  # never stops: censored at the budget
        assert len(episode) == BUDGET and not any(r["stop"] for r in episode)


@pytest.mark.slow
def test_summary_keys_censoring_and_false_stops_by_hand(cli_run):
    pairs = cli_run.summary["protocols"]
    entry = pairs["arcs"]["online"]["target"]
    assert set(entry) == {"value", "confidence", "budget", "time_to_target",
                          "false_stop_rate", "error_at_stop"}
    assert (entry["value"], entry["confidence"], entry["budget"]) == (TARGET, 0.95, BUDGET)
    assert set(entry["time_to_target"]) == {"segments", "seconds", "metres", "censored"}
    assert set(entry["false_stop_rate"]) == {"rate", "ci95", "false_stops", "stops"}
    assert cli_run.summary["settings"]["target"] == TARGET
    # by hand from the rows: each arcs episode's last row
    last = [episode[-1] for episode in _episodes(cli_run.rows, "arcs")]
    false = sum(any(abs(r[c]) > TARGET for c in BATCH_ERRORS if not math.isnan(r[c]))
                for r in last)
    assert entry["false_stop_rate"]["false_stops"] == false
    assert entry["false_stop_rate"]["stops"] == EPISODES
    assert entry["time_to_target"]["censored"] == 0
    assert entry["time_to_target"]["segments"]["median"] == np.median(
        [r["segment"] for r in last])
    errors = [max(abs(r["batch_r_L_err"]), abs(r["batch_r_R_err"]), abs(r["batch_b_err"]))
              for r in last]
    assert entry["error_at_stop"]["median"] == pytest.approx(np.median(errors))
    spin = pairs["spin"]["online"]["target"]
    assert spin["time_to_target"]["censored"] == EPISODES
    assert spin["time_to_target"]["segments"] == {"median": None, "ci95": [None, None],
                                                  "at_least": BUDGET}
    assert spin["false_stop_rate"] == {"rate": None, "ci95": [0.0, 1.0], "false_stops": 0,
                                       "stops": 0}
    assert f">{BUDGET}({EPISODES})" in cli_run.table and "false stops" in cli_run.table
    formats = (Path(__file__).resolve().parents[2] / "docs" / "formats.md").read_text()
    for key in [*entry, *entry["time_to_target"], *entry["false_stop_rate"], "vs_reference",
                "at_least", *TARGET_COLUMNS]:
        assert f"`{key}`" in formats, key


@pytest.mark.slow
def test_survival_png_is_written(cli_run):
    from matplotlib.image import imread

    image = imread(cli_run.out / "target_survival.png")
    assert image.shape[0] > 100 and image.std() > 0.01


@pytest.mark.slow
def test_paired_ratio_of_time_to_target_against_the_reference(cli_run):
    """spin's median is censored, arcs' is not: the ratio is only bounded, by arcs' median
    over the budget."""
    columns = columns_of(cli_run.rows)
    summary = add_target(summarize(columns, n_boot=200, reference="arcs"), columns, TARGET,
                         0.95, BUDGET, n_boot=200)
    ratio = summary["protocols"]["spin"]["online"]["target"]["vs_reference"]
    stops = [episode[-1]["segment"] for episode in _episodes(cli_run.rows, "arcs")]
    assert ratio["episodes"] == EPISODES
    assert ratio["time_to_target"] == {"ratio": None, "ci95": [None, None],
                                       "at_most": pytest.approx(np.median(stops) / BUDGET)}


@pytest.mark.slow
def test_the_record_holds_the_rules_batch_calibration_at_the_stop():
    env = make_env(IDEAL, BUDGET, target=TARGET)
    records = run_protocol_episode(env, make_protocol("arcs"), seed=7)
    base = env.unwrapped
    assert records[-1]["stop"] == 1 and base.last_stop.done
    decision = StoppingRule(TARGET, sensor_pose="axle").decide(base.rule_segments,
                                                              nominal=base.nominal_theta[:3])
    assert decision.done
    expected = decision.result.params.as_array() / base.true_params.as_array() - 1.0
    np.testing.assert_allclose([records[-1][c] for c in BATCH_ERRORS[:3]], expected,
                               rtol=1e-9, atol=1e-12)
    assert all(math.isnan(records[-1][c]) for c in BATCH_ERRORS[3:])  # the axle model
    env.close()


@pytest.mark.slow
def test_resume_keeps_stopped_episodes_drops_partial_ones_and_refuses_another_target(tmp_path):
    settings = CompareSettings(IDEAL, BUDGET, 1, target=TARGET)
    run_comparison(tmp_path, ["arcs"], 2, settings, workers=1, progress=False)
    first = read_complete_rows(tmp_path / "segments.csv", BUDGET, target=True)
    with open(tmp_path / "segments.csv", "a") as handle:  # an interrupted episode 2
        handle.write("arcs,online,2,1" + ",0" * (len(COLUMNS + TARGET_COLUMNS) - 4) + "\n")
    assert {r["episode"] for r in read_complete_rows(tmp_path / "segments.csv", BUDGET,
                                                     target=True)} == {0, 1}
    rows = run_comparison(tmp_path, ["arcs"], 3, settings, workers=1, progress=False)
    assert repr(rows[:len(first)]) == repr(first)  # kept as they were (nan too)
    assert {r["episode"] for r in rows} == {0, 1, 2}
    keys = [(r["episode"], r["segment"]) for r in rows]
    assert len(keys) == len(set(keys))
    for other in (CompareSettings(IDEAL, BUDGET, 1, target=0.01),
                  CompareSettings(IDEAL, BUDGET, 1, target=TARGET, target_confidence=0.9),
                  CompareSettings(IDEAL, BUDGET, 1)):
        with pytest.raises(CompareError, match="other settings"):
            run_comparison(tmp_path, ["arcs"], 1, other, progress=False)


def test_settings_without_a_target_are_stored_as_before():
    assert set(settings_dict(CompareSettings())) == {"env_id", "segments", "seed", "robot",
                                                     "stream", "final_only"}
    assert settings_dict(CompareSettings(target=0.01))["target"] == 0.01


def _stop(done=True, params=(0.05, 0.05, 0.3), pose=None):
    result = SimpleNamespace(params=Params(*params),
                             sensor_pose=None if pose is None else SensorPose(*pose))
    return SimpleNamespace(done=done, statistic=0.5, result=result)


def test_target_fields_by_hand():
    truth = np.array([0.05, 0.05, 0.3, 0.1, 0.0, 3.1])
    env = SimpleNamespace(unwrapped=SimpleNamespace(
        true_theta=truth, last_stop=_stop(params=(0.051, 0.049, 0.3),
                                          pose=(0.103, -0.006, -3.1))))
    fields = target_fields(env)
    assert fields["stop"] == 1
    np.testing.assert_allclose([fields[c] for c in BATCH_ERRORS],
                               [0.02, -0.02, 0.0, 0.01, -0.02, 2 * math.pi - 6.2], atol=1e-12)
    env.unwrapped.last_stop = None  # before the first segment
    assert target_fields(env)["stop"] == 0 and math.isnan(target_fields(env)["batch_b_err"])


def _columns(episodes):
    """A segment record of one pair from (segments, stop at the end?, batch errors there)."""
    rows = []
    for e, (segments, stopped, errors) in enumerate(episodes):
        for k in range(1, segments + 1):
            end = k == segments
            rows.append({"protocol": "p", "estimator": "online", "episode": e, "segment": k,
                         "time": 2.0 * k, "distance": 0.5 * k,
                         "stop": int(stopped and end),
                         **{c: errors.get(c, math.nan) if end else 0.5
                            for c in BATCH_ERRORS}})
    return {key: np.array([row[key] for row in rows]) for key in rows[0]}


def test_false_stops_and_time_to_target_by_hand():
    columns = _columns([
        (4, True, {"batch_r_L_err": 0.001, "batch_r_R_err": -0.003, "batch_b_err": 0.002}),
        (6, True, {"batch_r_L_err": 0.001, "batch_r_R_err": 0.0, "batch_b_err": -0.006}),
        (3, True, {"batch_r_L_err": 0.0, "batch_r_R_err": 0.0, "batch_b_err": 0.0,
                   "batch_x_err": 0.0, "batch_y_err": 0.0051, "batch_theta_err": 0.0}),
        (10, False, {}),
    ])
    stops = stops_of(columns, "p", "online")
    np.testing.assert_array_equal(stops.stopped, [True, True, True, False])
    np.testing.assert_array_equal(false_stops(columns, stops, 0.005),
                                  [False, True, True, False])
    np.testing.assert_array_equal(stops.to_target(stops.segments), [4, 6, 3, np.inf])
    np.testing.assert_array_equal(stops.to_target(stops.metres), [2.0, 3.0, 1.5, np.inf])
    summary = {"protocols": {"p": {"online": {}}}, "reference": None}
    entry = add_target(summary, columns, 0.005, 0.95, 10, n_boot=100)[
        "protocols"]["p"]["online"]["target"]
    assert entry["time_to_target"]["segments"]["median"] == 5.0  # of 3, 4, 6, inf
    assert entry["time_to_target"]["seconds"]["median"] == 10.0
    assert entry["time_to_target"]["censored"] == 1
    rate = entry["false_stop_rate"]
    assert (rate["false_stops"], rate["stops"], rate["rate"]) == (2, 3, 2 / 3)
    assert rate["ci95"] == list(rate_interval(2, 3)[1])
    assert entry["error_at_stop"]["median"] == 0.003  # of 0.003, 0.006, 0
    assert entry["error_at_stop"]["stops"] == 3


def test_an_episode_that_stopped_keeps_its_last_value_in_the_matrix():
    columns = _columns([(2, True, {}), (4, False, {})])
    columns["value"] = np.array([1.0, 2.0, 5.0, 6.0, 7.0, 8.0])
    _, segments, matrix = by_episode(columns, np.ones(6, bool), columns["value"])
    np.testing.assert_array_equal(segments, [1, 2, 3, 4])
    np.testing.assert_array_equal(matrix, [[1, 2, 2, 2], [5, 6, 7, 8]])


def test_rate_interval_is_wilsons():
    rate, (low, high) = rate_interval(0, 4)
    assert rate == 0.0 and low == 0.0 and high == pytest.approx(0.4899, abs=1e-4)
    # Wilson by hand: centre (p + z^2/2n) / (1 + z^2/n), half z sqrt(p q / n + z^2/4n^2) / (...)
    z, n, p = 1.959963985, 40, 3 / 40
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    assert rate_interval(3, 40)[1] == pytest.approx((centre - half, centre + half), rel=1e-6)
    assert rate_interval(0, 0) == (None, (0.0, 1.0))


def test_the_target_budget_matches_the_env():
    from envs.config import TARGET_BUDGET
    from excite.commands.options import TARGET_SEGMENTS

    assert TARGET_SEGMENTS == TARGET_BUDGET


@pytest.mark.parametrize("argv, fragment", [
    (["--target", "0"], "--target: must be a relative error strictly between 0 and 1"),
    (["--target", "1.5"], "--target: must be a relative error strictly between 0 and 1"),
    (["--target", "half"], "--target: not a number"),
    (["--target", "0.01", "--target-confidence", "1"], "--target-confidence: must be"),
    (["--target-confidence", "0.9"], "--target-confidence needs --target"),
])
def test_bad_target_options_are_one_line_errors(tmp_path, capsys, argv, fragment):
    code = main(["compare", "--protocols", "spin", "--out", str(tmp_path / "out"), *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("excite: error: ")
    assert fragment in err[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_the_single_and_the_vector_env_keep_the_rules_last_decision():
    import gymnasium as gym

    drive = [np.array(a) for a in ([0.3, 0.15], [0.15, 0.3], [-0.2, 0.2], [0.2, -0.2])]
    env = gym.make(IDEAL, target=TARGET, budget=8)
    env.reset(seed=2)
    assert env.unwrapped.last_stop is None
    vec = gym.make_vec(IDEAL, num_envs=2, target=TARGET, budget=8)
    vec.reset(seed=[2, 3])
    for k in range(4):
        *_, info = env.step(drive[k])
        *_, vec_info = vec.step(np.stack([drive[k], drive[k]]))
        assert env.unwrapped.last_stop.to_dict() == info["stop"]
        assert [d.to_dict() for d in vec.unwrapped.last_stops] == vec_info["stop"]
    assert env.unwrapped.last_stop.result is not None  # the batch calibration is kept
    env.close()
    vec.close()
