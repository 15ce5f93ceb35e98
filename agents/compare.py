"""Paired comparison of calibration protocols on the same hidden robots (``excite compare``).

Episode i gives every protocol the same hidden robot, start pose and sensor-noise streams
(the env is reset with the same seed), so differences are protocol effects, not luck.
Protocols are specs (``umbmark:speed=0.2``, see :mod:`agents.catalog`); their labels name
them in the results. Episode seeds come from one of two disjoint streams: ``evaluation``
(``excite compare``) and ``tuning`` (``excite tune``), see :func:`episode_seed`.
Episodes run in parallel worker processes; each finished episode's rows are appended to
``DIR/segments.csv`` at once, so an interrupted run re-run with the same ``DIR`` continues
where it stopped, losing and duplicating nothing.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import os
from collections.abc import Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import excite  # noqa: F401  (registers the environment ids in worker processes)
from agents.catalog import ProtocolSpec, check_distinct, make_protocol, parse_protocol
from agents.oracle import oracle_design
from agents.protocols import Protocol
from excite.errors import ExciteError
from excite.information import crlb_relative_std
from excite.registration import DEFAULT_BUDGET, DEFAULT_ENV_ID

COLUMNS = ("protocol", "episode", "segment", "r_L_err", "r_R_err", "b_err", "sigma_min",
           "oracle_sigma_min", "rel_std_r_L", "rel_std_r_R", "rel_std_b", "collision",
           "x", "y", "theta", "distance")
#: The seed streams of episodes; stream i's env seeds lie in [i 2**32, (i + 1) 2**32).
EVALUATION_STREAM, TUNING_STREAM = STREAMS = ("evaluation", "tuning")
STREAM_SPAN = 2**32


class CompareError(ExciteError, ValueError):
    """Bad settings for a comparison (e.g. an output folder made with other settings)."""


@dataclass(frozen=True)
class CompareSettings:
    """What makes two runs comparable (stored in DIR/config.json)."""

    env_id: str = DEFAULT_ENV_ID
    segments: int = DEFAULT_BUDGET
    seed: int = 0
    robot: str = "default"  # a robot preset (envs.robot.PRESETS)
    stream: str = EVALUATION_STREAM  # the seed stream of the episodes (STREAMS)
    final_only: bool = False  # keep only each episode's last segment (all that tuning needs)


def episode_seed(seed: int, episode: int, stream: str = EVALUATION_STREAM) -> int:
    """The env seed of one episode: distinct for every (seed, episode) pair of a stream.

    Stream i's seeds lie in [i 2**32, (i + 1) 2**32), so no tuning episode is ever an
    evaluation episode, whatever the seeds and episode counts (seed >= 0).
    """
    index = STREAMS.index(stream)
    entropy = [seed, episode] if index == 0 else [seed, episode, index]
    return index * STREAM_SPAN + int(np.random.SeedSequence(entropy).generate_state(1)[0])


def episode_seeds(settings: CompareSettings, episodes: int) -> list[int]:
    """The env seeds of episodes 0 .. episodes-1 of these settings."""
    return [episode_seed(settings.seed, e, settings.stream) for e in range(episodes)]


def make_env(env_id: str, segments: int, robot: str = "default", **config) -> gym.Env:
    """The env ``env_id`` with a budget of ``segments``, the robot preset and further config
    overrides."""
    return gym.make(env_id, budget=segments, robot=robot, **config)


def run_protocol_episode(env: gym.Env, protocol: Protocol, seed: int) -> list[dict]:
    """Run one episode of ``protocol``; one record per segment (see COLUMNS)."""
    env.reset(seed=seed)
    base = env.unwrapped
    protocol.reset(np.random.default_rng([seed, 1]))
    truth = base.true_params.as_array()
    records, distance, done = [], 0.0, False
    knowledge = base.knowledge()
    while not done:
        _, _, terminated, truncated, info = env.step(protocol.act(knowledge))
        done = terminated or truncated
        knowledge = base.knowledge()
        distance += base.last_segment_distance
        err = knowledge.estimate.as_array() / truth - 1.0
        rel_std = crlb_relative_std(knowledge.information)
        x, y, theta = base.sim.pose
        records.append({
            "segment": info["n_segments"], "r_L_err": err[0], "r_R_err": err[1],
            "b_err": err[2], "sigma_min": info["sigma_min"],
            "rel_std_r_L": rel_std[0], "rel_std_r_R": rel_std[1], "rel_std_b": rel_std[2],
            "collision": int(info["collision"]), "x": x, "y": y, "theta": theta,
            "distance": distance,
        })
    return records


@functools.cache
def _worker_protocol(spec: ProtocolSpec) -> Protocol:
    """One instance per protocol and worker process (a learned policy is loaded once, not
    every episode); run_protocol_episode resets it at the start of each episode."""
    return make_protocol(spec)


def as_specs(protocols: Iterable[str | ProtocolSpec]) -> list[ProtocolSpec]:
    """Protocols given as specs or as their text, as distinct specs."""
    return check_distinct(parse_protocol(p) if isinstance(p, str) else p for p in protocols)


def incompatible_protocols(protocols: Iterable[ProtocolSpec],
                           observation_shape: tuple[int, ...]) -> dict[str, str]:
    """Labels of the protocols that cannot run on an env with this observation shape (e.g. a
    policy trained for another observation layout), with the reason in words."""
    shape = tuple(observation_shape)
    reasons = {spec.label: make_protocol(spec).incompatibility(shape) for spec in protocols}
    return {label: reason for label, reason in reasons.items() if reason}


def run_episode(settings: CompareSettings, protocols: list[ProtocolSpec],
                episode: int) -> list[dict]:
    """All requested protocols on episode ``episode`` (runs in a worker process)."""
    env = make_env(settings.env_id, settings.segments, settings.robot)
    seed = episode_seed(settings.seed, episode, settings.stream)
    env.reset(seed=seed)
    base = env.unwrapped
    oracle = oracle_design(base.true_theta, base.sigma, base.nominal_theta, settings.segments,
                           base.max_wheel_speed, base.segment_duration,
                           model=base.model).sigma_min
    rows = []
    for spec in protocols:
        records = run_protocol_episode(env, _worker_protocol(spec), seed)
        for record in records[-1:] if settings.final_only else records:
            rows.append({"protocol": spec.label, "episode": episode,
                         "oracle_sigma_min": oracle, **record})
    env.close()
    return rows


# -- the results file -----------------------------------------------------------------------
def _parse(row: dict[str, str]) -> dict | None:
    try:
        out = {"protocol": row["protocol"], "episode": int(row["episode"]),
               "segment": int(row["segment"]), "collision": int(row["collision"])}
        for key in COLUMNS[3:]:
            if key != "collision":
                out[key] = float(row[key])
    except (KeyError, TypeError, ValueError):
        return None
    return out


def read_complete_rows(path: Path, segments: int, final_only: bool = False) -> list[dict]:
    """Rows of every (protocol, episode) present with all segments exactly once (or only the
    last, ``final_only``); partial episodes (an interrupted write) and malformed lines are
    dropped."""
    if not path.exists():
        return []
    groups: dict[tuple[str, int], dict[int, dict]] = {}
    with open(path, newline="") as handle:
        for raw in csv.DictReader(handle):
            row = _parse(raw)
            if row is not None:
                groups.setdefault((row["protocol"], row["episode"]), {})[row["segment"]] = row
    expected = [segments] if final_only else list(range(1, segments + 1))
    complete = [g for g in groups.values() if sorted(g) == expected]
    return [row for g in complete for _, row in sorted(g.items())]


def _write_rows(path: Path, rows: Iterable[dict], mode: str) -> None:
    with open(path, mode, newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        if mode == "w":
            writer.writeheader()
        writer.writerows({k: _format(row[k]) for k in COLUMNS} for row in rows)
        handle.flush()
        os.fsync(handle.fileno())


def _format(value):
    """CSV text of a value: floats (numpy's too) in shortest round-trip form."""
    if isinstance(value, float | np.floating):
        value = float(value)
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, np.integer):
        return int(value)
    return value


