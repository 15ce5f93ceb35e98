"""Paired comparison of calibration protocols on the same hidden robots (``excite compare``).

Episode i gives every (protocol, estimator) pair the same hidden robot, start pose and
sensor-noise streams (the env is reset with the same seed), so differences are protocol and
estimator effects, not luck. Protocols are specs (``umbmark:speed=0.2``, see
:mod:`agents.catalog`), estimators too (``window:size=20``, ``mypkg.est:factory``, see
:mod:`excite.estimators`; plugged in as the env's ``estimator_factory``); their labels name
them in the results. Episode seeds come from one of two disjoint streams: ``evaluation``
(``excite compare``) and ``tuning`` (``excite tune``), see :func:`episode_seed`.
Episodes run in parallel worker processes or Ray tasks (:mod:`agents.backends`); each
finished task's rows are appended to ``DIR/segments.csv`` at once, so an interrupted run
re-run with the same ``DIR`` continues where it stopped (per protocol, estimator and
episode), losing and duplicating nothing.

With a target (``CompareSettings.target``) every episode runs in the env's target mode: it
ends where the stopping rule says done, or at the budget, and its rows carry the columns of
:mod:`agents.target_record`; such an episode is complete when it ends at its stop or at the
budget.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import os
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import excite  # noqa: F401  (registers the environment ids in worker processes)
from agents.backends import LOCAL, chunk_size, open_backend
from agents.catalog import (
    Checked,
    ProtocolSpec,
    calling,
    check_distinct,
    make_protocol,
    parse_protocol,
    user_supplied,
)
from agents.oracle import oracle_design
from agents.protocols import Protocol, ProtocolError
from agents.target_record import TARGET_COLUMNS, target_fields
from excite.core.information import crlb_relative_std
from excite.errors import ExciteError
from excite.estimators import DEFAULT_ESTIMATOR, EstimatorSpec, estimator_factory
from excite.estimators import check_distinct as check_distinct_estimators
from excite.registration import DEFAULT_BUDGET, DEFAULT_ENV_ID
from excite.stats.consistency import estimate_error, nees
from excite.stopping import DEFAULT_CONFIDENCE

#: The columns of DIR/segments.csv (see :mod:`agents.segment_record` for their meaning and units);
#: with a target, followed by agents.target_record.TARGET_COLUMNS.
COLUMNS = ("protocol", "estimator", "episode", "segment", "r_L_err", "r_R_err", "b_err",
           "sigma_min", "oracle_sigma_min", "rel_std_r_L", "rel_std_r_R", "rel_std_b",
           "nees", "nees_dof", "collision", "x", "y", "theta", "distance", "time")
#: The text columns and the integer columns; every other column is a float.
_TEXT, _INTEGER = ("protocol", "estimator"), ("episode", "segment", "nees_dof", "collision",
                                                "stop")
#: One run of an episode: a protocol driving, an estimator estimating.
Pair = tuple[ProtocolSpec, EstimatorSpec]
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
    target: float | None = None  # target mode's relative error (None: off), see envs.target
    target_confidence: float = DEFAULT_CONFIDENCE  # the stopping rule's confidence


def settings_dict(settings: CompareSettings) -> dict:
    """The settings as DIR/config.json stores them: without the target keys when the
    target is off (the file of such a run is the one an excite without targets wrote)."""
    out = asdict(settings)
    if settings.target is None:
        del out["target"], out["target_confidence"]
    return out


def columns_for(target: bool) -> tuple[str, ...]:
    """The columns of DIR/segments.csv: COLUMNS, then TARGET_COLUMNS with a target."""
    return COLUMNS + TARGET_COLUMNS if target else COLUMNS


def target_config(settings: CompareSettings) -> dict:
    """The env's target-mode keys of these settings (none when the target is off)."""
    if settings.target is None:
        return {}
    return {"target": settings.target, "target_confidence": settings.target_confidence}


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
    """The env ``env_id`` with a budget of ``segments``, the robot preset and further
    keyword arguments of the env (config overrides, ``estimator_factory``)."""
    return gym.make(env_id, budget=segments, robot=robot, **config)


