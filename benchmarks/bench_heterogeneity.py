"""Do logs that disagree get said so? The heterogeneity test of ``excite calibrate A B C``
(between inputs) and of one input (between kinds of motion), on simulated robots whose
effective track grows with the turn (``scrub``: b (1 + scrub min(kappa b / 2, 1)),
:func:`excite.logs.synthetic.scrubbed_increment`), through
:func:`excite.calibration.logs.calibrate_logs` on files, as the command line does.

Cells (``--cases`` data sets each, seeds 0..cases-1 of each cell's own stream):

* ``ts-*``: time-series logs (:func:`excite.logs.synthetic.synthetic_log`, 100 Hz encoders,
  50 Hz poses with 1 mm / 2 mrad noise, 1 s windows; no wheel slip: with slip the
  calibration's own std of such logs are too narrow (BENCHMARKS.md), and a test of agreement
  beyond them would measure that), of two
  maneuvers: ``tight`` (0.08 m/s, turn rate up to 1.5 rad/s) and ``wide`` (0.3 m/s, up to
  0.4 rad/s), or a maneuver drawn per log (speed and turn rate log-uniform between those).
* ``seg-*``: segment CSVs (independent segments, noise 2 mm, 2 mm, 1 mrad): ``tight``
  (wheel increments with mean travel N(0, 0.15^2) rad and difference N(0, 0.4^2) rad) and
  ``wide`` (N(0, 0.5^2) and N(0, 0.04^2)); the lesson's data set within one input.

What is measured:

* detection (``*-detect-*``): the fraction of cases flagged, and the cell's difference in
  combined std: over all directions, sqrt(mean Q - dof) (Q's mean is dof plus its
  noncentrality, the squared difference in combined std along the best direction); for b
  between two groups, |mean difference| / sqrt(mean of the sum of their variances). (A
  noise-free twin of the same driving is no truth: with the effective track varying within a
  log, which segments weigh most depends on the noise levels the fit estimates.) The scrub of
  each detection cell is set so that the difference is about 4 combined std over all
  directions (``seg-detect-2b``: in b alone).
* false alarms (``*-null-*``): the fraction flagged on a robot with constant parameters.
* pairs (``*-pairs``; ``*-pairs-null`` of a robot with constant parameters): two independent
  sets of logs of one robot, maneuvers drawn per log;
  the fraction of cases whose two pooled estimates agree within their std: (difference)'
  (C_1 + C_2)^-1 (difference) below the 95% chi-square(3) quantile.

Run: ``OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_heterogeneity.py --cases 100``
(``--cells`` to choose; ``--out FILE.json`` keeps every case).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from excite.calibration.logs import calibrate_logs
from excite.core.kinematics import Params
from excite.core.models import SensorPose
from excite.logs.segments import Segments, save_segments
from excite.logs.synthetic import lesson_dataset, scrubbed_increment, synthetic_log
from excite.logs.timeseries_csv import write_timeseries
from excite.stats.chi2 import chi2_quantile

TRUTH = Params(0.050, 0.051, 0.300)
OFF_AXLE = SensorPose(0.05, 0.02, 0.1)
MANEUVERS = {"tight": (0.08, 1.5), "wide": (0.3, 0.4)}
SEGMENT_KINDS = {"tight": (0.15, 0.4), "wide": (0.5, 0.04)}
SEGMENT_SIGMA = (2e-3, 2e-3, 1e-3)


def _drawn(rng: np.random.Generator) -> tuple[float, float]:
    """A maneuver drawn per log: speed (m/s) and turn rate (rad/s), log-uniform between the
    two named maneuvers'."""
    (v0, w0), (v1, w1) = MANEUVERS["tight"], MANEUVERS["wide"]
    return (math.exp(rng.uniform(math.log(v0), math.log(v1))),
            math.exp(rng.uniform(math.log(w1), math.log(w0))))


def _ts_file(directory: Path, name: str, seed: int, maneuver: tuple[float, float],
             scrub: float, sensor: SensorPose | None, duration: float) -> str:
    speed, turn = maneuver
    log = synthetic_log(np.random.default_rng(seed), duration, TRUTH, sensor,
                        pose_noise=(1e-3, 2e-3), speed=speed,
                        turn_rate=turn, scrub=scrub)
    path = directory / name
    write_timeseries(path, log.series)
    return str(path)


def _seg_file(directory: Path, name: str, seed: int, kind: str | None, scrub: float,
              n: int = 100) -> str:
    rng = np.random.default_rng(seed)
    sigma = np.array(SEGMENT_SIGMA)
    if kind is None:  # the lesson's data set
        seg = lesson_dataset(rng, 3 * n, TRUTH, sigma, scrub=scrub)
    else:
        travel, difference = SEGMENT_KINDS[kind]
        m, d = rng.normal(0, travel, n), rng.normal(0, difference, n)
        dphi_L, dphi_R = m - d, m + d
        truth = np.column_stack(scrubbed_increment(dphi_L, dphi_R, TRUTH, scrub))
        measured = truth + rng.normal(size=truth.shape) * sigma
        seg = Segments(dphi_L, dphi_R, *measured.T)
    path = directory / name
    save_segments(path, seg)
    return str(path)


def _calibrated(paths: list[str]):
    return calibrate_logs(paths).result


