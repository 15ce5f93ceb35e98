"""The stopping rule's cost and false-stop rate.

Cost: one decision (excite.stopping.StoppingRule.decide) on a 60-segment session, as segments
of the lesson's kind (independent noise), as an env episode's segments (the env's target mode
and excite compare --target: ten encoder readings per segment, driven by slip_aware) and as
segments cut from a time-series log (shared pose samples, the GLS with estimated noise
levels: excite live), median of repeated calls. Then, on a noisy
time-series log, side by side in one run: the 60th look of a growing session by the batch
calibration alone and with the previous look's decision (the screen, excite.calibration.screen),
and every look from the 15th to the 60th (and on to the rule's first *done*) both ways: the
cost per look and the first *done* of each (every *done* is the calibration's; the first is
the same unless the screen's statistic is above its margin where the calibration's is at
most 1).

False stops: sequences of segments of the lesson's kind, the rule asked after every segment
from the 6th; the share of sequences where it stopped while the truth was outside the target,
with its Wilson 95% interval, and the median segments to the stop.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_stopping.py [--runs N] [--sessions K]

(--runs 0: the cost only; --sessions K: the first done of the rule alone and of a session,
and their costs, on K noisy logs.)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from agents.metrics import rate_interval
from excite.core.models import SensorPose
from excite.logs.segmentation import segment_timeseries
from excite.logs.synthetic import LESSON_TRUTH, lesson_dataset, synthetic_log
from excite.stopping import StoppingRule

#: The noisy time-series session: a sensor off the axle, pose samples with 2 mm / 2 mrad noise.
SESSION_SENSOR = SensorPose(0.1, -0.03, 0.4)
SESSION_TARGET = 0.005


def _median_ms(rule: StoppingRule, segments, repeats: int = 15, previous=None) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        rule.decide(segments, previous=previous)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def _session(rule: StoppingRule, segments, first: int = 15, last: int = 60) -> dict:
    """Every look from ``first`` to ``last`` (and on to the first done of both), by the batch
    calibration alone and by a session (the screen), side by side: their costs (ms) and first
    done looks."""
    full_ms, screened_ms, calibrated_ms = [], [], []
    full_done = session_done = None
    session = rule.session()
    for n in range(first, len(segments) + 1):
        if n > last and full_done is not None and session_done is not None:
            break
        start = time.perf_counter()
        full = rule.decide(segments[:n])
        full_ms.append(1e3 * (time.perf_counter() - start))
        start = time.perf_counter()
        looked = session.decide(segments[:n])
        (screened_ms if looked.screened else calibrated_ms).append(
            1e3 * (time.perf_counter() - start))
        if looked.done != full.done and not looked.screened:
            raise AssertionError(f"look {n}: the session's calibrated decision differs")
        full_done = n if full.done and full_done is None else full_done
        session_done = n if looked.done and session_done is None else session_done
    return {"first": first, "full": full_ms, "screened": screened_ms,
            "calibrated": calibrated_ms, "full_done": full_done, "session_done": session_done}


def _print_session(found: dict) -> None:
    full, screened, calibrated = found["full"], found["screened"], found["calibrated"]
    session = sum(screened) + sum(calibrated)
    print(f"growing session, looks {found['first']}..{found['first'] + len(full) - 1}: batch "
          f"calibration at every look {sum(full) / 1e3:.2f} s (median {np.median(full):.1f} ms,"
          f" max {max(full):.0f} ms); session {session / 1e3:.2f} s (ratio "
          f"{session / sum(full):.3f}): {len(screened)} looks screened (median "
          f"{np.median(screened) if screened else float('nan'):.1f} ms, max "
          f"{max(screened, default=float('nan')):.1f} ms), {len(calibrated)} calibrated "
          f"(median {np.median(calibrated) if calibrated else float('nan'):.0f} ms); first "
          f"done at look {found['full_done']} (calibration alone) and "
          f"{found['session_done']} (session)")


def _sessions(count: int) -> None:
    """``count`` noisy logs (pose noise; every other one with wheel slip 0.01 rad/sqrt(s)),
    target 1%, asked from the 15th segment to the first done: the first done of the rule
    alone and of a session, and the cost of each; printed."""
    same = 0
    full, screened, calibrated, looks = [], [], [], []
    for seed in range(count):
        log = synthetic_log(np.random.default_rng([seed, 27]), 150.0, LESSON_TRUTH,
                            SESSION_SENSOR, pose_noise=(2e-3, 2e-3), slip=0.01 * (seed % 2))
        found = _session(StoppingRule(target=0.01), segment_timeseries(log.series).segments,
                         last=0)
        same += found["full_done"] == found["session_done"]
        full += found["full"]
        screened += found["screened"]
        calibrated += found["calibrated"]
        looks.append(len(found["calibrated"]))
    session = sum(screened) + sum(calibrated)
    print(f"{count} growing sessions (target 0.01, to the first done): the same first done in "
          f"{same}/{count}; {len(full)} looks, batch calibration {sum(full) / 1e3:.1f} s, "
          f"session {session / 1e3:.1f} s (ratio {session / sum(full):.3f}); screened "
          f"{len(screened)} (median {np.median(screened):.1f} ms, max {max(screened):.1f} ms),"
          f" calibrated {len(calibrated)} (median per session {np.median(looks):.0f})")


def _env_session_ms(env_id: str, segments: int = 60, seed: int = 3) -> tuple[float, int]:
    """One decision on the segments of an env episode (each with its ten encoder readings),
    ``segments`` driven by slip_aware: the median cost (ms) of the rule's decision on them,
    and how many parameters it estimated."""
    import gymnasium as gym

    import envs  # noqa: F401  (registers the env ids)
    from agents.catalog import make_protocol
    from envs.target import stopping_rule

    env = gym.make(env_id, budget=segments, target=1e-9)  # asked every segment, never done
    env.reset(seed=seed)
    protocol = make_protocol("slip_aware")
    protocol.reset(np.random.default_rng([seed, 1]))
    base = env.unwrapped
    for _ in range(segments):
        env.step(protocol.act(base.knowledge()))
    rule, data = stopping_rule(base.config, base.model), base.rule_segments
    decision = rule.decide(data, nominal=base.nominal_theta[:3])
    times = []
    for _ in range(15):
        start = time.perf_counter()
        rule.decide(data, nominal=base.nominal_theta[:3])
        times.append(time.perf_counter() - start)
    env.close()
    return 1e3 * float(np.median(times)), len(decision.result.parameter_names)



def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=200, help="sequences for the false stops")
    parser.add_argument("--target", type=float, default=0.01)
    parser.add_argument("--sessions", type=int, default=0,
                        help="noisy logs on which the session's first done is compared")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    lesson = lesson_dataset(rng, 60, dphi_std=2.0)
    log = synthetic_log(np.random.default_rng(1), 70, LESSON_TRUTH)
    cut = segment_timeseries(log.series).segments[:60]
    for name, segments, pose in (("lesson segments, axle", lesson, "axle"),
                                 ("lesson segments, auto", lesson, "auto"),
                                 ("time-series segments, auto", cut, "auto")):
        ms = _median_ms(StoppingRule(target=args.target, sensor_pose=pose), segments)
        print(f"one decision, {len(segments)} {name}: {ms:.1f} ms")
    for env_id in ("excite/DiffDriveCalib-v0", "excite/DiffDriveCalibSensor-v0"):
        ms, count = _env_session_ms(env_id)
        print(f"one decision, 60 segments of {env_id} driven by slip_aware ({count} "
              f"parameters): {ms:.1f} ms")
    noisy = segment_timeseries(synthetic_log(np.random.default_rng(1), 150.0, LESSON_TRUTH,
                                             SESSION_SENSOR, pose_noise=(2e-3, 2e-3)).series
                               ).segments
    rule = StoppingRule(target=SESSION_TARGET)
    previous = rule.decide(noisy[:59])
    before = _median_ms(rule, noisy[:60], 5)
    after = _median_ms(rule, noisy[:60], 15, previous)
    how = "screened" if rule.decide(noisy[:60], previous=previous).screened else "calibrated"
    print(f"one decision, 60 noisy time-series segments, target {SESSION_TARGET:g}: batch "
          f"calibration {before:.1f} ms; after the look at 59 ({how}) {after:.1f} ms; ratio "
          f"{after / before:.3f}")
    _print_session(_session(rule, noisy))
    if args.sessions:
        _sessions(args.sessions)
    rule = StoppingRule(target=args.target, sensor_pose="axle")
    truth = LESSON_TRUTH.as_array()
    false = stops = 0
    when = []
    for run in range(args.runs):
        seg = lesson_dataset(np.random.default_rng(10_000 + run), 300, dphi_std=2.0)
        for n in range(6, 301):
            decision = rule.decide(seg[:n])
            if decision.done:
                stops += 1
                when.append(n)
                error = np.abs(decision.result.params.as_array() - truth) / truth
                false += bool(np.max(error) > args.target)
                break
    low, high = rate_interval(false, stops)[1]
    print(f"false stops at target {args.target:g}, asked after every segment: {false}/{stops} "
          f"= {false / max(stops, 1):.3f} [{low:.3f}, {high:.3f}]; stopped in {stops}/"
          f"{args.runs}, median {np.median(when) if when else float('nan'):.0f} segments")


if __name__ == "__main__":
    main()
