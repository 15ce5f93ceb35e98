"""`make bench`: run every benchmark and print what it measured (record it in BENCHMARKS.md)."""

from __future__ import annotations

import os
import platform
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))

import bench_calibration  # noqa: E402
import bench_compare  # noqa: E402
import bench_env  # noqa: E402
import bench_estimator  # noqa: E402
import bench_import  # noqa: E402
import bench_ray  # noqa: E402
import bench_sensor_pose  # noqa: E402
import bench_simulation  # noqa: E402
import bench_slip  # noqa: E402

if __name__ == "__main__":
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python "
          f"{platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M')}")
    for module in (bench_import, bench_calibration, bench_sensor_pose, bench_simulation,
                   bench_env, bench_slip, bench_estimator, bench_compare, bench_ray):
        print(f"\n=== {module.__name__} ===", flush=True)
        with_argv = (bench_calibration, bench_sensor_pose, bench_ray, bench_env)
        module.main([]) if module in with_argv else module.main()