def _case(cell: str, seed: int, scrub: float, work: Path) -> dict:
    """One case of a cell: what was found (and the truth's difference, or the pairs' test)."""
    kind, what = cell.split("-", 1)
    rng = np.random.default_rng([seed, sum(map(ord, cell))])
    seeds = rng.integers(0, 2**31, 16)
    drawn = [_drawn(rng) for _ in range(8)]  # maneuvers drawn per log
    kinds = [str(k) for k in rng.choice(list(SEGMENT_KINDS), 8)]

    def files(directory: Path) -> list[str]:
        directory.mkdir(exist_ok=True)
        if kind == "ts":
            sensor = OFF_AXLE if what.endswith("2") else None
            if what.startswith("motion"):
                return [_ts_file(directory, "mixed.csv", int(seeds[0]), (0.12, 1.2), scrub,
                                 None, 150.0)]
            if what.endswith("2"):
                return [_ts_file(directory, f"{m}.csv", int(s), MANEUVERS[m], scrub, sensor,
                                 60.0)
                        for m, s in zip(("tight", "wide"), seeds[:2], strict=True)]
            return [_ts_file(directory, f"log{i}.csv", int(seeds[i]), drawn[i], scrub,
                             None, 60.0) for i in range(4)]
        if what.startswith("motion"):
            return [_seg_file(directory, "lesson.csv", int(seeds[0]), None, scrub)]
        return [_seg_file(directory, f"{m}.csv", int(s), m, scrub)
                for m, s in zip(("tight", "wide"), seeds[:2], strict=True)]

    out: dict = {"seed": seed}
    if what.startswith("pairs"):
        results = []
        for half in range(2):
            directory = work / f"set{half}"
            directory.mkdir(exist_ok=True)
            if kind == "ts":
                paths = [_ts_file(directory, f"log{i}.csv", int(seeds[4 * half + i]),
                                  drawn[4 * half + i], scrub, None, 60.0)
                         for i in range(4)]
            else:
                paths = [_seg_file(directory, f"f{i}.csv", int(seeds[4 * half + i]),
                                   kinds[4 * half + i], scrub) for i in range(4)]
            results.append(_calibrated(paths))
        d = results[0].params.as_array() - results[1].params.as_array()
        c = results[0].covariance + results[1].covariance
        out["mahalanobis"] = float(d @ np.linalg.solve(c, d))
        out["agree"] = out["mahalanobis"] <= chi2_quantile(0.95, 3)
        out["agree_each"] = bool(np.all(np.abs(d) <= 1.96 * np.sqrt(np.diag(c))))
        out["detected"] = [bool(r.heterogeneity is not None and r.heterogeneity.detected)
                           for r in results]
        return out
    h = _calibrated(files(work / "data")).heterogeneity
    out["tested"] = h is not None
    out["detected"] = bool(h is not None and h.detected)
    if h is not None:
        out.update(p_value=h.p_value, statistic=h.statistic, dof=h.dof,
                   groups=[g.name.split("/")[-1] for g in h.groups],
                   params=[g.params.tolist() for g in h.groups],
                   std=[g.std.tolist() for g in h.groups])
    return out


CELLS = {  # cell: scrub
    "ts-detect-2": 0.008, "ts-null-2": 0.0, "ts-null-4": 0.0,
    "ts-motion-detect": 0.032, "ts-motion-null": 0.0, "ts-pairs": 0.008,
    "seg-detect-2": 0.045, "seg-detect-2b": 0.2, "seg-null-2": 0.0,
    "seg-motion-detect": 0.022, "seg-motion-null": 0.0, "seg-pairs": 0.02,
    "seg-pairs-null": 0.0,
}


def _difference(tested: list[dict]) -> dict:
    """The cell's difference between groups in combined std (module docstring), over the
    cases with the most common grouping."""
    names = [tuple(c["groups"]) for c in tested]
    common = max(set(names), key=names.count)
    same = [c for c in tested if tuple(c["groups"]) == common]
    q = np.array([c["statistic"] for c in same])
    out = {"grouping": list(common), "grouping_cases": len(same),
           "z_all": math.sqrt(max(float(q.mean()) - same[0]["dof"], 0.0))}
    if len(common) == 2:
        b = np.array([[g[2] for g in c["params"]] for c in same])
        var = np.array([[s[2] ** 2 for s in c["std"]] for c in same])
        out["z_b"] = abs(float((b[:, 0] - b[:, 1]).mean())) / math.sqrt(var.sum(1).mean())
    out["detected_in_grouping"] = sum(c["detected"] for c in same) / len(same)
    return out


def _summary(cell: str, cases: list[dict]) -> dict:
    n = len(cases)
    if "pairs" in cell:
        agree = sum(c["agree"] for c in cases)
        return {"cases": n, "agree": agree, "rate": agree / n,
                "agree_each": sum(c["agree_each"] for c in cases) / n,
                "detected_sets": sum(sum(c["detected"]) for c in cases) / (2 * n)}
    tested = [c for c in cases if c["tested"]]
    summary = {"cases": n, "tested": len(tested),
               "flagged": sum(c["detected"] for c in cases)}
    summary["rate"] = summary["flagged"] / max(len(tested), 1)
    if "detect" in cell:
        summary.update(_difference(tested))
    return summary


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=100)
    parser.add_argument("--cells", default=",".join(CELLS))
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    report: dict = {}
    for cell in args.cells.split(","):
        start = time.time()
        cases = []
        for seed in range(args.cases):
            with tempfile.TemporaryDirectory() as work:
                cases.append(_case(cell, seed, CELLS[cell], Path(work)))
        summary = _summary(cell, cases)
        summary["seconds"] = round(time.time() - start, 1)
        report[cell] = {"summary": summary, "cases": cases}
        print(cell, json.dumps(summary), flush=True)
        if args.out:
            Path(args.out).write_text(json.dumps(report, indent=1, default=float))
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
