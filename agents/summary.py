"""The summary of a comparison (``summary.json``): medians with bootstrap intervals per pair.

:func:`summarize` reduces each (protocol, estimator) pair's episodes of the segment record
(:mod:`agents.segment_record`) to medians with percentile bootstrap 95% intervals and the
decision metrics of :mod:`agents.metrics` and :mod:`excite.stats.consistency`, and puts the
reference protocol over each baseline in paired ratios. Computation only: :mod:`agents.tables`
prints the summary, :mod:`agents.plots` draws the record.
"""

from __future__ import annotations

import math

import numpy as np

from agents.metrics import N_BOOT, error_time_area, paired_ratio, time_to_accuracy
from agents.segment_record import (
    PARAMETERS,
    by_episode,
    final_max_errors,
    last_rows,
    max_abs_error,
    oracle_median,
    pair_mask,
    pairs_of,
)
from excite.stats.consistency import CONFIDENCE, anees_bounds, verdict

#: A parameter whose median final Cramér–Rao relative std exceeds this is undetermined.
UNDETERMINED_REL_STD = 0.1
#: Accuracy thresholds of the time to accuracy (max relative error; keys of the summary).
THRESHOLDS = {"0.5%": 0.005, "0.2%": 0.002}
#: The threshold of the paired time ratio (a key of THRESHOLDS).
RATIO_THRESHOLD = "0.2%"
#: The protocol the paired ratios put over each baseline (its label, or its name with
#: settings: ``learned:margin=0.1``).
REFERENCE = "learned"


def json_float(value: float) -> float | None:
    """A plain Python float, or None for inf / nan (so `json.dumps(allow_nan=False)` works)."""
    value = float(value)
    return value if math.isfinite(value) else None


def median_ci(values: np.ndarray, resample: np.ndarray) -> dict[str, float | list | None]:
    """Median of `values` and the percentile bootstrap interval (CONFIDENCE) of the median.

    resample: (n_boot, n) indices into `values`, one bootstrap sample per row.
    """
    tail = 50.0 * (1.0 - CONFIDENCE)
    with np.errstate(invalid="ignore"):
        boot = np.median(values[resample], axis=1)
        lo, hi = np.percentile(boot, [tail, 100.0 - tail], method="inverted_cdf")
    return {"median": json_float(np.median(values)), "ci95": [json_float(lo), json_float(hi)]}


def _time_to_accuracy(max_error: np.ndarray, time: np.ndarray, distance: np.ndarray,
                      resample: np.ndarray) -> tuple[dict, dict[str, np.ndarray]]:
    """Per threshold: medians with intervals of the segments, seconds and metres to
    accuracy, and the censored count; and the per-episode segments (inf: censored)."""
    out, segments = {}, {}
    for key, threshold in THRESHOLDS.items():
        reached = time_to_accuracy(max_error, threshold, time, distance)
        out[key] = {
            "threshold": threshold,
            "segments": median_ci(reached.segments, resample),
            "seconds": median_ci(reached.seconds, resample),
            "metres": median_ci(reached.metres, resample),
            "censored": int(reached.censored.sum()),
        }
        segments[key] = reached.segments
    return out, segments


def _consistency(nees: np.ndarray, dof: np.ndarray) -> dict:
    """ANEES (episodes' mean NEES) at the last segment and per segment against the bounds
    of a consistent estimator (nees: (M, K) matrix; dof: the pair's nees_dof values)."""
    parameters = int(np.max(dof))
    bounds = anees_bounds(nees.shape[0], parameters)
    per_segment = nees.mean(axis=0)
    with np.errstate(invalid="ignore"):
        inside = (per_segment >= bounds[0]) & (per_segment <= bounds[1])
    final = float(per_segment[-1])
    return {
        "final": json_float(final),
        "bounds": list(bounds),
        "verdict": verdict(final, bounds),
        "parameters": parameters,
        "segments_inside": float(inside.mean()),
    }