def run_protocol_episode(env: gym.Env, protocol: Protocol, seed: int,
                         options: dict | None = None, label: str | None = None) -> list[dict]:
    """Run one episode of ``protocol`` with the env's estimator (reset with ``seed`` and
    ``options``); one record per segment (see COLUMNS). ``label`` names the protocol in
    errors (default: its class name): an action that is not two finite numbers, or a user's
    protocol raising, is a ProtocolError naming it. ``nees`` is the estimator's NEES
    against the hidden truth over the ``nees_dof`` parameters it reports a covariance for
    (:func:`excite.stats.consistency.estimate_error`), ``time`` the seconds driven since the
    start. In the env's target mode each record also holds the columns of
    :func:`agents.target_record.target_fields`."""
    checked = Checked(protocol, label or type(protocol).__name__)
    env.reset(seed=seed, options=options)
    base = env.unwrapped
    checked.reset(np.random.default_rng([seed, 1]))
    truth, true_theta = base.true_params.as_array(), base.true_theta
    seconds_per_segment = base.segment_duration + float(base.config["settle_time"])
    records, distance, done = [], 0.0, False
    knowledge = base.knowledge()
    while not done:
        _, _, terminated, truncated, info = env.step(checked.act(knowledge))
        done = terminated or truncated
        knowledge = base.knowledge()
        distance += base.last_segment_distance
        err = knowledge.estimate.as_array() / truth - 1.0
        rel_std = crlb_relative_std(knowledge.information)
        error, covariance = estimate_error(base.estimator, true_theta)
        x, y, theta = base.sim.pose
        records.append({
            "segment": info["n_segments"], "r_L_err": err[0], "r_R_err": err[1],
            "b_err": err[2], "sigma_min": info["sigma_min"],
            "rel_std_r_L": rel_std[0], "rel_std_r_R": rel_std[1], "rel_std_b": rel_std[2],
            "nees": float(nees(error, covariance)), "nees_dof": error.size,
            "collision": int(info["collision"]), "x": x, "y": y, "theta": theta,
            "distance": distance, "time": info["n_segments"] * seconds_per_segment,
            **(target_fields(env) if "stop" in info else {}),
        })
    return records


def _worker_protocol(spec: ProtocolSpec, expected: str | None = None) -> Protocol:
    """One instance per protocol, file content and process (a learned policy is loaded once,
    not every episode, and loaded again when its file has changed since); run_protocol_episode
    resets it at the start of each episode. ``expected``: the digest of its files when the
    comparison started (a ProtocolError if they have changed since: one label, one policy)."""
    digest = spec.fingerprint()
    if expected is not None and digest != expected:
        raise ProtocolError(
            f"protocol {spec.label}: its files here differ from those the comparison started "
            f"with (sha256 {str(digest)[:12]}, was {expected[:12]}: changed since, or another "
            "copy on this node); the episodes finished are kept: start again with another --out")
    return _protocol_instance(spec, digest)


@functools.lru_cache(maxsize=256)  # tune's default grid has 111 candidates
def _protocol_instance(spec: ProtocolSpec, fingerprint: str | None) -> Protocol:
    """``spec``'s protocol, kept per (spec, digest of the files it names)."""
    return make_protocol(spec)


def as_specs(protocols: Iterable[str | ProtocolSpec]) -> list[ProtocolSpec]:
    """Protocols given as specs or as their text, as distinct specs."""
    return check_distinct(parse_protocol(p) if isinstance(p, str) else p for p in protocols)


def as_estimator_specs(estimators: Iterable[str | EstimatorSpec]) -> list[EstimatorSpec]:
    """Estimators given as specs or as their text, as distinct specs."""
    return check_distinct_estimators(
        [estimator_factory(e) if isinstance(e, str) else e for e in estimators])


def incompatible_protocols(protocols: Iterable[ProtocolSpec],
                           observation_shape: tuple[int, ...]) -> dict[str, str]:
    """Labels of the protocols that cannot run on an env with this observation shape (e.g. a
    policy trained for another observation layout), with the reason in words. Each is built
    once and kept for the episodes run in this process."""
    shape = tuple(observation_shape)
    reasons = {}
    for spec in protocols:
        protocol = _worker_protocol(spec)
        with calling(spec.label, "incompatibility", user_supplied(type(protocol).__module__)):
            reasons[spec.label] = protocol.incompatibility(shape)
    return {label: reason for label, reason in reasons.items() if reason}


