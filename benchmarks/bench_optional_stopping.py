"""The stopping rule's margin against optional stopping, measured: which half-width quantile
keeps the false-stop rate within the bound when the rule is asked after every segment, and
what each costs in time to target.

The rule (``excite.stopping.StoppingRule``) says *done* when q x std_i <= tolerance_i for
every parameter. The quantiles q compared, on the same calibrations (paired: one batch
calibration per look serves every variant and target, since the statistic scales as
q / target once the rule's other conditions hold), with P parameters and dof = segments - P:

- ``bound``: the Bonferroni normal quantile over the P parameters times an upper 95% bound on
  the noise scale, sqrt(dof / chi2_dof^-1(0.05));
- ``t``: the Bonferroni quantile of Student's t with dof degrees of freedom (exact coverage at
  one fixed look for a linear model with an estimated noise scale);
- ``normal``: the Bonferroni normal quantile alone (no allowance for the estimated scale).

Each robot drives the protocol for the whole budget in the env's target mode with a target
no robot reaches, so that the rule is asked after every segment and never ends the episode;
a variant *stops* at its first look whose statistic is at most 1. Per variant, target and
protocol: the median segments to the stop (censored at the budget), the false stops (stopped
with the truth outside the target) over the stops with their Wilson 95% interval.

Robots are drawn from a tuning stream of seeds (``--seed``, default 9_000_000), never the
evaluation episodes of ``excite compare``.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_optional_stopping.py --robots 200 \\
        --protocols slip_aware,learned --workers 2
"""

from __future__ import annotations

import argparse
import math
import time
from multiprocessing import get_context

import numpy as np

from agents.metrics import rate_interval

#: The target the episodes run with: no robot reaches it, so the rule is asked every segment.
UNREACHABLE = 1e-9
VARIANTS = ("bound", "t", "normal")


def _quantiles(n: int, count: int, confidence: float) -> dict[str, float]:
    """Each variant's quantile at a look with ``n`` segments and ``count`` parameters."""
    from scipy.stats import chi2, norm, t

    dof = max(n - count, 1)
    alpha = (1.0 - confidence) / (2 * count)
    z = float(norm.ppf(1.0 - alpha))
    return {"bound": z * math.sqrt(dof / chi2.ppf(0.05, dof)),
            "t": float(t.ppf(1.0 - alpha, dof)), "normal": z}


def _episode(job: tuple[str, str, int, int, float]) -> dict:
    """One robot driven by one protocol for the budget: per look, each variant's statistic at
    target 1 (inf where the rule's other conditions fail) and the max relative error of
    r_L, r_R, b against the truth."""
    import gymnasium as gym

    import envs  # noqa: F401  (registers the env ids)
    import envs.env as env_module
    from agents.catalog import make_protocol
    from agents.compare import run_protocol_episode

    env_id, protocol, seed, budget, confidence = job
    looks: list[tuple[int, dict[str, float], np.ndarray]] = []
    decide = env_module.decide

    def recorded(rule, log, sub, nominal):
        decision = decide(rule, log, sub, nominal)
        n = len(log)
        if math.isfinite(decision.quantile) and math.isfinite(decision.statistic):
            count = len(decision.result.parameter_names)
            q = _quantiles(n, count, confidence)
            at_one = decision.statistic * UNREACHABLE  # the statistic at target 1
            stats = {v: at_one * q[v] / decision.quantile for v in VARIANTS}
        else:
            stats = dict.fromkeys(VARIANTS, math.inf)
        looks.append((n, stats, decision.result.params.as_array()
                      if decision.result is not None else np.full(3, np.nan)))
        return decision

    env_module.decide = recorded
    try:
        env = gym.make(env_id, budget=budget, target=UNREACHABLE,
                       target_confidence=confidence)
        run_protocol_episode(env, make_protocol(protocol), seed)
        truth = env.unwrapped.true_params.as_array()
        env.close()
    finally:
        env_module.decide = decide
    return {"protocol": protocol, "seed": seed,
            "n": np.array([n for n, _, _ in looks]),
            "stats": {v: np.array([s[v] for _, s, _ in looks]) for v in VARIANTS},
            "error": np.array([np.max(np.abs(p / truth - 1.0)) for _, _, p in looks])}



def _summary(episodes: list[dict], variant: str, target: float, budget: int) -> str:
    stops, false = [], 0
    for ep in episodes:
        hit = np.flatnonzero(ep["stats"][variant] <= target)
        if hit.size:
            stops.append(int(ep["n"][hit[0]]))
            false += bool(ep["error"][hit[0]] > target)
        else:
            stops.append(budget + 1)  # censored
    low, high = rate_interval(false, sum(s <= budget for s in stops))[1]
    done = sum(s <= budget for s in stops)
    median = float(np.median(stops))
    shown = f"{median:g}" if median <= budget else f">{budget}"
    return (f"{shown} ({len(stops) - done} not done), false stops {false}/{done} "
            f"[{100 * low:.1f}, {100 * high:.1f}%]")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="excite/DiffDriveCalib-v0")
    parser.add_argument("--protocols", default="slip_aware")
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--budget", type=int, default=150)
    parser.add_argument("--targets", default="0.005,0.002")
    parser.add_argument("--confidence", type=float, default=0.95)
    parser.add_argument("--seed", type=int, default=9_000_000, help="first tuning seed")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    protocols = args.protocols.split(",")
    targets = [float(t) for t in args.targets.split(",")]
    jobs = [(args.env, p, args.seed + k, args.budget, args.confidence)
            for k in range(args.robots) for p in protocols]
    start = time.perf_counter()
    with get_context("fork").Pool(args.workers) as pool:
        episodes = []
        for k, ep in enumerate(pool.imap_unordered(_episode, jobs), start=1):
            episodes.append(ep)
            if k % 20 == 0 or k == len(jobs):
                print(f"  {k}/{len(jobs)} episodes, {time.perf_counter() - start:.0f} s",
                      flush=True)
    print(f"{args.env}, {args.robots} robots (seeds {args.seed}+), budget {args.budget}, "
          f"confidence {args.confidence}: segments to the stop, median (not done), false "
          "stops over stops [Wilson 95%]")
    for protocol in protocols:
        mine = [ep for ep in episodes if ep["protocol"] == protocol]
        for target in targets:
            for variant in VARIANTS:
                print(f"{protocol:>12} {target:g} {variant:>8}: "
                      f"{_summary(mine, variant, target, args.budget)}")


if __name__ == "__main__":
    main()