def _summarize_pair(columns: dict[str, np.ndarray], protocol: str, estimator: str,
                    rng: np.random.Generator, n_boot: int) -> tuple[dict, dict[str, np.ndarray]]:
    """Summary of one (protocol, estimator) pair (see `summarize`), and its per-episode
    values the paired ratios compare: ``final_max_error`` and the segments to each
    threshold, ordered by episode, with ``episode`` the episode numbers."""
    last = last_rows(columns, protocol, estimator)
    mask = pair_mask(columns, protocol, estimator)
    n = last.size
    resample = rng.integers(0, n, size=(n_boot, n))
    sigma = np.asarray(columns["sigma_min"], float)[last]
    oracle = np.asarray(columns["oracle_sigma_min"], float)[last]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = sigma / oracle
    collisions = np.asarray(columns["collision"], float)
    episodes = np.asarray(columns["episode"])[mask]
    per_episode = np.bincount(np.unique(episodes, return_inverse=True)[1], collisions[mask])
    rel_std = {p: np.median(np.asarray(columns[f"rel_std_{p}"], float)[last]) for p in PARAMETERS}
    episode, _, max_error = by_episode(columns, mask, max_abs_error(columns))
    time = by_episode(columns, mask, columns["time"])[2]
    distance = by_episode(columns, mask, columns["distance"])[2]
    nees = by_episode(columns, mask, columns["nees"])[2]
    accuracy, to_accuracy = _time_to_accuracy(max_error, time, distance, resample)
    final = final_max_errors(columns, protocol, estimator)
    summary = {
        "episodes": int(n),
        "segments": int(np.max(np.asarray(columns["segment"])[mask])),
        "final_max_error": median_ci(final, resample),
        "final_error": {
            p: json_float(np.median(np.abs(np.asarray(columns[f"{p}_err"], float)[last])))
            for p in PARAMETERS
        },
        "sigma_min": median_ci(sigma, resample),
        "ratio_to_oracle": median_ci(ratio, resample),
        "distance_m": json_float(np.median(np.asarray(columns["distance"], float)[last])),
        "collisions": {
            "total": int(round(collisions[mask].sum())),
            "per_episode": float(per_episode.mean()),
        },
        "undetermined": [
            p for p in PARAMETERS if not rel_std[p] <= UNDETERMINED_REL_STD  # nan counts too
        ],
        "time_to_accuracy": accuracy,
        "error_time_area": median_ci(error_time_area(max_error, time), resample),
        "anees": _consistency(nees, np.asarray(columns["nees_dof"])[mask]),
    }
    return summary, {"episode": episode, "final_max_error": final, **to_accuracy}


def reference_protocol(protocols: list[str], reference: str = REFERENCE) -> str | None:
    """The first protocol label that is ``reference`` or ``reference`` with settings
    (``learned:margin=0.1``); None when there is none."""
    return next((p for p in protocols if p == reference or p.startswith(reference + ":")),
                None)


def _censored_bound(reference: np.ndarray, baseline: np.ndarray,
                    segments: int) -> dict[str, float]:
    """What a ratio of medians of times to accuracy still says when a median is censored
    (not reached within ``segments``, so beyond it): ``{"at_most": r}`` when only the
    baseline's is, ``{"at_least": r}`` when only the reference's is, else nothing."""
    ours, theirs = float(np.median(reference)), float(np.median(baseline))
    if math.isfinite(ours) and not math.isfinite(theirs):
        return {"at_most": ours / segments}
    if math.isfinite(theirs) and not math.isfinite(ours):
        return {"at_least": segments / theirs}
    return {}


def paired_entry(reference: np.ndarray, baseline: np.ndarray, segments: int | None,
                 rng: np.random.Generator, n_boot: int) -> dict:
    """The reference's median over the baseline's on the same episodes (per-episode values,
    paired by index), with its paired bootstrap interval: ``{"ratio", "ci95"}``
    (:func:`agents.metrics.paired_ratio`; None where undefined). For times censored at
    ``segments`` (inf: not reached within them) a ratio with one censored median is None,
    and so is its interval, with the bound it still gives (:func:`_censored_bound`);
    ``segments`` None: not a time."""
    if not reference.size:
        return {"ratio": None, "ci95": [None, None]}
    result = paired_ratio(reference, baseline, rng, n_boot)
    bound = {} if segments is None else _censored_bound(reference, baseline, segments)
    ci = [None, None] if bound else [json_float(result.ci[0]), json_float(result.ci[1])]
    return {"ratio": None if bound else json_float(result.ratio), "ci95": ci, **bound}


def _paired(reference: dict[str, np.ndarray], baseline: dict[str, np.ndarray],
            segments: int, rng: np.random.Generator, n_boot: int) -> dict:
    """reference / baseline ratios of medians over their common episodes, with paired
    bootstrap intervals: the final max error and the segments to RATIO_THRESHOLD (see
    :func:`paired_entry`)."""
    common, ours, theirs = np.intersect1d(reference["episode"], baseline["episode"],
                                          return_indices=True)
    out: dict = {"episodes": int(common.size)}
    for key, name in (("final_max_error", "final_max_error"),
                      (RATIO_THRESHOLD, f"time_to_{RATIO_THRESHOLD}")):
        out[name] = paired_entry(reference[key][ours], baseline[key][theirs],
                                 segments if key == RATIO_THRESHOLD else None, rng, n_boot)
    return out


