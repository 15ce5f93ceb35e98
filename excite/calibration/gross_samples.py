"""Gross errors of segments that share pose samples (cut from one log, noise levels estimated
by the chain model of :mod:`excite.calibration.noise`): a bad pose sample is flagged, not the
two segments it spoils.

A pose sample at the boundary of chained segments k - 1 and k enters both increments: a gross
error of that sample (a scan matcher's bad match, a marker swap, a jump the segmentation let
through) moves both, in opposite senses. Segment k's residual r_k (predicted - measured, m, m,
rad) has the marginal covariance C_kk, the diagonal block of the chain covariance at the
estimated levels; u_k = L_kk^-1 r_k (L_kk its Cholesky factor) is N(0, I) without gross errors
and z_k^2 = |u_k|^2 chi-square with 3 degrees of freedom.

* **The test** (at :data:`excite.calibration.gross_errors.GROSS_TEST_LEVEL`): the largest z_k^2
  against the chi-square(3) quantile at 1 - level / N, as for independent segments (the
  Bonferroni bound holds for dependent segments too).
* **The candidates** (when it rejects): the gross errors inflate the estimated pose levels and
  hide each other, so each channel of u is first scaled by its robust std (the median absolute
  value); the contaminated normal's EM on these sizes (the fit held) gives each segment's
  posterior probability of being gross; above 1/2 it is a candidate, unless the candidates are
  too many (:mod:`excite.calibration.gross_errors`). A bad sample makes
  a pair: a candidate alone counts only when its own z^2 exceeds the test's quantile, and is
  then paired with its chained neighbour of the larger z^2 (the sample they share is the
  likely bad one), or left alone at the end of a chain.
* **The repair.** A run of consecutive chained candidates shares its inner pose samples: they
  are the gross errors, and the run becomes one segment from the run's first sample to its last
  (its measured increment the composition of theirs, in which the inner samples cancel
  exactly; its wheel increments and sub-steps theirs, one after the other). A candidate left
  alone at the end of a chain (its end sample bad) is left out. The noise levels and the fits
  are then estimated again on the repaired segments, and the test repeats on them (at most
  :data:`PASSES` times) until it no longer rejects. A repaired segment that is a candidate
  again with a chained neighbour that is one too (its run's first or last sample was bad
  too, the sample they share) joins the neighbour's run; one that is a candidate again
  alone is left out whole, and so is a run that grew by joining and then does not agree
  with the other segments (below: an error that no sample explains, such as a step of the
  pose source that stays). Joining keeps the chain whole: with white pose noise the
  information of a chain grows faster than its length (each sample ties the dead reckoning
  from the chain's start), and a run left out in its middle breaks it in two, which on a
  120-segment log can double the std of the wheel radii.
* **Explained, or following the driving.** A bad sample moves the two segments that share
  it in opposite senses, and it cancels in their composition: a run made whole is explained
  by its inner samples when its merged segment agrees with the other segments
  (:func:`shift_statistics`: its increment against its prediction from the others, within
  the test's quantile; the others must determine the parameters, else its residual tests
  nothing, as for a merged segment that alone carries the common scale). Slip adds up
  instead, so a slipping segment and its neighbour make a run that does not agree. The
  candidates left unexplained (left out, alone at a chain's end, a run that grew by
  joining, or a run that does not agree) are tested against the driving
  (:func:`excite.calibration.gross_errors.follows_driving`): when they follow it, nothing is
  repaired and the report says why. Not the explained ones: a swapped sample errs by the
  speed times the lag, so bad samples are found mostly where the robot moves fastest.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from excite.calibration.gross_errors import (
    Fits,
    GrossErrors,
    follows_driving,
    mixture,
    size_range,
    test_threshold,
    too_many,
)
from excite.calibration.model_fit import weak_directions
from excite.calibration.noise import chain_band, chained_mask, stacked
from excite.calibration.solver import complement
from excite.core import se2
from excite.core.arrays import BoolArray, FloatArray, IntArray
from excite.logs.segments import Segments
from excite.stats.robust import MEDIAN_ABS_NORMAL

__all__ = ["PASSES", "marginal_sizes", "merged", "screen_chain", "shift_statistics"]

#: Most rounds of (test, find the candidates, repair, estimate the levels and fit again).
PASSES = 3
#: :func:`shift_statistics` whitens the offsets of this many segments at a time (3 N rows
#: each: memory, not results).
SHIFT_BATCH = 64


def marginal_sizes(fits: Fits) -> FloatArray:
    """u (3, N): each segment's residual of the primary fit whitened by its own marginal
    covariance C_kk at the estimated levels (dimensionless; N(0, I) without gross errors)."""
    primary, noise = fits.candidates.primary, fits.noise
    assert noise is not None
    data, geometry = fits.fitter.data, noise.whitener.geometry
    assert geometry is not None
    band = chain_band(geometry, noise.levels, noise.whitener.wheels)
    n = len(data)
    blocks = np.zeros((n, 3, 3))
    for a in range(3):
        for b in range(a + 1):
            blocks[:, a, b] = blocks[:, b, a] = band[a - b, 3 * np.arange(n) + b]
    factor = np.linalg.cholesky(blocks)
    residual = primary.fit.ev.residual.T[:, :, None]
    return np.linalg.solve(factor, residual)[:, :, 0].T


def shift_statistics(fits: Fits, segments: list[int]) -> FloatArray:
    """The mean-shift test of each of ``segments`` (indices into ``fits.fitter.data``) at the
    primary fit: the chi-square(3) statistic of a free offset of its increment (m, m, rad)
    fitted with the parameters, under the chain covariance at the estimated levels, which is
    the test of its measured increment against its prediction from the other segments
    (deleting a segment is fitting it a free offset; its neighbours' shared pose samples
    stay correlated with it). inf where the other segments do not determine the parameters
    (the calibration's rule, ``max_relative_std``): the segment's residual is then not tested
    by the others, whatever its size."""
    out = np.zeros(len(segments))
    if not segments:
        return out
    primary, noise = fits.candidates.primary, fits.noise
    assert noise is not None
    ev = primary.fit.ev  # whitened at the estimated levels
    rows = stacked(ev.raw, np.einsum("cpn,pm->cmn", ev.jac, complement(primary.weak)))
    basis, _ = np.linalg.qr(rows[:, 1:])
    outside = rows[:, :1] - basis @ (basis.T @ rows[:, :1])  # the residual off the fit
    information = rows[:, 1:].T @ rows[:, 1:]
    max_relative_std = fits.fitter.options.max_relative_std
    for first in range(0, len(segments), SHIFT_BATCH):  # the offsets whitened a batch at once
        batch = segments[first:first + SHIFT_BATCH]
        units = np.zeros((rows.shape[0], 3 * len(batch)))
        for i, k in enumerate(batch):
            units[3 * k:3 * k + 3, 3 * i:3 * i + 3] = np.eye(3)
        offsets = noise.whitener.whiten_stacked(units)
        for i in range(len(batch)):
            own = offsets[:, 3 * i:3 * i + 3]
            cross = rows[:, 1:].T @ own
            others = information - cross @ np.linalg.solve(own.T @ own, cross.T)
            if weak_directions(others, max_relative_std).shape[1]:
                out[first + i] = np.inf
                continue
            free = own - basis @ (basis.T @ own)  # the offset's directions off the parameters'
            score = free.T @ outside[:, 0]
            out[first + i] = float(score @ np.linalg.solve(free.T @ free, score))
    return out


def _candidates(u: FloatArray) -> tuple[IntArray, float, float, FloatArray]:
    """The candidates from marginal sizes u (3, N): each channel scaled by its median absolute
    value's std, then the contaminated normal's EM (the fit held); with eps, k and every
    segment's size sqrt(z^2 / 3) on that scale."""
    scale = np.maximum(np.median(np.abs(u), axis=1) / MEDIAN_ABS_NORMAL, 1e-300)
    z2 = np.sum((u / scale[:, None]) ** 2, axis=0)
    posterior, fraction, spread = mixture(z2)
    chosen = np.flatnonzero(posterior > 0.5).astype(np.int64)
    return chosen, fraction, spread, np.sqrt(z2 / 3.0)


def _attributed(data: Segments, chosen: IntArray, z2: FloatArray, threshold: float
                ) -> IntArray:
    """The segments to repair for the candidates ``chosen``: every run of two or more
    consecutive chained candidates (their inner samples are bad); a single candidate only
    when its own z^2 exceeds ``threshold`` (the test's quantile: a false alarm otherwise),
    then with its chained neighbour of the larger z^2 (the sample they share is the likely bad
    one), or alone at the end of a chain (its end sample is)."""
    mask = np.zeros(len(data), dtype=bool)
    mask[chosen] = True
    chained = chained_mask(data)
    out = np.zeros(len(data), dtype=bool)
    for run in _runs(data, mask):
        if run.size > 1:
            out[run] = True
            continue
        k = int(run[0])
        if z2[k] <= threshold:
            continue
        neighbours = [j for j, ok in ((k - 1, chained[k]),
                                      (k + 1, k + 1 < len(data) and chained[k + 1])) if ok]
        out[k] = True
        if len(neighbours) == 2:
            out[max(neighbours, key=lambda j: z2[j])] = True
    return np.flatnonzero(out).astype(np.int64)


def _shifts(fits: Fits, parts: list[IntArray]) -> tuple[list[int], FloatArray]:
    """The repaired segments made of several (indices into ``fits.fitter.data``) and their
    :func:`shift_statistics`."""
    whole = [i for i, part in enumerate(parts) if part.size > 1]
    return whole, shift_statistics(fits, whole)


def _joins(chained: BoolArray, chosen: set[int], k: int) -> bool:
    """Whether segment ``k`` is chained (``chained``, per segment) to a neighbour among
    ``chosen``: the sample they share is the bad one, and their runs join into one."""
    return bool((k > 0 and chained[k] and k - 1 in chosen)
                or (k + 1 < chained.size and chained[k + 1] and k + 1 in chosen))


def _runs(data: Segments, flagged: BoolArray) -> list[IntArray]:
    """The flagged segments split into runs of consecutive chained segments."""
    chosen = np.flatnonzero(flagged)
    if chosen.size == 0:
        return []
    chained = chained_mask(data)
    breaks = np.flatnonzero((np.diff(chosen) != 1) | ~chained[chosen[1:]]) + 1
    return np.split(chosen, breaks)


def merged(data: Segments, flagged: BoolArray,
           left_out: BoolArray | None = None) -> tuple[Segments, list[IntArray]]:
    """``data`` repaired around the ``flagged`` segments: each run of two or more consecutive
    chained flagged segments made one segment, each single flagged segment and every
    ``left_out`` one left out; and the segments of ``data`` each repaired segment is made of.
    A merged segment's measured increment is the composition of its parts' (m, m, rad; the
    pose samples inside the run cancel exactly), its wheel increments and sub-steps its
    parts' in order, its times the first part's start and the last's end; it is chained to
    the segment before it as its first part was, unless that segment was left out."""
    n = len(data)
    dropped = np.zeros(n, dtype=bool) if left_out is None else left_out.copy()
    runs = _runs(data, flagged & ~dropped)
    head_of = {}
    for run in runs:
        if run.size == 1:
            dropped[run] = True
        else:
            head_of[int(run[0])] = run
    inner = np.zeros(n, dtype=bool)
    for run in head_of.values():
        inner[run[1:]] = True
    kept = np.flatnonzero(~dropped & ~inner)
    parts = [head_of.get(int(k), np.array([k])) for k in kept]
    rows = data.as_array()[kept].copy()
    for i, part in enumerate(parts):
        if part.size > 1:
            pose = data.measured[part[0]]
            for k in part[1:]:
                pose = se2.compose(pose, data.measured[k])
            rows[i, :2] = data.as_array()[part, :2].sum(axis=0)
            rows[i, 2:] = pose
    optional: dict = {}
    if data.t_start is not None and data.t_end is not None:
        optional.update(t_start=data.t_start[kept],
                        t_end=np.array([data.t_end[part[-1]] for part in parts]))
    if data.chained is not None:
        after_dropped = np.zeros(kept.size, dtype=bool)
        after_dropped[kept > 0] = dropped[kept[kept > 0] - 1]
        optional["chained"] = data.chained[kept] & ~after_dropped
    counts = data.substep_counts
    if counts is not None:
        assert data.sub_dphi_L is not None and data.sub_dphi_R is not None
        count = np.array([int(counts[part].sum()) for part in parts], dtype=np.int64)
        subs = []
        for wheel in (data.sub_dphi_L, data.sub_dphi_R):
            rows_sub = np.zeros((kept.size, int(count.max())))
            for i, part in enumerate(parts):
                own = np.concatenate([wheel[k, :counts[k]] for k in part])
                rows_sub[i, :own.size] = own
            subs.append(rows_sub)
        optional.update(sub_dphi_L=subs[0], sub_dphi_R=subs[1], sub_count=count)
    return Segments(*rows.T, **optional), parts


def screen_chain(fits: Fits, refit: Callable[[Segments], Fits]
                 ) -> tuple[Segments, Fits, GrossErrors]:
    """The gross errors of segments that share pose samples (module doc): the repaired
    segments, their fits and what was found (the flagged segments' indices in the order of
    ``fits.fitter.data``, the bad samples' times). A repaired segment that is a candidate
    again joins a chained neighbour that is one too, or else is left out."""
    original = data = fits.fitter.data
    n = len(original)
    parts = [np.array([k]) for k in range(n)]
    flagged = np.zeros(n, dtype=bool)
    left_out = np.zeros(n, dtype=bool)
    grown = np.zeros(n, dtype=bool)  # repaired runs that were candidates again and grew
    plain = fits
    found: GrossErrors | None = None
    sizes: list[FloatArray] = []
    for _ in range(PASSES):
        u = marginal_sizes(fits)
        z2 = np.sum(u * u, axis=0)
        statistic, threshold = float(np.max(z2)), test_threshold(len(data))
        if found is None:
            found = GrossErrors(np.zeros(0, dtype=np.int64), n, statistic, threshold)
        if statistic <= threshold:
            break
        chosen, fraction, spread, size = _candidates(u)
        chosen = _attributed(data, chosen, z2, threshold)
        if chosen.size == 0:
            break
        size = size[chosen]
        more, out = flagged.copy(), left_out.copy()
        chained, picked = chained_mask(data), set(chosen.tolist())
        for c in chosen:
            if not more[parts[c]].all():
                more[parts[c]] = True
            elif _joins(chained, picked, int(c)):  # a repaired segment, a candidate again
                grown[parts[c]] = True
            else:
                out[parts[c]] = True
        if not found.candidates.size:  # the first pass: are these gross errors at all?
            candidates = np.flatnonzero(more).astype(np.int64)
            why = too_many(original, candidates)
            found = replace(found, candidates=candidates, fraction=fraction, spread=spread,
                            ratio=size_range(size), declined=why)
            if why is not None:
                return original, plain, found
        if np.array_equal(more, flagged) and np.array_equal(out, left_out):
            break
        flagged, left_out = more, out
        sizes.append(size)
        data, parts = merged(original, flagged, left_out)
        fits = refit(data)
    assert found is not None
    if not flagged.any():
        return original, plain, found
    # a bad sample's two segments err in opposite senses, and their composition, where it
    # cancels, agrees with the other segments: the runs the repair made whole are explained;
    # slip, which adds up, is not, and the candidates left unexplained are tested against
    # the driving
    whole, shifts = _shifts(fits, parts)
    threshold = test_threshold(len(data))
    # a run that grew by joining and still does not agree holds an error no sample explains
    # (a step of the pose source that stays): left out, as a candidate again alone is
    spoilt = [i for i, shift in zip(whole, shifts, strict=True)
              if not shift <= threshold and grown[parts[i]].any()]
    if spoilt:
        for i in spoilt:
            left_out[parts[i]] = True
        data, parts = merged(original, flagged, left_out)
        fits = refit(data)
        whole, shifts = _shifts(fits, parts)
        threshold = test_threshold(len(data))
    runs = _runs(original, flagged & ~left_out)
    unexplained = left_out.copy()
    for run in runs:
        if run.size == 1 or grown[run].any():
            unexplained[run] = True
    for i, shift in zip(whole, shifts, strict=True):
        if not shift <= threshold:
            unexplained[parts[i]] = True
    why = (follows_driving(original, np.flatnonzero(unexplained).astype(np.int64))
           if unexplained.any() else None)
    if why is not None:
        return original, plain, replace(found, declined=why)
    segments = np.flatnonzero(flagged).astype(np.int64)
    samples = (None if original.t_start is None else
               np.array([t for run in runs for t in original.t_start[run[1:]]]))
    alone = int(np.sum(left_out)) + sum(run.size == 1 for run in runs)
    found = replace(found, segments=segments, candidates=segments,
                    ratio=size_range(np.concatenate(sizes)),
                    t_start=None if original.t_start is None else original.t_start[segments],
                    t_end=None if original.t_end is None else original.t_end[segments],
                    samples=samples, dropped=alone)
    return data, fits, found
