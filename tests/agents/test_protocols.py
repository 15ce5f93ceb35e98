"""Protocol parameters, the registry (user protocols as module:Class), light imports, and
tuning on seeds disjoint from every evaluation seed."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agents.catalog import (
    PROTOCOLS,
    ProtocolError,
    ProtocolSpec,
    default_protocols,
    make_protocol,
    parse_protocol,
    parse_protocols,
    register,
)
from agents.compare import STREAM_SPAN, CompareSettings, episode_seed, episode_seeds
from agents.protocols import Parameter, Protocol
from agents.tuning import (
    SHIPPED_DIR,
    TunedError,
    candidates,
    check_disjoint,
    load_tuned,
    shipped_path,
)
from excite.contracts import RobotKnowledge
from excite.registration import DEFAULT_BUDGET, DEFAULT_ENV_ID, ENV_IDS
from tests.conftest import assert_one_line_error, run_cli

IDEAL = "excite/DiffDriveCalibIdeal-v0"
ROOT = Path(__file__).resolve().parents[2]


class Zigzag(Protocol):
    """A user's protocol, defined outside excite: alternating gentle arcs."""

    parameters = (Parameter("amplitude", float, 0.2, "turn part of the command", 0.0, 0.5,
                            grid=2),)
    amplitude: float  # no declared wall margin: the guard keeps its usual one

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        turn = self.amplitude if self.step_index % 2 == 0 else -self.amplitude
        return np.array([0.3 - turn, 0.3 + turn])


ZIGZAG = "tests.agents.test_protocols:Zigzag"


def test_parameter_syntax_labels_and_settings():
    specs = parse_protocols("umbmark:speed=0.20, greedy:max_speed=0.3:lookahead=yes,learned")
    assert [s.label for s in specs] == ["umbmark:speed=0.2",
                                        "greedy:max_speed=0.3:lookahead=true", "learned"]
    umbmark = make_protocol(specs[0])
    assert umbmark.speed == 0.2 and umbmark.speed_margin == 0.35
    greedy = make_protocol(specs[1])
    assert greedy.lookahead is True and np.abs(greedy.candidates).max() == pytest.approx(0.3)
    assert specs[2].resolved()["speed_margin"] == 0.1  # learned's own default
    # the same protocol twice with different settings: allowed, each labelled
    twice = parse_protocols("arcs:speed=0.2,arcs:speed=0.4,arcs")
    assert len({s.label for s in twice}) == 3


def test_every_speed_range_includes_slow_speeds_and_every_default_is_declared_once():
    for name in PROTOCOLS:
        cls = ProtocolSpec(name).protocol
        for p in cls.parameters:
            assert p.check(p.default) == p.default, (name, p.name)
            if p.name in ("speed", "max_speed"):
                assert p.low <= 0.1 and p.high >= 1.0 and p.grid
                assert min(p.tuning_values()) == pytest.approx(0.1)
                assert p.default in p.tuning_values()


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("zigzag", "unknown protocol 'zigzag'"),
        ("umbmark:sped=0.2", "umbmark has no parameter 'sped'"),
        ("umbmark:speed=fast", "speed must be a number, got 'fast'"),
        ("umbmark:speed=2", "speed must be in [0.1, 1.0], got 2.0"),
        ("umbmark:speed=nan", "speed must be in"),
        ("greedy:grid=2.5", "grid must be a whole number"),
        ("greedy:lookahead=maybe", "lookahead must be true or false"),
        ("umbmark:speed=0.2:speed=0.3", "speed is set twice"),
        ("umbmark:fast", "settings are KEY=VALUE"),
        (":speed=0.2", "needs a name"),
        ("umbmark,umbmark:speed=0.5", "protocols must be distinct"),
        ("nosuchmodule:Thing", "no module named 'nosuchmodule'"),
        ("agents.protocols:SPEED", "no Protocol subclass named 'SPEED'"),
    ],
)
def test_bad_protocols_are_one_line_errors(tmp_path, capsys, text, fragment):
    with pytest.raises(ProtocolError) as info:
        parse_protocols(text)
    assert fragment in str(info.value)
    code, _, err = run_cli(capsys, "compare", "--protocols", text, "--episodes", "1",
                           "--out", tmp_path)
    assert_one_line_error(code, err, fragment)


def test_excite_protocols_lists_names_parameters_defaults_and_ranges(capsys):
    code, out, _ = run_cli(capsys, "protocols")
    assert code == 0
    for name in PROTOCOLS:
        assert f"{name}  ({PROTOCOLS[name]})" in out
    assert "speed         float  0.5      [0.1, 1.0]" in out
    assert "lookahead     bool   false" in out
    code, _, err = run_cli(capsys, "protocols", "tests.agents.test_protocols:Nope")
    assert_one_line_error(code, err, "no Protocol subclass named 'Nope'")