def summarize(columns: dict[str, np.ndarray], seed: int = 0, n_boot: int = N_BOOT,
              reference: str = REFERENCE) -> dict:
    """Per-(protocol, estimator) summary of a comparison.

    Args:
        columns: the segment record (:mod:`agents.segment_record`), equal-length arrays.
        seed: seed of the numpy Generator drawing the bootstrap resamples.
        n_boot: number of bootstrap resamples of the episodes.
        reference: the protocol the paired ratios put over each baseline (a label, or a
            name whose labels with settings count too); no ratios when it did not run.

    Returns:
        ``{"protocols": {protocol: {estimator: {...}}}, "oracle_sigma_min": {"median"},
        "reference": label or None, "thresholds": THRESHOLDS, "bootstrap": {...}}``,
        protocols and estimators in order of first appearance. Per pair:

        - ``episodes``, ``segments`` (K);
        - ``final_max_error`` (relative, ``{"median", "ci95": [lo, hi]}``), ``final_error``
          (median |relative error| per parameter);
        - ``sigma_min`` and ``ratio_to_oracle`` (dimensionless, median and ci95),
          ``distance_m`` (median path length, m), ``collisions`` (``{"total",
          "per_episode"}``), ``undetermined`` (parameters whose median final Cramér–Rao
          relative std exceeds 10%);
        - ``time_to_accuracy``: per threshold key (``"0.5%"``, ``"0.2%"``) ``threshold``
          (relative), ``segments``, ``seconds`` (s) and ``metres`` (m) driven until the max
          relative error stays below it (median and ci95; an episode that does not end below
          is censored, counted as later than all others, so a median or bound beyond the
          reached episodes is None: "not reached within K segments"), and ``censored`` (the
          number of such episodes);
        - ``error_time_area``: the area under the max relative error over time from the end
          of segment 1 to the end of the last (relative error x s; median and ci95);
        - ``anees``: ``final`` (the mean over episodes of the last segment's NEES, None when
          a covariance says nothing), ``bounds`` ([lo, hi], the two-sided 95% chi-square
          interval of a consistent estimator for these episodes and ``parameters``),
          ``verdict`` ("consistent", "over-confident", "under-confident", "undefined") and
          ``segments_inside`` (the share of segments 1..K whose ANEES is inside the bounds);
        - ``vs_reference`` (baselines only, when the reference ran with the same estimator):
          ``episodes`` (paired), ``final_max_error`` and ``time_to_0.2%`` (segments), each
          ``{"ratio", "ci95"}``: the reference's median over the baseline's (below 1: the
          reference is better), with a paired percentile bootstrap interval over episodes
          (:func:`agents.metrics.paired_ratio`; None where undefined). When only one median
          time is censored (beyond K segments) the ratio and its interval are None and the
          entry says what is known: ``at_most`` (reference median / K, the baseline's censored) or
          ``at_least`` (K / baseline median, the reference's censored).

        The ci95 of medians are percentile bootstrap intervals over episodes (resampled
        jointly for all metrics of a pair). Only plain ints, floats, str, lists, dicts and
        None (for inf / nan) appear.
    """
    rng = np.random.default_rng(seed)
    pairs = pairs_of(columns)
    protocols: dict[str, dict[str, dict]] = {}
    per_episode: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    for protocol, estimator in pairs:
        entry, per_episode[protocol, estimator] = _summarize_pair(
            columns, protocol, estimator, rng, n_boot)
        protocols.setdefault(protocol, {})[estimator] = entry
    ref = reference_protocol(list(protocols), reference)
    if ref is not None:
        for protocol, estimator in pairs:
            if protocol != ref and (ref, estimator) in per_episode:
                protocols[protocol][estimator]["vs_reference"] = _paired(
                    per_episode[ref, estimator], per_episode[protocol, estimator],
                    protocols[protocol][estimator]["segments"], rng, n_boot)
    return {
        "protocols": protocols,
        "oracle_sigma_min": {"median": json_float(oracle_median(columns))},
        "reference": ref,
        "thresholds": dict(THRESHOLDS),
        "bootstrap": {"seed": int(seed), "n_boot": int(n_boot), "confidence": CONFIDENCE},
    }
