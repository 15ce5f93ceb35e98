"""A user's protocols and estimators (``module:Class``, ``module:factory``) that misbehave:
each failure is a one-line error naming the plug-in and what went wrong (exit 2), never an
internal error, and never silently run (a NaN action turned into a wall-guard turn)."""

import shutil
import sys

import pytest

from excite.cli import main

IDEAL = "excite/DiffDriveCalibIdeal-v0"
PROTOCOLS = '''
import numpy as np
from agents.protocols import Parameter, Protocol, Spin

class Good(Protocol):
    def plan(self, k):
        return np.array([0.2, 0.3])

class SpinChild(Spin):
    pass

class Raises(Protocol):
    def plan(self, k):
        raise RuntimeError("boom in plan")

class NaNPlan(Protocol):
    def plan(self, k):
        return np.array([np.nan, 0.2])

class NonePlan(Protocol):
    def plan(self, k):
        return None

class TextPlan(Protocol):
    def plan(self, k):
        return "fast"

class ThreePlan(Protocol):
    def plan(self, k):
        return np.array([0.1, 0.2, 0.3])

class ActOverride(Protocol):
    def act(self, k):
        return np.array([5.0, -5.0, 1.0])
    def plan(self, k):
        return np.zeros(2)

class Abstract(Protocol):
    pass

class InitRaises(Protocol):
    def __init__(self, **settings):
        raise ValueError("bad init")
    def plan(self, k):
        return np.zeros(2)

class ResetRaises(Protocol):
    def reset(self, rng):
        raise KeyError("in reset")
    def plan(self, k):
        return np.zeros(2)

class FromFile(Protocol):
    """Drives at the speed written in its file (a stand-in for a policy file)."""
    parameters = (Parameter("path", str, "", "a file holding the speed"),)
    @classmethod
    def fingerprint(cls, settings):
        return open(settings["path"]).read()
    def __init__(self, **settings):
        super().__init__(**settings)
        self.speed = float(open(self.settings["path"]).read())
    def plan(self, k):
        return np.array([self.speed, self.speed])

class RetrainedDuringRun(FromFile):
    """Rewrites its own file at each episode's start, as a policy retrained at the same path
    while a comparison runs."""
    def reset(self, rng):
        super().reset(rng)
        with open(self.settings["path"], "a") as f:
            f.write("0")

class ListFingerprint(Good):
    @classmethod
    def fingerprint(cls, settings):
        return ["not", "a", "digest"]

class BadDefault(Protocol):
    parameters = (Parameter("x", float, 5.0, "out of its range", 0.0, 1.0),)
    def plan(self, k):
        return np.zeros(2)
'''
ESTIMATORS = '''
import numpy as np
from excite import OnlineEstimator

def good(nominal, sigma):
    return OnlineEstimator(nominal, sigma=sigma)

def raises(nominal, sigma):
    raise RuntimeError("factory boom")

def returns_none(nominal, sigma):
    return None

class _Fixed:
    def __init__(self, nominal, sigma):
        self.params = np.asarray(nominal.as_array())
        self.covariance = 1e-4 * np.eye(3)
    def update(self, *row):
        pass

class UpdateRaises(_Fixed):
    def update(self, *row):
        raise ValueError("update boom")

class NaNParams(_Fixed):
    def update(self, *row):
        self.params = np.full(3, np.nan)

class TwoParams(_Fixed):
    def update(self, *row):
        self.params = np.array([1.0, 2.0])

class NaNCovariance(_Fixed):
    def update(self, *row):
        self.covariance = np.full((3, 3), np.nan)

class OneArgUpdate(_Fixed):
    def update(self, segment):
        pass
'''
BROKEN = {"plugin_importerror": "raise ImportError('missing dependency xyz')\n",
          "plugin_zerodivision": "x = 1 / 0\n", "plugin_syntax": "def f(:\n"}


@pytest.fixture(scope="module")
def plugins(tmp_path_factory):
    """A folder of user modules on the path (of this process and of its worker processes)."""
    folder = tmp_path_factory.mktemp("plugins")
    (folder / "plugin_protocols.py").write_text(PROTOCOLS)
    (folder / "plugin_estimators.py").write_text(ESTIMATORS)
    for name, text in BROKEN.items():
        (folder / f"{name}.py").write_text(text)
    sys.path.insert(0, str(folder))
    yield folder
    sys.path.remove(str(folder))


