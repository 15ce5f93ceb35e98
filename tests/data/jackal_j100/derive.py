"""Derive the time-series fixture of the Jackal J100 log from the authors' files.

Source: LeoBrizi/jackass-calibrator (MIT licence; see NOTICE.md beside this file),
``calib_dump.txt`` and ``calib_dump_associations.txt``. Wheel speeds (rad/s, right then left)
are integrated by the trapezoidal rule into cumulative wheel angles (rad); the lidar odometry
poses keep their own timestamps. Times start at the first encoder row.

Usage: python derive.py SOURCE_DIR   (writes encoders.csv and poses.csv here)
"""

import sys
from pathlib import Path

import numpy as np


def main(source: Path, out: Path) -> None:
    dump = np.loadtxt(source / "calib_dump.txt")
    t, speed_right, speed_left = dump[:, 0], dump[:, 1], dump[:, 2]
    step = np.diff(t)
    phi_left = np.concatenate([[0.0], np.cumsum(0.5 * (speed_left[1:] + speed_left[:-1]) * step)])
    phi_right = np.concatenate([[0.0],
                                np.cumsum(0.5 * (speed_right[1:] + speed_right[:-1]) * step)])
    rows = [line.split() for line in (source / "calib_dump_associations.txt").open()]
    poses = np.array([[float(v) for v in row[6:10]] for row in rows if len(row) > 6])
    np.savetxt(out / "encoders.csv", np.column_stack([t - t[0], phi_left, phi_right]),
               delimiter=",", header="t,phi_L,phi_R", comments="", fmt="%.6f")
    np.savetxt(out / "poses.csv", np.column_stack([poses[:, 3] - t[0], poses[:, :3]]),
               delimiter=",", header="t,x,y,theta", comments="", fmt="%.6f")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(__file__).resolve().parent)
