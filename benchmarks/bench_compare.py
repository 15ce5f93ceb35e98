"""Protocol comparison (issue 4): wall time of 7 protocols x 20 episodes x 30 segments on 2
workers, and the summary tables on the ideal and slip envs (plus `learned` when a policy is
shipped, over 100 held-out episodes)."""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

from excite.cli import main as cli


def run(args: list[str]) -> float:
    start = time.perf_counter()
    code = cli(args)
    if code != 0:
        raise SystemExit(f"excite {' '.join(args)} failed with {code}")
    return time.perf_counter() - start


def main() -> dict:
    tmp = Path(tempfile.mkdtemp())
    seven = "straight,spin,straight_spin,umbmark,random,arcs,greedy"
    out = {}
    for env in ("excite/DiffDriveCalibIdeal-v0", "excite/DiffDriveCalib-v0"):
        wall = run(["compare", "--protocols", seven, "--episodes", "20", "--workers", "2",
                    "--env", env, "--out", str(tmp / env.split("/")[1])])
        print(f"\n{env}: 7 protocols x 20 episodes x 30 segments in {wall:.1f} s (2 workers)\n")
        out[env] = wall
    wall = run(["compare", "--episodes", "100", "--workers", "2", "--out", str(tmp / "all")])
    print(f"\nslip env, every available protocol, 100 episodes: {wall:.1f} s")
    shutil.rmtree(tmp)
    return out


if __name__ == "__main__":
    main()
