"""One recorded episode of a protocol on an env, for the regression tests of logs that
once came back wrong (the held-out logs of benchmarks/bench_slip_misfit.py)."""

from __future__ import annotations

from agents.catalog import make_protocol, parse_protocol
from agents.compare import make_env, run_protocol_episode
from envs.recording import Recording

#: The slip env.
SLIP = "excite/DiffDriveCalib-v0"


def recorded_episode(env_id: str, protocol: str, seed: int, segments: int) -> Recording:
    """The recording (encoder and pose streams) of ``protocol`` (its text) driving
    ``segments`` segments of ``env_id`` with ``seed``."""
    spec = parse_protocol(protocol)
    env = make_env(env_id, segments, record=True)
    run_protocol_episode(env, make_protocol(spec), seed, None, label=spec.label)
    recording = env.unwrapped.recording
    env.close()
    return recording
