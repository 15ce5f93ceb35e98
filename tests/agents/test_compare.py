import csv
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from agents.catalog import PROTOCOLS, ProtocolError, make_protocol
from agents.compare import (
    COLUMNS,
    CompareError,
    CompareSettings,
    make_env,
    read_complete_rows,
    run_comparison,
)
from agents.greedy import GreedyPlanner
from agents.oracle import oracle_design
from excite import OnlineEstimator, Params, calibrate, load_segments
from excite.cli import main
from excite.stats.consistency import estimate_error, nees

IDEAL = "excite/DiffDriveCalibIdeal-v0"
SCRIPTED = [name for name in PROTOCOLS if PROTOCOLS[name].startswith("agents.protocols:")]


def test_every_scripted_protocol_stays_inside_the_arena_on_the_ideal_env():
    env = make_env(IDEAL, 30)
    for name in SCRIPTED:
        for seed in range(3):
            env.reset(seed=seed)
            protocol = make_protocol(name)
            protocol.reset(np.random.default_rng(seed))
            for _ in range(30):
                *_, info = env.step(protocol.act(env.unwrapped.knowledge()))
                assert not info["collision"], (name, seed)


def test_greedy_beats_scripted_information_on_the_ideal_env_and_nears_the_oracle():
    env = make_env(IDEAL, 30)
    env.reset(seed=11)
    base = env.unwrapped
    oracle = oracle_design(base.true_params, base.sigma, base.nominal, 30,
                           base.max_wheel_speed, base.segment_duration)
    results = {}
    for name in ("greedy", "straight_spin", "umbmark"):
        env.reset(seed=11)
        protocol = make_protocol(name)
        protocol.reset(np.random.default_rng(0))
        for _ in range(30):
            *_, info = env.step(protocol.act(base.knowledge()))
        results[name] = info["sigma_min"]
    assert results["greedy"] > 1.5 * max(results["straight_spin"], results["umbmark"])
    assert 0.9 * oracle.sigma_min < results["greedy"] <= 1.02 * oracle.sigma_min


def test_greedy_breaks_mirror_ties_towards_the_centre():
    """(l, r) and (-l, -r) add exactly the same information; the planner takes the one that
    ends nearer the centre whenever both are safe, whatever the rounding."""
    import gymnasium as gym

    from agents.greedy import command_information
    from agents.motion import predicted_poses, safe_actions, wheel_increments

    env = gym.make(IDEAL, budget=12, arena_size=12.0)
    env.reset(seed=5, options={"pose": (0.8, -0.5, 0.3)})
    planner = GreedyPlanner(grid=11)
    planner.reset(np.random.default_rng(0))
    checked = 0
    for _ in range(12):
        knowledge = env.unwrapped.knowledge()
        action = planner.plan(knowledge)
        pair = np.array([action, -action])
        gains = command_information(pair, knowledge)
        np.testing.assert_allclose(gains[0], gains[1], rtol=1e-12, atol=1e-9)
        if safe_actions(pair, knowledge).all():
            ends = predicted_poses(knowledge.pose, wheel_increments(pair, knowledge),
                                   knowledge.estimate)[:, -1, :2]
            assert np.hypot(*ends[0]) <= np.hypot(*ends[1]) + 1e-9
            checked += 1
        env.step(action)
    assert checked >= 6


def test_greedy_lookahead_runs_and_is_at_least_as_informative_here():
    env = make_env(IDEAL, 6)
    values = []
    for planner in (GreedyPlanner(grid=11), GreedyPlanner(grid=11, lookahead=True)):
        env.reset(seed=3)
        planner.reset(np.random.default_rng(0))
        for _ in range(6):
            *_, info = env.step(planner.act(env.unwrapped.knowledge()))
        values.append(info["sigma_min"])
    assert values[1] >= 0.95 * values[0]