def _check_settings(out_dir: Path, settings: CompareSettings) -> None:
    config = out_dir / "config.json"
    if config.exists():
        try:
            stored = json.loads(config.read_text())
        except json.JSONDecodeError:
            raise CompareError(
                f"{config}: not valid JSON; remove it or choose another --out") from None
        if not isinstance(stored, dict):
            raise CompareError(f"{config}: not a comparison's settings; remove it or choose "
                               "another --out")
        stored = {**asdict(CompareSettings()), **stored}  # keys added since: their defaults
        if stored != asdict(settings):
            raise CompareError(
                f"{out_dir} holds a comparison with other settings ({stored}); "
                "use another --out or the same --env, --segments, --seed and --robot")
    else:
        config.write_text(json.dumps(asdict(settings), indent=2) + "\n")


def run_comparison(
    out_dir: str | Path,
    protocols: Sequence[str | ProtocolSpec],
    episodes: int,
    settings: CompareSettings | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> list[dict]:
    """Run (or finish) a comparison in ``out_dir``; returns the rows of the requested
    protocols (specs or their text; rows name them by label) and episodes. Every protocol is
    built once before any work starts, so bad names or settings fail at once."""
    settings = settings or CompareSettings()
    specs = as_specs(protocols)
    for spec in specs:
        make_protocol(spec)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _check_settings(out, settings)
    csv_path = out / "segments.csv"
    rows = read_complete_rows(csv_path, settings.segments, settings.final_only)
    _write_rows(csv_path, rows, "w")  # rewrite without partial episodes or duplicates
    done = {(r["protocol"], r["episode"]) for r in rows}
    todo = {e: [s for s in specs if (s.label, e) not in done] for e in range(episodes)}
    todo = {e: s for e, s in todo.items() if s}

    bar = tqdm(total=len(todo), desc="episodes", unit="ep", disable=not progress)
    with ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
        pending = {pool.submit(run_episode, settings, names, e) for e, names in todo.items()}
        try:
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    new_rows = future.result()
                    _write_rows(csv_path, new_rows, "a")
                    rows.extend(new_rows)
                    bar.update(1)
        except BaseException:
            for future in pending:
                future.cancel()
            raise
        finally:
            bar.close()
    wanted = {spec.label for spec in specs}
    return [r for r in rows if r["protocol"] in wanted and r["episode"] < episodes]


def columns_of(rows: Sequence[dict]) -> dict[str, np.ndarray]:
    """Rows of a comparison as columns (equal-length arrays, one per COLUMNS key), the input
    of :mod:`agents.report`."""
    return {key: np.array([row[key] for row in rows]) for key in COLUMNS}
