"""The Ray backend of compare and tune against a real local Ray (one per session)."""

import os
import signal
import subprocess
import sys
import time

import pytest

from agents.backends import (
    RAY_TASK_SECONDS,
    BackendError,
    chunk_size,
    connect_ray,
    open_backend,
)
from agents.compare import CompareSettings, read_complete_rows, run_comparison
from tests.conftest import assert_one_line_error, run_cli

pytestmark = pytest.mark.xdist_group("ray")

IDEAL = "excite/DiffDriveCalibIdeal-v0"
SETTINGS = CompareSettings(IDEAL, 6, 2)
PROTOCOLS = ["spin", "umbmark", "random"]
EPISODES = 24


@pytest.fixture(scope="session")
def local_reference(tmp_path_factory):
    """The comparison run on the local backend (2 processes): the file Ray must reproduce."""
    out = tmp_path_factory.mktemp("local")
    run_comparison(out, PROTOCOLS, EPISODES, SETTINGS, workers=2, progress=False)
    return (out / "segments.csv").read_bytes()


def test_chunk_size_gives_tasks_of_at_least_the_target():
    for item in (0.01, 0.07, 0.3, 0.999, 1.0, 2.5):
        size = chunk_size(RAY_TASK_SECONDS, item)
        assert size * item >= RAY_TASK_SECONDS and (size - 1) * item < RAY_TASK_SECONDS
    assert chunk_size(0.0, 0.2) == 1


@pytest.mark.slow
def test_ray_tasks_yield_results_as_they_finish(ray_cluster, tmp_path):
    """The first task submitted waits for a file the driver writes only after it received
    the second task's result: results come in completion order, not submission order."""
    gate = tmp_path / "gate"
    with open_backend("ray") as executor:
        results = executor.imap_unordered(_wait_for, [(str(gate), "first submitted"),
                                                      (None, "second submitted")])
        assert next(results) == "second submitted"
        gate.touch()
        assert next(results) == "first submitted"


def _fail(message: str) -> None:
    raise BackendError(message)


@pytest.mark.slow
def test_an_excite_error_in_a_ray_task_is_raised_as_itself(ray_cluster):
    """Not Ray's wrapper, whose text carries the remote traceback: the CLI prints excite's
    errors on one line."""
    with open_backend("ray") as executor, pytest.raises(BackendError) as info:
        list(executor.imap_unordered(_fail, [("a worker's one-line error",)]))
    assert type(info.value) is BackendError
    assert str(info.value) == "a worker's one-line error"


def _wait_for(path: str | None, value: str, timeout: float = 60.0) -> str:
    deadline = time.time() + timeout
    while path is not None and not os.path.exists(path):
        if time.time() > deadline:
            return "timed out"
        time.sleep(0.02)
    return value


@pytest.mark.slow
def test_compare_on_ray_writes_the_same_file_as_local(ray_cluster, tmp_path, local_reference):
    rows = run_comparison(tmp_path, PROTOCOLS, EPISODES, SETTINGS, progress=False,
                          backend="ray")
    assert len(rows) == len(PROTOCOLS) * EPISODES * SETTINGS.segments
    assert (tmp_path / "segments.csv").read_bytes() == local_reference


@pytest.mark.slow
def test_ray_comparison_resumes_like_a_local_one(ray_cluster, tmp_path, local_reference):
    run_comparison(tmp_path, PROTOCOLS[:2], 5, SETTINGS, progress=False, backend="ray")
    with open(tmp_path / "segments.csv", "a") as handle:  # an interrupted write
        handle.write("random,0,1,0.1,0.1,0.1,5,9,1,1,1,0,0,0,0,0\nrandom,0,2,0.1,0.")
    run_comparison(tmp_path, PROTOCOLS, EPISODES, SETTINGS, progress=False, backend="ray")
    assert (tmp_path / "segments.csv").read_bytes() == local_reference


def _line_count(path) -> int:
    with open(path) as handle:
        return sum(1 for _ in handle)


