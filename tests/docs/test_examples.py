"""The example files under examples/ run as documented (docs/architecture.md, "Where to add")."""

import importlib
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture
def examples():
    """examples/ on the path, as ``cd examples`` or ``python examples/X.py`` puts it: the
    command line then finds ``custom_protocol:Sweep`` and ``custom_estimator:batch_map``."""
    sys.path.insert(0, str(EXAMPLES))
    yield lambda name: importlib.import_module(name)
    sys.path.remove(str(EXAMPLES))


@pytest.mark.slow
def test_a_custom_protocol_runs_in_a_comparison(examples, tmp_path, capsys):
    module = examples("custom_protocol")
    assert module.main(str(tmp_path)) == 0
    assert "custom_protocol:Sweep:turn=0.6" in capsys.readouterr().out
    assert (tmp_path / "summary.json").is_file()


@pytest.mark.slow
def test_a_custom_estimator_is_checked_and_compared(examples, tmp_path, capsys):
    module = examples("custom_estimator")
    assert module.main(str(tmp_path), episodes=3) == 0
    out = capsys.readouterr().out
    assert "ANEES" in out and "custom_estimator:batch_map" in out


@pytest.mark.slow
def test_a_custom_input_format_calibrates(examples, tmp_path, capsys):
    module = examples("custom_input_format")
    assert module.main(str(tmp_path / "log.jsonl")) == 0
    out = capsys.readouterr().out
    assert "model=sensor_pose" in out and "identifiable    = yes" in out


@pytest.mark.slow
def test_a_live_session_without_ros_calibrates_its_made_up_robot(examples, capsys):
    module = examples("live_session")
    module.main()
    out = capsys.readouterr().out
    assert out.startswith("done after") and "verdict: calibrated" in out