def test_oracle_bounds_are_certified_and_beat_any_single_command():
    p, sigma = Params(0.05, 0.051, 0.3), np.array([2e-3, 2e-3, 1e-3])
    design = oracle_design(p, sigma, Params(0.05, 0.05, 0.3), 30, 20.0, 1.0)
    assert design.lower <= design.sigma_min <= design.lower * (1 + 1e-3)
    assert design.weights.sum() == pytest.approx(30)
    from agents.greedy import command_grid
    from excite.core.information import fisher_information, scaled_jacobian, sigma_min

    grid = command_grid(9)
    for action in grid[::7]:
        dphi = np.tile(action * 20.0, (30, 1))
        single = sigma_min(fisher_information(scaled_jacobian(dphi[:, 0], dphi[:, 1], p, sigma,
                                                              scale=Params(0.05, 0.05, 0.3))))
        assert single <= design.sigma_min * (1 + 1e-6)


def test_unknown_protocol_and_missing_policy():
    with pytest.raises(ProtocolError, match="unknown protocol 'zigzag'"):
        make_protocol("zigzag")
    with pytest.raises(ProtocolError, match="learned policy file not found"):
        make_protocol("learned:policy=/nonexistent/policy.zip")


def _rows(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.slow
def test_comparison_outputs_and_paired_episodes(tmp_path):
    settings = CompareSettings(IDEAL, 6, 1)
    rows = run_comparison(tmp_path, ["umbmark", "greedy"], 3, settings, workers=1,
                          progress=False)
    assert len(rows) == 2 * 3 * 6
    disk = _rows(tmp_path / "segments.csv")
    assert set(COLUMNS) <= set(disk[0]) and len(disk) == 36
    # Same episode: same hidden robot for both protocols (same oracle, same first estimate
    # prior), and each protocol's episodes differ.
    oracle = {(r["protocol"], r["episode"]): r["oracle_sigma_min"] for r in disk}
    for e in range(3):
        assert oracle[("umbmark", str(e))] == oracle[("greedy", str(e))]
    assert len({oracle[("greedy", str(e))] for e in range(3)}) == 3


@pytest.mark.slow
def test_rerun_adds_only_what_is_missing_and_rejects_other_settings(tmp_path):
    settings = CompareSettings(IDEAL, 4, 0)
    run_comparison(tmp_path, ["spin"], 2, settings, workers=1, progress=False)
    # Simulate an interrupted write: a partial episode and a truncated line at the end.
    with open(tmp_path / "segments.csv", "a") as handle:
        handle.write("arcs,online,1,1,0.1,0.1,0.1,5,9,1,1,1,3,3,0,0,0,0,0,1\n"
                     "arcs,online,1,2,0.1,0.")
    rows = run_comparison(tmp_path, ["spin", "arcs"], 3, settings, workers=2, progress=False)
    keys = [(r["protocol"], r["episode"], r["segment"]) for r in _rows_parsed(tmp_path, 4)]
    assert len(keys) == len(set(keys)) == 2 * 3 * 4 == len(rows)
    with pytest.raises(CompareError, match=r"other settings: segments 4 \(now 5\); use "
                       "another --out or the same settings"):
        run_comparison(tmp_path, ["spin"], 1, CompareSettings(IDEAL, 5, 0), progress=False)


def _rows_parsed(path, segments):
    return read_complete_rows(path / "segments.csv", segments)


def _line_count(path) -> int:
    with open(path) as handle:
        return sum(1 for _ in handle)


@pytest.mark.slow
def test_killed_comparison_resumes_without_loss_or_duplicates(tmp_path):
    """Kill a running `excite compare` (SIGKILL, no chance to clean up) and re-run it."""
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "excite.cli", "compare", "--protocols", "random,arcs",
           "--episodes", "24", "--segments", "10", "--env", IDEAL, "--workers", "2",
           "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    deadline = time.time() + 60
    while time.time() < deadline:  # wait until some, not all, episodes are written
        path = out / "segments.csv"
        if path.exists() and 3 * 20 < _line_count(path) < 20 * 20:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    partial = len(read_complete_rows(out / "segments.csv", 10))
    assert 0 < partial < 2 * 24 * 10
    subprocess.run(cmd, check=True, capture_output=True)
    rows = read_complete_rows(out / "segments.csv", 10)
    keys = [(r["protocol"], r["episode"], r["segment"]) for r in rows]
    assert len(keys) == len(set(keys)) == 2 * 24 * 10
    assert _line_count(out / "segments.csv") == 2 * 24 * 10 + 1


@pytest.mark.slow
def test_compare_cli_writes_summary_and_plots(tmp_path, capsys):
    from matplotlib.image import imread

    code = main(["compare", "--protocols", "umbmark,greedy,straight", "--episodes", "3",
                 "--segments", "8", "--env", IDEAL, "--workers", "1", "--out",
                 str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 0 and "greedy" in out and "oracle" in out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary["protocols"]) == {"umbmark", "greedy", "straight"}
    assert "b" in summary["protocols"]["straight"]["online"]["undetermined"]
    assert summary["settings"]["estimators"] == ["online"]
    for name in ("errors_vs_segment.png", "sigma_min_vs_segment.png", "trajectories.png"):
        image = imread(tmp_path / name)
        assert image.shape[0] > 100 and image.std() > 0.01


@pytest.mark.slow
def test_compare_runs_on_the_sensor_env_and_skips_a_policy_of_another_layout(tmp_path, capsys):
    """greedy and the oracle plan with the six-parameter model; the shipped policy (trained on
    the axle env's 16 observations) is skipped with a one-line message, the rest runs."""
    code = main(["compare", "--protocols", "greedy,umbmark,learned", "--episodes", "2",
                 "--segments", "6", "--env", "excite/DiffDriveCalibSensor-v0", "--workers",
                 "1", "--out", str(tmp_path)])
    out, err = capsys.readouterr()
    assert code == 0
    skipped = [line for line in err.splitlines() if line.startswith("excite: skipping")]
    assert len(skipped) == 1 and "another observation layout" in skipped[0]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary["protocols"]) == {"greedy", "umbmark"}
    assert summary["protocols"]["greedy"]["online"]["sigma_min"]["median"] > 0
    anees = summary["protocols"]["greedy"]["online"]["anees"]
    assert anees["parameters"] == 6 and anees["final"] > 0  # wheels and sensor pose


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["compare", "--protocols", "zigzag"], "unknown protocol 'zigzag'"),
        (["compare", "--protocols", "spin,spin"], "distinct"),
        (["compare", "--episodes", "0"], "must be at least 1"),
        (["compare", "--segments", "x"], "not a whole number"),
        (["compare", "--env", "CartPole-v1"], "unknown environment 'CartPole-v1'"),
        (["compare", "--env", "nope"], "unknown environment"),
        (["compare", "--workers", "-2"], "must be at least 1"),
        (["compare", "--robot", "roomba"], "unknown robot preset 'roomba'"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--robot", "x", "--out", "x.csv"],
         "unknown robot preset 'x'"),
        (["compare", "--policy", "/nonexistent.zip"], "--policy: no such file"),
        (["compare", "--estimators", "kalman"], "unknown estimator 'kalman'"),
        (["compare", "--estimators", "online,ekf,online"], "distinct"),
        (["compare", "--estimators", "online,,ekf"], "empty name"),
        (["compare", "--estimators", ""], "empty name"),
        (["compare", "--estimators", "window:width=3"], "'width=3' is not a setting"),
        (["compare", "--estimators", "tests.agents.test_compare:missing"], "has no 'missing'"),
        (["compare", "--estimators", "no_such_module_x:f"], "cannot import module"),
        (["compare", "--estimators", "tests.agents.test_compare:two_arguments_too_few",
          "--episodes", "1", "--segments", "2"], "its factory raised TypeError"),
        (["compare", "--protocols", "learned", "--episodes", "1"], "learned policy"),
        (["simulate", "--protocol", "zigzag", "--segments", "3", "--out", "x.csv"],
         "unknown protocol"),
        (["simulate", "--protocol", "spin", "--segments", "3"], "required: --out"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--out", "/no/dir/x.csv"],
         "no such directory"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--seed", "-5", "--out",
          "x.csv"], "--seed: must be at least 0"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--robot-seed", "-1", "--out",
          "x.csv"], "--robot-seed: must be at least 0"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--out", "adir"],
         "cannot write adir: it is a folder"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--out", "afile/x.csv"],
         "afile is a file, not a folder"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--format", "bag", "--out",
          "afile/bag"], "afile is a file, not a folder"),
        (["compare", "--out", "afile"], "--out: afile is a file, not a folder"),
        (["compare", "--out", ""], "--out: is empty"),
        (["compare", "--protocols", "spin", "--episodes", "1", "--segments", "2", "--out",
          "adir"], "cannot write adir/summary.json: it is a folder"),
        (["compare", "--protocols", "umbmark,,spin"], "empty name in the list"),
        (["compare", "--protocols", ","], "empty name in the list"),
        (["compare", "--protocols", "spin,umbmark", "--policy", "afile"],
         "none of the protocols (spin, umbmark) takes a policy"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--policy", "afile", "--out",
          "x.csv"], "none of the protocols (spin) takes a policy"),
        (["simulate", "--protocol", "spin", "--segments", "3", "--format", "timeseries",
          "--pose-noise", "-1,0", "--out", "x.csv"], "must be SXY,STH: two finite numbers >= 0"),
        (["tune", "--protocols", "spin", "--out", "afile/x.json"],
         "afile is a file, not a folder"),
        (["tune", "--protocols", "spin", "--out", "adir/summary.json"],
         "adir/summary.json: it is a folder"),
    ],
)
@pytest.mark.slow
def test_compare_and_simulate_bad_input(tmp_path, capsys, monkeypatch, argv, fragment):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("a file, not a folder\n")
    (tmp_path / "adir" / "summary.json").mkdir(parents=True)
    if argv[:3] == ["compare", "--protocols", "learned"]:
        import agents.learned

        monkeypatch.setattr(agents.learned, "SHIPPED_POLICY", tmp_path / "none.zip")
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("excite: error: ")
    assert fragment in err[0]