def _error(capsys, argv) -> str:
    code = main(argv)
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if not line.startswith("episodes:")]  # the progress bar
    assert code == 2 and len(err) == 1 and err[0].startswith("excite: error: "), (code, err)
    return err[0]


def _simulate(tmp_path, protocol, *extra):
    return ["simulate", "--protocol", protocol, "--segments", "3", "--env", IDEAL,
            "--out", str(tmp_path / "log.csv"), *extra]


@pytest.mark.parametrize(("name", "fragments"), [
    ("NaNPlan", ["plan returned array([nan, 0.2])", "not an action"]),
    ("NonePlan", ["plan returned None"]),
    ("TextPlan", ["plan returned 'fast'"]),
    ("ThreePlan", ["plan returned array([0.1, 0.2, 0.3])"]),
    ("ActOverride", ["act returned array([ 5., -5., 1.])"]),
    ("Raises", ["act raised RuntimeError: boom in plan"]),
    ("InitRaises", ["__init__ raised ValueError: bad init"]),
    ("ResetRaises", ["reset raised KeyError: 'in reset'"]),
    ("Abstract", ["Abstract is abstract", "plan"]),
    ("BadDefault", ["the default of its parameter x is invalid", "x must be in [0.0, 1.0]"]),
])
def test_a_misbehaving_user_protocol_is_a_one_line_error_naming_it(plugins, tmp_path, capsys,
                                                                   name, fragments):
    message = _error(capsys, _simulate(tmp_path, f"plugin_protocols:{name}"))
    assert f"plugin_protocols:{name}" in message
    for fragment in fragments:
        assert fragment in message


@pytest.mark.parametrize(("module", "fragment"), [
    ("plugin_importerror", "ImportError: missing dependency xyz"),
    ("plugin_zerodivision", "ZeroDivisionError: division by zero"),
    ("plugin_syntax", "SyntaxError: invalid syntax"),
])
def test_a_user_module_that_fails_to_import_is_named(plugins, tmp_path, capsys, module,
                                                     fragment):
    message = _error(capsys, _simulate(tmp_path, f"{module}:P"))
    assert f"protocol '{module}:P': importing {module} raised {fragment}" in message
    message = _error(capsys, ["compare", "--protocols", "spin", "--estimators", f"{module}:f",
                              "--out", str(tmp_path / "c")])
    assert f"estimator '{module}:f': cannot import module" in message and fragment in message


def test_a_good_user_protocol_and_estimator_run(plugins, tmp_path, capsys):
    assert main(_simulate(tmp_path, "plugin_protocols:Good")) == 0
    assert main(["compare", "--protocols", "plugin_protocols:Good", "--estimators",
                 "plugin_estimators:good", "--episodes", "1", "--segments", "2", "--env",
                 IDEAL, "--workers", "1", "--out", str(tmp_path / "c")]) == 0


def test_a_bad_action_in_a_compare_worker_is_named(plugins, tmp_path, capsys):
    """The check is where protocols are driven, so it holds in the worker processes too."""
    message = _error(capsys, ["compare", "--protocols", "spin,plugin_protocols:NaNPlan",
                              "--episodes", "1", "--segments", "2", "--env", IDEAL,
                              "--workers", "1", "--out", str(tmp_path / "c")])
    assert "protocol plugin_protocols:NaNPlan: plan returned array([nan, 0.2])" in message


@pytest.mark.parametrize(("factory", "fragment"), [
    ("raises", "its factory raised RuntimeError: factory boom"),
    ("returns_none", "its factory returned None, not an estimator"),
    ("UpdateRaises", "update raised ValueError: update boom"),
    ("NaNParams", "params is array([nan, nan, nan]), not 3 finite values"),
    ("TwoParams", "params is array([1., 2.]), not 3 finite values"),
    ("NaNCovariance", "covariance is array([[nan, nan, nan], [nan, nan, nan], [nan, "),
    ("OneArgUpdate", "its update(segment) does not take the segment's five values "
                     "update(dphi_L, dphi_R, dx, dy, dtheta) (rad, rad, m, m, rad)"),
])
def test_a_misbehaving_user_estimator_is_a_one_line_error_naming_it(plugins, tmp_path, capsys,
                                                                    factory, fragment):
    message = _error(capsys, ["compare", "--protocols", "spin", "--estimators",
                              f"plugin_estimators:{factory}", "--episodes", "1",
                              "--segments", "2", "--env", IDEAL, "--workers", "1",
                              "--out", str(tmp_path / "c")])
    assert f"estimator plugin_estimators:{factory}: {fragment}" in message