@pytest.mark.slow
def test_a_user_protocol_plugs_in_by_module_and_class(tmp_path, capsys, monkeypatch):
    """Defined here, never registered in excite: described, compared and tuned by its entry
    point; registering a name for it is one call."""
    listing = subprocess.run([sys.executable, "-m", "excite.cli", "protocols", ZIGZAG],
                             cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert "A user's protocol, defined outside excite" in listing and "amplitude" in listing
    code, out, _ = run_cli(capsys, "compare", "--protocols", f"{ZIGZAG}:amplitude=0.4,umbmark",
                           "--episodes", "2", "--segments", "5", "--env", IDEAL,
                           "--workers", "1", "--tuned", "none", "--out", tmp_path)
    assert code == 0 and f"{ZIGZAG}:amplitude=0.4" in out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["protocol_settings"][f"{ZIGZAG}:amplitude=0.4"] == {"amplitude": 0.4}
    monkeypatch.setitem(PROTOCOLS, "zigzag", "")
    register("zigzag", ZIGZAG)
    assert make_protocol("zigzag:amplitude=0.1").amplitude == 0.1
    assert [c.label for c in candidates(ProtocolSpec("zigzag"))] == [
        "zigzag:amplitude=0.0", "zigzag:amplitude=0.5"]


def test_protocol_modules_import_neither_pymunk_nor_gymnasium_nor_numba():
    code = ("import sys, agents.protocols, agents.catalog, agents.greedy, agents.slip_aware, "
            "agents.motion, "
            "agents.learned, excite.contracts, excite.core.arena\n"
            "heavy = sorted(m for m in ('pymunk', 'gymnasium', 'numba', 'torch', "
            "'stable_baselines3') if m in sys.modules)\n"
            "assert not heavy, heavy\n"
            "from agents.catalog import PROTOCOLS, make_protocol\n"
            "[make_protocol(name) for name in PROTOCOLS if name != 'learned']\n"
            "assert 'pymunk' not in sys.modules and 'gymnasium' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True)


def test_tuning_seeds_are_never_evaluation_seeds():
    for seed in (0, 1, 7, 2**31):
        settings = CompareSettings(seed=seed)
        evaluation = episode_seeds(settings, 300)
        tuning = episode_seeds(CompareSettings(seed=seed, stream="tuning"), 300)
        assert max(evaluation) < STREAM_SPAN <= min(tuning) < 2 * STREAM_SPAN
        assert len(set(tuning)) == 300
    # the evaluation stream is the one compare always used: results stay comparable
    assert episode_seed(0, 0) == int(np.random.SeedSequence([0, 0]).generate_state(1)[0])


def _tuning_rows(path):
    with open(path, newline="") as handle:
        return [(r["protocol"], r["episode"], r["segment"]) for r in csv.DictReader(handle)]


@pytest.mark.slow
def test_tune_writes_settings_and_seeds_resumes_and_compare_uses_them(tmp_path, capsys):
    out = tmp_path / "tuned.json"
    argv = ["tune", "--protocols", "umbmark,greedy:grid=5", "--segments", "5", "--env", IDEAL,
            "--workers", "1", "--out", out]
    code, text, _ = run_cli(capsys, *argv, "--episodes", "2")
    assert code == 0 and "umbmark" in text
    work = tmp_path / "tuned.tuning" / "segments.csv"
    with open(work, "a") as handle:  # an interrupted write: half a row
        handle.write("umbmark:speed=0.1,2,5,0.1,0.")
    code, text, _ = run_cli(capsys, *argv, "--episodes", "3")
    assert code == 0
    rows = _tuning_rows(work)
    n_candidates = 11 + 11 * 3  # umbmark: speed; greedy: max_speed x speed_margin
    assert len(rows) == len(set(rows)) == 3 * n_candidates
    assert {segment for *_, segment in rows} == {"5"}  # tuning keeps only final segments

    document = load_tuned(out)
    assert document["episodes"] == 3 and document["env_id"] == IDEAL
    assert document["tuning_seeds"] == episode_seeds(
        CompareSettings(IDEAL, 5, stream="tuning"), 3)
    entry = document["protocols"]["greedy:grid=5"]
    assert entry["settings"]["grid"] == 5 and len(entry["candidates"]) == 33
    assert entry["final_max_error"] == min(c["final_max_error"] for c in entry["candidates"])

    cmp_dir = tmp_path / "cmp"
    code, text, _ = run_cli(capsys, "compare", "--protocols", "umbmark,greedy:grid=5,spin",
                            "--tuned", out, "--segments", "5", "--env", IDEAL, "--episodes",
                            "2", "--workers", "1", "--out", cmp_dir)
    assert code == 0
    summary = json.loads((cmp_dir / "summary.json").read_text())
    labels = summary["settings"]["protocols"]
    assert labels[0] == document["protocols"]["umbmark"]["label"]
    assert labels[1] == entry["label"] and labels[2] == "spin"
    assert summary["settings"]["tuned"]["untuned"] == ["spin"]
    assert "settings: tuned by excite tune on 3 tuning episodes" in text
    assert labels[0] in text  # the table names the settings each protocol ran with

    code, _, err = run_cli(capsys, "compare", "--tuned", out, "--segments", "6", "--env",
                           IDEAL, "--episodes", "1", "--out", tmp_path / "other")
    assert_one_line_error(code, err, "tuned for 5 segments")


def test_compare_refuses_tuned_settings_chosen_on_its_own_episodes(tmp_path, capsys):
    settings = CompareSettings(IDEAL, 5)
    forged = {"excite_tuned": 1, "env_id": IDEAL, "segments": 5, "robot": "default",
              "tuning_seeds": episode_seeds(settings, 3), "protocols": {}}
    path = tmp_path / "forged.json"
    path.write_text(json.dumps(forged))
    with pytest.raises(TunedError, match="were tuning episodes"):
        check_disjoint(load_tuned(path), settings, 3)
    code, _, err = run_cli(capsys, "compare", "--tuned", path, "--segments", "5", "--env",
                           IDEAL, "--episodes", "2", "--out", tmp_path / "c")
    assert_one_line_error(code, err, "were tuning episodes")
    path.write_text("{not json")
    code, _, err = run_cli(capsys, "compare", "--tuned", path, "--out", tmp_path / "c")
    assert_one_line_error(code, err, "not valid JSON")
    path.write_text("[" * 100_000 + "]" * 100_000)  # nested too deeply for the parser
    code, _, err = run_cli(capsys, "compare", "--tuned", path, "--out", tmp_path / "c")
    assert_one_line_error(code, err, "not valid JSON")
    path.write_text(json.dumps({**forged, "tuning_seeds": [[1], [2]]}))
    code, _, err = run_cli(capsys, "compare", "--tuned", path, "--out", tmp_path / "c")
    assert_one_line_error(code, err, "tuning_seeds must be a list of integers")
    code, _, err = run_cli(capsys, "tune", "--out", tmp_path / "tuned.txt")
    assert_one_line_error(code, err, "--out must name a .json file")


def test_the_default_env_and_robot_ship_tuned_settings():
    assert shipped_path(DEFAULT_ENV_ID).exists()
    assert shipped_path(DEFAULT_ENV_ID, "jackal").name == "excite_DiffDriveCalib-v0.jackal.json"


@pytest.mark.parametrize("path", sorted(SHIPPED_DIR.glob("*.json")), ids=lambda p: p.name)
def test_shipped_tuned_settings_were_tuned_on_tuning_seeds_only(path):
    document = load_tuned(path)
    env, robot = document["env_id"], document["robot"]
    assert env in ENV_IDS and shipped_path(env, robot) == path  # found by compare --robot
    assert document["segments"] == DEFAULT_BUDGET
    assert document["stream"] == "tuning" and document["episodes"] >= 100
    assert min(document["tuning_seeds"]) >= STREAM_SPAN
    assert document["tuning_seeds"] == episode_seeds(
        CompareSettings(env, DEFAULT_BUDGET, document["seed"], robot, stream="tuning"),
        document["episodes"])
    scripted = {spec.label for spec in default_protocols()} - {"learned"}
    assert scripted <= set(document["protocols"])
    for label, entry in document["protocols"].items():
        parse_protocol(label).under(entry["settings"])  # every setting valid today


@pytest.mark.slow
def test_compare_of_a_preset_runs_that_presets_shipped_settings(tmp_path, capsys):
    path = shipped_path(DEFAULT_ENV_ID, "turtlebot3")
    label = load_tuned(path)["protocols"]["umbmark"]["label"]
    assert label != load_tuned(shipped_path(DEFAULT_ENV_ID))["protocols"]["umbmark"]["label"]
    code, text, _ = run_cli(capsys, "compare", "--robot", "turtlebot3", "--protocols",
                            "umbmark", "--episodes", "1", "--workers", "1", "--out", tmp_path)
    assert code == 0 and label in text and str(path) in text


@pytest.mark.slow
def test_default_compare_runs_the_shipped_settings(tmp_path, capsys):
    document = load_tuned(shipped_path(DEFAULT_ENV_ID))
    code, text, _ = run_cli(capsys, "compare", "--protocols", "umbmark", "--episodes", "1",
                            "--workers", "1", "--out", tmp_path)
    assert code == 0
    label = document["protocols"]["umbmark"]["label"]
    assert label in text and str(shipped_path(DEFAULT_ENV_ID)) in text
    code, text, _ = run_cli(capsys, "compare", "--protocols", "umbmark", "--episodes", "1",
                            "--workers", "1", "--tuned", "none", "--out", tmp_path / "d")
    assert code == 0 and "declared defaults (--tuned none)" in text
    code, text, _ = run_cli(capsys, "compare", "--protocols", "umbmark:speed=0.2,spin",
                            "--episodes", "1", "--workers", "1", "--tuned", "none", "--out",
                            tmp_path / "w")
    assert code == 0
    assert "as written (umbmark:speed=0.2), else declared defaults (--tuned none)" in text


def test_simulate_takes_protocol_settings(tmp_path, capsys):
    out = tmp_path / "log.csv"
    code, _, _ = run_cli(capsys, "simulate", "--protocol", "arcs:speed=0.2", "--segments", "4",
                         "--env", IDEAL, "--out", out)
    truth = json.loads((tmp_path / "log.truth.json").read_text())
    assert code == 0 and truth["protocol"] == "arcs:speed=0.2"
    assert truth["protocol_settings"] == {"speed": 0.2, "speed_margin": 0.35}