@pytest.mark.parametrize("protocol", [*SCRIPTED, "greedy"])
def test_simulate_every_protocol_and_calibrate_against_the_truth(tmp_path, capsys, protocol):
    out = tmp_path / "log.csv"
    assert main(["simulate", "--protocol", protocol, "--segments", "12", "--seed", "4",
                 "--env", IDEAL, "--out", str(out)]) == 0
    truth = json.loads((tmp_path / "log.truth.json").read_text())
    seg = load_segments(out)
    assert len(seg) == 12 and truth["protocol"] == protocol and truth["segments"] == 12
    if protocol in ("greedy", "random", "arcs", "umbmark", "straight_spin"):
        result = calibrate(seg, sigma=(2e-3, 2e-3, 1e-3))
        truth_p = np.array([truth["r_L"], truth["r_R"], truth["b"]])
        z = (result.params.as_array() - truth_p) / result.std
        assert np.all(np.abs(z) < 5)


class InflatedOnline:
    """A user's estimator for the tests: the online estimator reporting 4x its covariance
    (the same estimates, so the same run; the NEES exactly a quarter)."""

    def __init__(self, nominal, sigma):
        self.inner = OnlineEstimator(nominal, sigma=sigma)

    def update(self, *row):
        self.inner.update(*row)

    @property
    def params(self):
        return self.inner.params

    @property
    def covariance(self):
        return 4.0 * self.inner.covariance