def run_episodes(settings: CompareSettings, work: Sequence[tuple[int, list[Pair]]],
                 digests: Mapping[str, str] | None = None) -> list[list[dict]]:
    """The rows of :func:`run_episode` of each (episode, pairs) of ``work``: one task of an
    execution backend (:mod:`agents.backends`)."""
    return [run_episode(settings, pairs, episode, digests) for episode, pairs in work]


def run_episode(settings: CompareSettings, pairs: list[Pair], episode: int,
                digests: Mapping[str, str] | None = None) -> list[dict]:
    """All requested (protocol, estimator) pairs on episode ``episode`` (runs in a worker
    process): one env per estimator (its ``estimator_factory``), each reset with the
    episode's seed, so every pair meets the same hidden robot. ``digests``: protocol label ->
    the digest of its files when the comparison started (see :func:`_worker_protocol`)."""
    seed = episode_seed(settings.seed, episode, settings.stream)
    envs: dict[str, gym.Env] = {}
    rows, oracle = [], None
    for protocol, estimator in pairs:
        if estimator.label not in envs:
            envs[estimator.label] = make_env(settings.env_id, settings.segments,
                                             settings.robot, estimator_factory=estimator,
                                             **target_config(settings))
        env = envs[estimator.label]
        if oracle is None:  # the robot's design bound: the same for every pair
            env.reset(seed=seed)
            base = env.unwrapped
            oracle = oracle_design(base.true_theta, base.sigma, base.nominal_theta,
                                   settings.segments, base.max_wheel_speed,
                                   base.segment_duration, model=base.model).sigma_min
        expected = None if digests is None else digests.get(protocol.label)
        records = run_protocol_episode(env, _worker_protocol(protocol, expected), seed,
                                       label=protocol.label)
        for record in records[-1:] if settings.final_only else records:
            rows.append({"protocol": protocol.label, "estimator": estimator.label,
                         "episode": episode, "oracle_sigma_min": oracle, **record})
    for env in envs.values():
        env.close()
    return rows


# -- the results file -----------------------------------------------------------------------
def _parse(row: dict[str, str], columns: tuple[str, ...]) -> dict | None:
    try:
        out = {}
        for key in columns:
            kind = str if key in _TEXT else int if key in _INTEGER else float
            out[key] = kind(row[key])
    except (KeyError, TypeError, ValueError):
        return None
    return out


def read_complete_rows(path: Path, segments: int, final_only: bool = False,
                       target: bool = False) -> list[dict]:
    """Rows of every (protocol, estimator, episode) present with all segments exactly once
    (or only the last, ``final_only``); partial episodes (an interrupted write) and malformed
    lines are dropped. An episode ends at the budget ``segments``, or with ``target`` (the
    columns of :func:`columns_for` with a target) at the segment whose ``stop`` is 1.
    CompareError for a file with other columns (written by an older excite, before
    estimators were an axis)."""
    if not path.exists():
        return []
    columns = columns_for(target)
    groups: dict[tuple[str, str, int], dict[int, dict]] = {}
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        if reader.fieldnames is not None and tuple(reader.fieldnames) != columns:
            raise CompareError(
                f"{path}: columns {','.join(reader.fieldnames)} are not those of this excite "
                f"version ({','.join(columns)}); it was written by an older excite: re-run "
                "it into another --out")
        for raw in reader:
            row = _parse(raw, columns)
            if row is not None:
                key = (row["protocol"], row["estimator"], row["episode"])
                groups.setdefault(key, {})[row["segment"]] = row

    def complete(group: dict[int, dict]) -> bool:
        last = max(group)
        ends = last == segments or (target and last < segments and group[last]["stop"] == 1)
        return ends and sorted(group) == ([last] if final_only else list(range(1, last + 1)))

    return [row for g in groups.values() if complete(g) for _, row in sorted(g.items())]


