"""What the Monte Carlo benchmarks share: the command line they start from."""

from __future__ import annotations

import argparse
import os


def monte_carlo_parser(doc: str, datasets: int) -> argparse.ArgumentParser:
    """The parser of a Monte Carlo benchmark: its description the first line of ``doc`` (the
    module's docstring), ``--datasets`` (default ``datasets``) and ``--workers`` (processes;
    default every core)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=datasets)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    return parser