def inflated_online(nominal, sigma):
    """module:factory entry point of InflatedOnline."""
    return InflatedOnline(nominal, sigma)


def two_arguments_too_few():
    """A factory with the wrong signature (a usage error, before any episode runs)."""


def test_estimators_run_on_the_same_episodes_and_resume_per_estimator(tmp_path):
    """Every (protocol, estimator) pair meets the same robots; a user's estimator plugs in
    as module:factory; adding an estimator to a finished run computes only its rows."""
    settings = CompareSettings(IDEAL, 5, 2)
    first = run_comparison(tmp_path, ["greedy", "arcs"], 2, settings, workers=1,
                           progress=False, estimators=["online"])
    assert {r["estimator"] for r in first} == {"online"} and len(first) == 2 * 2 * 5
    before = _rows(tmp_path / "segments.csv")
    user = "tests.agents.test_compare:inflated_online"
    rows = run_comparison(tmp_path, ["greedy", "arcs"], 2, settings, workers=1,
                          progress=False, estimators=["online", user])
    assert len(rows) == 2 * 2 * 2 * 5
    after = _rows(tmp_path / "segments.csv")
    # the first run's rows kept as they were (the file is rewritten in episode order)
    assert [row for row in after if row["estimator"] == "online"] == before
    by_key = {(r["protocol"], r["estimator"], r["episode"], r["segment"]): r for r in rows}
    env = make_env(IDEAL, 5)
    seconds = env.unwrapped.segment_duration + env.unwrapped.config["settle_time"]
    for (protocol, estimator, episode, segment), row in by_key.items():
        if estimator != user:
            continue
        online = by_key[protocol, "online", episode, segment]
        # same robot, same estimates (greedy plans on them: same path), NEES / 4
        for key in ("oracle_sigma_min", "r_L_err", "b_err", "sigma_min", "x", "distance"):
            assert row[key] == online[key], key
        assert row["nees"] == pytest.approx(online["nees"] / 4.0, rel=1e-9)
        assert row["nees_dof"] == 3
        assert row["time"] == online["time"] == pytest.approx(segment * seconds)
    # the NEES is the estimator's against the hidden truth: recompute one episode by hand
    env.reset(seed=_episode_seed(settings, 1))
    protocol = make_protocol("arcs")
    protocol.reset(np.random.default_rng([_episode_seed(settings, 1), 1]))
    for _ in range(5):
        env.step(protocol.act(env.unwrapped.knowledge()))
    error, covariance = estimate_error(env.unwrapped.estimator, env.unwrapped.true_theta)
    assert by_key["arcs", "online", 1, 5]["nees"] == pytest.approx(nees(error, covariance))


