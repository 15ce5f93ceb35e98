"""Start-up time: `import excite` (target < 0.3 s) and `excite --version`, each in a fresh
interpreter, median of repeats, beside a bare `python -c pass` measured in the same run."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np


def _median_seconds(argv: list[str], repeats: int = 7) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, capture_output=True)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> dict:
    python = sys.executable
    bare = _median_seconds([python, "-c", "pass"])
    numpy_only = _median_seconds([python, "-c", "import numpy"])
    imported = _median_seconds([python, "-c", "import excite"])
    version = _median_seconds([python, "-m", "excite.cli", "--version"])
    print(f"fresh interpreter, median of 7: python -c pass {bare:.3f} s; import numpy "
          f"{numpy_only:.3f} s; import excite {imported:.3f} s "
          f"(+{imported - bare:.3f} s over the bare interpreter); excite --version "
          f"{version:.3f} s")
    return {"bare_s": bare, "numpy_s": numpy_only, "import_excite_s": imported,
            "version_s": version}


if __name__ == "__main__":
    main()
