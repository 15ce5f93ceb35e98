"""The per-segment record of a comparison, and the selections its summary and plots share.

The record of ``excite compare`` is ``DIR/segments.csv`` loaded as columns (equal-length numpy
arrays, :func:`agents.compare.columns_of`): one row per (protocol, estimator, episode,
segment), with the signed relative errors ``r_L_err, r_R_err, b_err`` of the estimate against
the hidden truth, the information measure ``sigma_min`` (dimensionless, see
docs/conventions.md), the per-episode ceiling ``oracle_sigma_min``, the Cramér–Rao relative
stds ``rel_std_r_L, rel_std_r_R, rel_std_b``, the estimator's ``nees`` against the truth over
``nees_dof`` parameters, ``collision`` (0/1), the true end pose ``x, y`` (m), ``theta`` (rad),
the cumulative ``distance`` (m) and ``time`` (s) driven. With a target, episodes end at
their stop or at the budget and the rows also hold the columns of
:mod:`agents.target_record`.
"""

from __future__ import annotations

import numpy as np

from excite.core.models import AXLE
from excite.estimators import DEFAULT_ESTIMATOR

#: The wheel parameters whose errors the record holds.
PARAMETERS = AXLE.names


def pairs_of(columns: dict[str, np.ndarray]) -> list[tuple[str, str]]:
    """(protocol, estimator) pairs in the order of their first appearance in the rows."""
    protocol = np.asarray(columns["protocol"]).astype(str).tolist()
    estimator = np.asarray(columns["estimator"]).astype(str).tolist()
    return list(dict.fromkeys(zip(protocol, estimator, strict=True)))


def pair_mask(columns: dict[str, np.ndarray], protocol: str,
              estimator: str = DEFAULT_ESTIMATOR) -> np.ndarray:
    """Boolean mask of one (protocol, estimator) pair's rows."""
    return ((np.asarray(columns["protocol"]).astype(str) == protocol)
            & (np.asarray(columns["estimator"]).astype(str) == estimator))


def last_rows(columns: dict[str, np.ndarray], protocol: str,
              estimator: str = DEFAULT_ESTIMATOR) -> np.ndarray:
    """Row indices of each episode's last segment for one pair, ordered by episode."""
    rows = np.flatnonzero(pair_mask(columns, protocol, estimator))
    episode = np.asarray(columns["episode"])[rows]
    order = np.lexsort((np.asarray(columns["segment"])[rows], episode))
    rows, episode = rows[order], episode[order]
    is_last = np.append(episode[1:] != episode[:-1], True)
    return rows[is_last]


def oracle_median(columns: dict[str, np.ndarray]) -> float:
    """Median over episodes of the per-episode oracle sigma_min (dimensionless)."""
    _, first = np.unique(np.asarray(columns["episode"]), return_index=True)
    return float(np.median(np.asarray(columns["oracle_sigma_min"], float)[first]))


def max_abs_error(columns: dict[str, np.ndarray]) -> np.ndarray:
    """Per-row max(|r_L_err|, |r_R_err|, |b_err|) (relative, dimensionless)."""
    errors = np.column_stack([np.asarray(columns[f"{p}_err"], float) for p in PARAMETERS])
    return np.max(np.abs(errors), axis=1)


def final_max_errors(columns: dict[str, np.ndarray], protocol: str,
                     estimator: str = DEFAULT_ESTIMATOR) -> np.ndarray:
    """One pair's final max relative error (the last segment's max of |r_L_err|, |r_R_err|,
    |b_err|) per episode, ordered by episode."""
    return max_abs_error(columns)[last_rows(columns, protocol, estimator)]


def by_episode(columns: dict[str, np.ndarray], mask: np.ndarray,
               values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Episode numbers, segment numbers 1..K and the (episodes, K) matrix of `values` over
    the rows of `mask` (one pair, or one protocol), K the longest episode's segments. An
    episode that ended earlier (at its stop, in target mode) keeps its last value after its
    end: the calibration is done, it drives no further; other missing (episode, segment)
    cells are nan."""
    episodes, ep_index = np.unique(np.asarray(columns["episode"])[mask], return_inverse=True)
    segment = np.asarray(columns["segment"], int)[mask]
    matrix = np.full((episodes.size, segment.max()), np.nan)
    matrix[ep_index, segment - 1] = np.asarray(values, float)[mask]
    ends = np.zeros(episodes.size, int)
    np.maximum.at(ends, ep_index, segment)
    for row in np.flatnonzero(ends < segment.max()):
        matrix[row, ends[row]:] = matrix[row, ends[row] - 1]
    return episodes, np.arange(1, segment.max() + 1), matrix