def _write_rows(path: Path, rows: Iterable[dict], mode: str,
                columns: tuple[str, ...] = COLUMNS) -> None:
    """Append rows (mode "a"), or replace the file by a header and rows (mode "w", atomic: a
    kill while writing leaves the old file)."""
    out = path.with_name(path.name + ".partial") if mode == "w" else path
    with open(out, mode, newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        if mode == "w":
            writer.writeheader()
        writer.writerows({k: _format(row[k]) for k in columns} for row in rows)
        handle.flush()
        os.fsync(handle.fileno())
    if mode == "w":
        os.replace(out, path)


def _format(value):
    """CSV text of a value: floats (numpy's too) in shortest round-trip form."""
    if isinstance(value, float | np.floating):
        value = float(value)
        if math.isnan(value):
            return "nan"
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, np.integer):
        return int(value)
    return value


#: The key of DIR/config.json that ties each protocol's results to the content of the files
#: its settings name (:meth:`agents.catalog.ProtocolSpec.fingerprint`: label -> sha256).
FILES_KEY = "protocol_files"


def _read_config(config: Path) -> dict | None:
    """DIR/config.json's content, None when there is none; CompareError when it is not a
    comparison's settings."""
    if not config.exists():
        return None
    try:
        stored = json.loads(config.read_text())
    except json.JSONDecodeError:
        raise CompareError(f"{config}: not valid JSON; remove it or choose another --out") from None
    except IsADirectoryError:
        raise CompareError(f"{config} is a folder; remove it or choose another --out") from None
    if not isinstance(stored, dict) or not isinstance(stored.get(FILES_KEY, {}), dict):
        raise CompareError(f"{config}: not a comparison's settings; remove it or choose "
                           "another --out")
    return stored


def _resumable_rows(out_dir: Path, settings: CompareSettings,
                    specs: Sequence[ProtocolSpec]) -> tuple[list[dict], dict[str, str]]:
    """The complete rows already in ``out_dir`` that this run may keep, and the digests of the
    protocols' files (label -> sha256, for those that name files), after checking
    DIR/config.json (read once, written once when it changes): the settings must be the
    stored ones (a CompareError otherwise; rows without a config.json too), and each
    protocol's results are tied to the content of the files its settings name (a learned
    policy): a protocol whose files changed since its results were made is a CompareError
    (resuming would mix or silently reuse results of another policy); the digests of the
    others are recorded."""
    config = out_dir / "config.json"
    stored = _read_config(config)
    if stored is not None:
        compared = {**asdict(CompareSettings()), **stored}  # keys added since: defaults
        compared.pop(FILES_KEY, None)
        if compared != asdict(settings):
            now = asdict(settings)
            differ = ", ".join(f"{key} {compared.get(key)!r} (now {now.get(key)!r})"
                               for key in sorted(set(now) | set(compared))
                               if compared.get(key) != now.get(key))
            raise CompareError(f"{out_dir} holds episodes of other settings: {differ}; use "
                               "another --out or the same settings")
    rows = read_complete_rows(out_dir / "segments.csv", settings.segments,
                              settings.final_only, settings.target is not None)
    if stored is None and rows:
        raise CompareError(f"{out_dir / 'segments.csv'} holds results but {config} is missing: "
                           "cannot tell which settings made them; use another --out")
    known = dict((stored or {}).get(FILES_KEY, {}))
    present = {row["protocol"] for row in rows}
    for spec in specs:
        digest = spec.fingerprint()
        if digest is None:
            continue
        old = known.get(spec.label)
        if old is None and spec.label in present:
            raise CompareError(
                f"{out_dir} holds results of {spec.label} that are not tied to its files' "
                "content (made by an older excite): cannot tell whether they came from the "
                "same policy; use another --out")
        if old is not None and old != digest and spec.label in present:
            raise CompareError(
                f"{spec.label}: its files changed since {out_dir} ran it (sha256 "
                f"{digest[:12]}, was {old[:12]}): its results there are of another policy; "
                "use another --out")
        known[spec.label] = digest
    if stored is None or known != stored.get(FILES_KEY, {}):
        content = {**(stored or settings_dict(settings)),
                   **({FILES_KEY: known} if known else {})}
        config.write_text(json.dumps(content, indent=2) + "\n")
    return rows, known