@pytest.mark.slow
def test_killed_ray_compare_cli_resumes_to_the_local_file(ray_cluster, tmp_path,
                                                         local_reference):
    """`excite compare --backend ray --address` joins the session's Ray; SIGKILL it after
    some episodes and re-run the same command."""
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "excite.cli", "compare", "--protocols", ",".join(PROTOCOLS),
           "--episodes", str(EPISODES), "--segments", str(SETTINGS.segments), "--seed",
           str(SETTINGS.seed), "--env", IDEAL, "--backend", "ray", "--address", ray_cluster,
           "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, env=env)
    per_episode = len(PROTOCOLS) * SETTINGS.segments
    deadline = time.time() + 90
    while time.time() < deadline:  # the first episode (timed here) is written: kill
        path = out / "segments.csv"
        if path.exists() and _line_count(path) > per_episode:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    partial = len(read_complete_rows(out / "segments.csv", SETTINGS.segments))
    assert 0 < partial < per_episode * EPISODES
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    assert (out / "segments.csv").read_bytes() == local_reference


@pytest.mark.parametrize(
    "argv,fragment",
    [
        (["compare", "--address", "127.0.0.1:6379"], "--address needs --backend ray"),
        (["tune", "--address", "auto", "--out", "t.json"], "--address needs --backend ray"),
        (["compare", "--backend", "spark"], "invalid choice: 'spark'"),
        (["compare", "--backend", "ray", "--address", ""], "--address is empty"),
    ],
)
def test_bad_backend_options(tmp_path, capsys, monkeypatch, argv, fragment):
    monkeypatch.chdir(tmp_path)
    assert_one_line_error(*run_cli(capsys, *argv)[::2], fragment)
    assert not (tmp_path / "excite_compare").exists()


@pytest.mark.slow
def test_unreachable_ray_address_is_a_one_line_error_at_once(tmp_path):
    """In a fresh process (this one may already hold the session's Ray): nothing listens on
    port 1, and RAY_ADDRESS is read like --address."""
    base = [sys.executable, "-m", "excite.cli", "compare", "--protocols", "spin",
            "--episodes", "1", "--segments", "3", "--env", IDEAL, "--out", str(tmp_path / "o"),
            "--backend", "ray"]
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    for extra, ray_address in (["--address", "127.0.0.1:1"], None), ([], "127.0.0.1:1"), (
            ["--address", "nonsense"], None):
        started = time.time()
        run_env = {**env, "RAY_ADDRESS": ray_address} if ray_address else env
        done = subprocess.run(base + extra, capture_output=True, text=True, env=run_env)
        assert time.time() - started < 30
        assert done.returncode == 2
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("excite: error: "), done.stderr
        assert ("127.0.0.1:1" in lines[0]) or ("'nonsense' is not HOST:PORT" in lines[0])


@pytest.mark.slow
def test_connect_ray_uses_the_ray_already_initialised(ray_cluster):
    assert connect_ray("127.0.0.1:1") is False  # already connected: no new connection


def test_open_backend_rejects_unknown_names():
    with pytest.raises(BackendError, match="unknown backend"), open_backend("dask"):
        pass


@pytest.mark.slow
def test_tune_on_ray_writes_the_same_settings_as_local(ray_cluster, tmp_path, capsys):
    common = ["tune", "--protocols", "umbmark,spin", "--episodes", "6", "--segments", "5",
              "--env", IDEAL]
    local, on_ray = tmp_path / "local.json", tmp_path / "ray.json"
    assert run_cli(capsys, *common, "--workers", "2", "--out", local)[0] == 0
    assert run_cli(capsys, *common, "--backend", "ray", "--out", on_ray)[0] == 0
    assert on_ray.read_bytes() == local.read_bytes()
    assert (tmp_path / "ray.tuning" / "segments.csv").read_bytes() == (
        tmp_path / "local.tuning" / "segments.csv").read_bytes()


def test_without_ray_the_error_names_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as if not installed
    code, _, err = run_cli(capsys, "compare", "--protocols", "spin", "--episodes", "1",
                           "--segments", "3", "--env", IDEAL, "--backend", "ray", "--out",
                           tmp_path / "o")
    assert_one_line_error(code, err, "needs the ray extra", "pip install 'excite[ray]'")
