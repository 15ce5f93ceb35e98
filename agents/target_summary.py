"""The target part of a comparison's summary (``excite compare --target``): time to target,
false stops and the error at the stop, per (protocol, estimator) pair.

:func:`add_target` adds to each pair of a :func:`agents.summary.summarize` result the
``target`` entry computed from the target columns of the segment record
(:mod:`agents.target_record`), with the reference protocol's paired ratio of time to target
over each baseline (the machinery of :func:`agents.summary.paired_entry`). Computation only:
:mod:`agents.tables` prints it, :mod:`agents.plots` draws the survival curves.
"""

from __future__ import annotations

import numpy as np

from agents.metrics import N_BOOT, rate_interval
from agents.segment_record import pairs_of
from agents.summary import json_float, median_ci, paired_entry
from agents.target_record import Stops, false_stops, stops_of

#: The amounts driven until the target, as the keys of ``time_to_target``.
DRIVEN = ("segments", "seconds", "metres")


def _time_to_target(stops: Stops, resample: np.ndarray) -> dict:
    """Per driven amount: the median until the stop with its bootstrap interval (inf, None
    in JSON, where censored), and ``at_least`` when the median is censored: the median with
    each censored episode at what it drove within the budget, a lower bound; and the
    number of censored episodes."""
    out: dict = {}
    for key in DRIVEN:
        driven = getattr(stops, key)
        entry = median_ci(stops.to_target(driven), resample)
        if entry["median"] is None:
            entry["at_least"] = json_float(np.median(driven))
        out[key] = entry
    out["censored"] = int((~stops.stopped).sum())
    return out


def _error_at_stop(stops: Stops, rng: np.random.Generator, n_boot: int) -> dict:
    """The median over the stopped episodes of the batch calibration's max relative error
    of r_L, r_R, b at the stop, with its bootstrap interval; ``stops``, their number."""
    errors = stops.error[stops.stopped]
    if not errors.size:
        return {"median": None, "ci95": [None, None], "stops": 0}
    resample = rng.integers(0, errors.size, size=(n_boot, errors.size))
    return {**median_ci(errors, resample), "stops": int(errors.size)}


def target_entry(columns: dict[str, np.ndarray], protocol: str, estimator: str,
                 target: float, confidence: float, budget: int,
                 rng: np.random.Generator, n_boot: int = N_BOOT) -> tuple[dict, Stops]:
    """The ``target`` entry of one pair (see :func:`add_target`) and its :class:`Stops`."""
    stops = stops_of(columns, protocol, estimator)
    n = stops.episode.size
    resample = rng.integers(0, n, size=(n_boot, n))
    false = int(false_stops(columns, stops, target).sum())
    rate, (low, high) = rate_interval(false, int(stops.stopped.sum()))
    entry = {
        "value": float(target), "confidence": float(confidence), "budget": int(budget),
        "time_to_target": _time_to_target(stops, resample),
        "false_stop_rate": {"rate": rate, "ci95": [low, high], "false_stops": false,
                            "stops": int(stops.stopped.sum())},
        "error_at_stop": _error_at_stop(stops, rng, n_boot),
    }
    return entry, stops


def add_target(summary: dict, columns: dict[str, np.ndarray], target: float,
               confidence: float, budget: int, seed: int = 0, n_boot: int = N_BOOT) -> dict:
    """Add the ``target`` entry to every (protocol, estimator) pair of ``summary`` (a
    :func:`agents.summary.summarize` result of the same ``columns``, which hold the target
    columns); returns ``summary``.

    Args:
        target: the relative error of the comparison's target mode (0.005 = 0.5%).
        confidence: the stopping rule's confidence.
        budget: the segments an episode may drive (K).
        seed, n_boot: the bootstrap (a generator of its own from ``seed``: the rest of the
            summary is the same with and without this part).

    Per pair, ``target``:

    - ``value``, ``confidence``, ``budget``: the settings;
    - ``time_to_target``: ``segments``, ``seconds`` (s), ``metres`` (m) driven until the
      stopping rule said done, each ``{"median", "ci95"}`` over episodes with a percentile
      bootstrap interval; an episode not done within the budget is censored (counted as
      later than every stop), so a median is None when at least half are, with
      ``at_least``, the median of what the episodes drove with the censored ones at the
      budget (a lower bound); ``censored``, the number of censored episodes;
    - ``false_stop_rate``: ``false_stops`` (stopped while the truth was outside the target:
      see :mod:`agents.target_record`) over ``stops`` (the episodes that stopped), ``rate``
      (None without stops) and its Wilson 95% interval ``ci95``;
    - ``error_at_stop``: the batch calibration's max relative error of r_L, r_R, b at the
      stop, median over the stopped episodes with a bootstrap ``ci95``, and ``stops``;
    - ``vs_reference`` (baselines, when the reference protocol ``summary["reference"]`` ran
      with the same estimator): ``episodes`` (paired) and ``time_to_target``, the
      reference's median segments over the baseline's, ``{"ratio", "ci95"}`` with a paired
      bootstrap interval, or ``at_most`` / ``at_least`` when one median is censored
      (:func:`agents.summary.paired_entry`).
    """
    rng = np.random.default_rng([seed, 1])
    pairs = pairs_of(columns)
    stops: dict[tuple[str, str], Stops] = {}
    for protocol, estimator in pairs:
        entry, stops[protocol, estimator] = target_entry(
            columns, protocol, estimator, target, confidence, budget, rng, n_boot)
        summary["protocols"][protocol][estimator]["target"] = entry
    reference = summary.get("reference")
    for protocol, estimator in pairs:
        if reference is None or protocol == reference or (reference, estimator) not in stops:
            continue
        ours, theirs = stops[reference, estimator], stops[protocol, estimator]
        common, i, j = np.intersect1d(ours.episode, theirs.episode, return_indices=True)
        summary["protocols"][protocol][estimator]["target"]["vs_reference"] = {
            "episodes": int(common.size),
            "time_to_target": paired_entry(ours.to_target(ours.segments)[i],
                                           theirs.to_target(theirs.segments)[j], budget, rng,
                                           n_boot)}
    return summary