def run_comparison(
    out_dir: str | Path,
    protocols: Sequence[str | ProtocolSpec],
    episodes: int,
    settings: CompareSettings | None = None,
    workers: int | None = None,
    progress: bool = True,
    estimators: Sequence[str | EstimatorSpec] = (DEFAULT_ESTIMATOR,),
    backend: str = LOCAL,
    address: str | None = None,
) -> list[dict]:
    """Run (or finish) a comparison in ``out_dir``; returns the rows of every requested
    (protocol, estimator) pair (specs or their text; rows name them by label) and episode.
    Every protocol is built once before any work starts, so bad names or settings fail at
    once.

    Episodes run on ``backend`` (:mod:`agents.backends`: ``local`` worker processes, at most
    ``workers``; ``ray`` at ``address``). On a backend whose tasks must carry at least
    ``task_seconds`` of work (Ray), the first episode runs here and is timed, and the others
    are grouped into tasks of ``ceil(task_seconds / that time)`` episodes; locally each
    episode is a task. Each finished task's rows are appended to ``segments.csv`` at once;
    at the end the file is rewritten in episode order, so it does not depend on the backend
    or on which task finished first."""
    settings = settings or CompareSettings()
    specs = as_specs(protocols)
    estimator_specs = as_estimator_specs(estimators)
    for spec in specs:
        _worker_protocol(spec)  # built (and kept for the episodes run here) or an error now
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows, digests = _resumable_rows(out, settings, specs)
    csv_path = out / "segments.csv"
    columns = columns_for(settings.target is not None)
    _write_rows(csv_path, rows, "w", columns)  # rewrite without partial episodes or duplicates
    done = {(r["protocol"], r["estimator"], r["episode"]) for r in rows}
    todo = {e: [(p, m) for p in specs for m in estimator_specs
                if (p.label, m.label, e) not in done] for e in range(episodes)}
    todo = {e: s for e, s in todo.items() if s}

    with open_backend(backend, address, workers) as executor:
        bar = tqdm(total=len(todo), desc="episodes", unit="ep", disable=not progress)

        def record(episode_rows: list[list[dict]]) -> None:
            new_rows = [row for rows_of_one in episode_rows for row in rows_of_one]
            _write_rows(csv_path, new_rows, "a", columns)
            rows.extend(new_rows)
            bar.update(len(episode_rows))

        try:
            work = list(todo.items())
            size = 1
            if executor.task_seconds > 0 and work:  # measure an episode to size the tasks
                started = time.perf_counter()
                first = run_episodes(settings, work[:1], digests)
                size = chunk_size(executor.task_seconds, time.perf_counter() - started)
                record(first)
                work = work[1:]
            tasks = [(settings, work[i:i + size], digests)
                     for i in range(0, len(work), size)]
            for episode_rows in executor.imap_unordered(run_episodes, tasks):
                record(episode_rows)
        finally:
            bar.close()
    # One order whatever the backend and the order episodes finished in: by episode, then
    # protocol and estimator as requested (the file is identical for the same settings).
    rank = {spec.label: i for i, spec in enumerate(specs)}
    estimator_rank = {spec.label: i for i, spec in enumerate(estimator_specs)}
    rows.sort(key=lambda r: (r["episode"], rank.get(r["protocol"], len(rank)),
                             estimator_rank.get(r["estimator"], len(estimator_rank))))
    _write_rows(csv_path, rows, "w", columns)
    wanted = {(p.label, m.label) for p in specs for m in estimator_specs}
    return [r for r in rows
            if (r["protocol"], r["estimator"]) in wanted and r["episode"] < episodes]


def columns_of(rows: Sequence[dict]) -> dict[str, np.ndarray]:
    """Rows of a comparison as columns (equal-length arrays, one per COLUMNS key, and per
    TARGET_COLUMNS key when the rows have them): the segment record that
    :mod:`agents.summary` and :mod:`agents.plots` take."""
    keys = columns_for(bool(rows) and "stop" in rows[0])
    return {key: np.array([row[key] for row in rows]) for key in keys}