@pytest.mark.slow
def test_a_learned_policy_with_discrete_actions_is_refused(tmp_path, capsys):
    from stable_baselines3 import PPO

    from agents.learned import SHIPPED_POLICY
    from agents.train import normalization_path

    policy = tmp_path / "discrete.zip"
    PPO("MlpPolicy", "CartPole-v1", device="cpu").save(policy)
    shutil.copy(normalization_path(SHIPPED_POLICY), normalization_path(policy))
    message = _error(capsys, _simulate(tmp_path, f"learned:policy={policy}"))
    assert f"{policy}: the policy's actions are Discrete(2), not two wheel-speed" in message


def test_builtin_protocol_bugs_stay_internal_errors(monkeypatch, tmp_path, capsys):
    """Only a user's code is bad input: an exception in excite's own protocols is a bug,
    reported as an internal error (exit 1), not blamed on the user."""
    from agents.protocols import Spin

    def broken(self, knowledge):
        raise ZeroDivisionError("excite's bug")

    monkeypatch.setattr(Spin, "plan", broken)
    assert main(_simulate(tmp_path, "spin")) == 1
    assert "internal error: ZeroDivisionError" in capsys.readouterr().err


def test_an_excite_bug_under_a_users_subclass_stays_an_internal_error(plugins, monkeypatch,
                                                                      tmp_path, capsys):
    """A user's subclass whose own code is fine, over excite code that fails (the wall guard,
    here replaced by a C function called with the wrong arguments: no user frame on the
    traceback): excite's bug, not blamed on the user's protocol."""
    import math

    import agents.protocols

    monkeypatch.setattr(agents.protocols, "safe_actions", math.sqrt)
    assert main(_simulate(tmp_path, "plugin_protocols:SpinChild")) == 1
    assert "internal error: TypeError" in capsys.readouterr().err


def test_a_protocol_file_replaced_at_the_same_path_is_loaded_again(plugins, tmp_path):
    """A long-lived process (a notebook, a test session) keeps one protocol per spec, but not
    across a change of the file it names (a policy retrained at the same path)."""
    from agents.catalog import parse_protocol
    from agents.compare import _worker_protocol

    speed = tmp_path / "speed.txt"
    speed.write_text("0.2")
    spec = parse_protocol(f"plugin_protocols:FromFile:path={speed}")
    first = _worker_protocol(spec)
    assert _worker_protocol(spec) is first  # loaded once
    speed.write_text("0.4")
    assert _worker_protocol(spec).speed == 0.4


def test_a_fingerprint_that_is_not_text_is_named(plugins):
    from agents.catalog import ProtocolError, parse_protocol
    from agents.compare import _worker_protocol

    with pytest.raises(ProtocolError, match=r"ListFingerprint: fingerprint returned \['not'"):
        _worker_protocol(parse_protocol("plugin_protocols:ListFingerprint"))


def test_a_policy_file_changed_during_a_comparison_stops_it(plugins, tmp_path, capsys):
    """Episodes after the change would run another policy under the same label: a one-line
    error, and the episode finished before is kept."""
    speed = tmp_path / "speed.txt"
    speed.write_text("0.2")
    message = _error(capsys, ["compare", "--protocols",
                              f"plugin_protocols:RetrainedDuringRun:path={speed}",
                              "--episodes", "2", "--segments", "2", "--env", IDEAL,
                              "--workers", "1", "--out", str(tmp_path / "c")])
    assert "its files here differ from those the comparison started with" in message
    rows = (tmp_path / "c" / "segments.csv").read_text().splitlines()
    assert len(rows) == 1 + 2  # the header and episode 0's two segments


def test_the_installed_command_finds_a_user_module_in_the_working_folder():
    """The console script `excite` (not `python -m excite.cli`) does not put the working
    folder on sys.path: `cd examples; excite protocols custom_protocol:Sweep`, as the README
    says, failed with "no module named 'custom_protocol'" (found by fuzzing)."""
    import subprocess
    from pathlib import Path

    command = Path(sys.executable).with_name("excite")
    assert command.exists(), "the package is installed with its console script"
    examples = Path(__file__).resolve().parents[2] / "examples"
    done = subprocess.run([str(command), "protocols", "custom_protocol:Sweep"], cwd=examples,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("custom_protocol:Sweep")