def _episode_seed(settings, episode):
    from agents.compare import episode_seed

    return episode_seed(settings.seed, episode, settings.stream)


@pytest.mark.slow
def test_compare_cli_estimators_axis(tmp_path, capsys):
    code = main(["compare", "--protocols", "umbmark,greedy", "--estimators",
                 "online,ekf,tests.agents.test_compare:inflated_online", "--episodes", "2",
                 "--segments", "5", "--env", IDEAL, "--workers", "1", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    estimators = ["online", "ekf", "tests.agents.test_compare:inflated_online"]
    assert summary["settings"]["estimators"] == estimators
    for protocol in ("umbmark", "greedy"):
        assert list(summary["protocols"][protocol]) == estimators
        entry = summary["protocols"][protocol]
        assert entry[estimators[2]]["anees"]["final"] == pytest.approx(
            entry["online"]["anees"]["final"] / 4.0)
    assert out.splitlines()[0].split()[:2] == ["protocol", "estimator"]
    assert (tmp_path / "anees_vs_segment.png").stat().st_size > 5000


def test_an_old_results_folder_is_a_clear_error(tmp_path, capsys):
    """A segments.csv of an older excite (no estimator axis) is neither read as something
    else nor overwritten: a one-line error, exit 2."""
    old = ("protocol,episode,segment,r_L_err,r_R_err,b_err,sigma_min,oracle_sigma_min,"
           "rel_std_r_L,rel_std_r_R,rel_std_b,collision,x,y,theta,distance\n"
           "spin,0,1,0.1,0.1,0.1,5,9,1,1,1,0,0,0,0,0\n")
    (tmp_path / "segments.csv").write_text(old)
    with pytest.raises(CompareError, match="older excite"):
        run_comparison(tmp_path, ["spin"], 1, CompareSettings(IDEAL, 1, 0), progress=False)
    code = main(["compare", "--protocols", "spin", "--episodes", "1", "--segments", "1",
                 "--env", IDEAL, "--workers", "1", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "older excite" in err[0]
    assert (tmp_path / "segments.csv").read_text() == old


def test_run_comparison_rejects_no_or_repeated_estimators(tmp_path):
    from excite.errors import EstimatorError
    from excite.estimators import estimator_factory

    settings = CompareSettings(IDEAL, 2, 0)
    with pytest.raises(EstimatorError, match="no estimator"):
        run_comparison(tmp_path, ["spin"], 1, settings, progress=False, estimators=[])
    with pytest.raises(EstimatorError, match="given twice"):
        run_comparison(tmp_path, ["spin"], 1, settings, progress=False,
                       estimators=["ekf:prior_std=0.1", estimator_factory("ekf:prior_std=1e-1")])
    assert not (tmp_path / "segments.csv").exists()


@pytest.mark.slow
def test_resume_refuses_results_without_their_settings(tmp_path):
    """Rows whose config.json is gone cannot be tied to their settings: a run with another
    seed reused seed 0's episodes and labelled them seed 5 (found by fuzzing)."""
    out = tmp_path / "run"
    run_comparison(out, ["arcs"], 2, CompareSettings(IDEAL, 3, 0), workers=1, progress=False)
    (out / "config.json").unlink()
    with pytest.raises(CompareError, match="holds results but .*config.json is missing"):
        run_comparison(out, ["arcs"], 2, CompareSettings(IDEAL, 3, 5), workers=1,
                       progress=False)


def test_resume_refuses_results_of_a_policy_file_changed_at_the_same_path(tmp_path):
    """The label learned:policy=PATH names a path, not a policy: a file retrained at the same
    path must not reuse the old file's results (the folder ties them to its sha256)."""
    import shutil

    from agents.learned import SHIPPED_POLICY
    from agents.train import normalization_path

    policy = tmp_path / "p.zip"

    def install(source):
        shutil.copy(source, policy)
        shutil.copy(normalization_path(source), normalization_path(policy))

    install(SHIPPED_POLICY)
    settings, out = CompareSettings(IDEAL, 2, 0), tmp_path / "run"
    spec = f"learned:policy={policy}"
    first = run_comparison(out, [spec], 1, settings, workers=1, progress=False)
    again = run_comparison(out, [spec, "spin"], 1, settings, workers=1, progress=False)
    assert [r for r in again if r["protocol"] != "spin"] == first  # same file: reused
    install(SHIPPED_POLICY.with_name("excite_ppo_robots.zip"))  # retrained at the same path
    with pytest.raises(CompareError, match="its files changed"):
        run_comparison(out, [spec], 2, settings, workers=1, progress=False)
    install(SHIPPED_POLICY)
    shutil.copy(normalization_path(SHIPPED_POLICY.with_name("excite_ppo_robots.zip")),
                normalization_path(policy))  # only the normalization differs
    with pytest.raises(CompareError, match="its files changed"):  # the normalization counts
        run_comparison(out, [spec], 2, settings, workers=1, progress=False)
    install(SHIPPED_POLICY)
    assert len(run_comparison(out, [spec], 2, settings, workers=1, progress=False)) == 2 * 2
    # a folder that recorded the policy's digest but kept none of its rows (killed before its
    # first episode finished) resumes with the new file, whose digest it then records
    other = tmp_path / "other"
    run_comparison(other, [spec, "spin"], 1, settings, workers=1, progress=False)
    csv = other / "segments.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([lines[0], *(line for line in lines[1:] if "learned" not in line)])
                   + "\n")
    install(SHIPPED_POLICY.with_name("excite_ppo_robots.zip"))
    rows = run_comparison(other, [spec, "spin"], 1, settings, workers=1, progress=False)
    assert {r["protocol"] for r in rows} == {spec, "spin"}
    with pytest.raises(CompareError, match="its files changed"):  # now tied to the new file
        install(SHIPPED_POLICY)
        run_comparison(other, [spec], 1, settings, workers=1, progress=False)
