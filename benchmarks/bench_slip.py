"""Slip bias of the slip env (issue 3 acceptance 3): batch calibration of 100-segment logs of
the wall-guarded `random` protocol with commands limited to a fraction of the motor limit,
and of full-speed spins alternating with straight runs, over many hidden robots."""

from __future__ import annotations

import numpy as np

from agents.compare import make_env
from agents.protocols import RandomCommands, StraightSpin
from excite import calibrate


def bias(protocol, robots: int = 40, segments: int = 100, env_id="excite/DiffDriveCalib-v0"):
    env = make_env(env_id, segments)
    errors = []
    for seed in range(robots):
        env.reset(seed=seed)
        protocol.reset(np.random.default_rng(seed))
        for _ in range(segments):
            env.step(protocol.act(env.unwrapped.knowledge()))
        base = env.unwrapped
        result = calibrate(base.segments, sigma=base.sigma)
        errors.append(result.params.as_array() / base.true_params.as_array() - 1)
    e = np.array(errors)
    return {"mean_signed_pct": (100 * e.mean(axis=0)).tolist(),
            "mean_abs_pct": (100 * np.abs(e).mean(axis=0)).tolist()}


def main() -> dict:
    cases = {
        "random <= 30% (gentle)": RandomCommands(max_speed=0.3),
        "random <= 100%": RandomCommands(),
        "full-speed straight+spin": StraightSpin(speed=1.0),
        "ideal env, random <= 100%": None,
    }
    out = {}
    for name, protocol in cases.items():
        if protocol is None:
            out[name] = bias(RandomCommands(), env_id="excite/DiffDriveCalibIdeal-v0")
        else:
            out[name] = bias(protocol)
        r = out[name]
        print(f"{name:<28} bias (mean signed error, r_L r_R b) "
              + " ".join(f"{v:+.3f}%" for v in r["mean_signed_pct"])
              + "   mean |error| " + " ".join(f"{v:.3f}%" for v in r["mean_abs_pct"]))
    return out


if __name__ == "__main__":
    main()
