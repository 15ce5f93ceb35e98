"""One episode of a shipped protocol on the slip env, as benchmarks/bench_slip_misfit.py
drives it: the regression tests' logs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents.catalog import make_protocol, parse_protocol
from agents.compare import make_env, run_protocol_episode
from excite.logs.segments import Segments

SLIP = "excite/DiffDriveCalib-v0"


@dataclass(frozen=True)
class Episode:
    """The truth (r_L, r_R, b in m), the env's segments and, when recorded, the time-series
    recording (``envs`` Recording: ``series`` and ``ticks_per_rev``)."""

    truth: np.ndarray
    segments: Segments
    recording: object | None


def slip_episode(protocol: str, seed: int, record: bool = False, segments: int = 30
                 ) -> Episode:
    """``protocol`` (NAME[:KEY=VALUE...]) for ``segments`` segments on the slip env, the
    episode's seed ``seed``."""
    spec = parse_protocol(protocol)
    env = make_env(SLIP, segments, record=record)
    try:
        run_protocol_episode(env, make_protocol(spec), seed, None, label=spec.label)
        base = env.unwrapped
        return Episode(base.true_params.as_array(), base.segments,
                       base.recording if record else None)
    finally:
        env.close()
