"""A calibration protocol of your own, plugged into excite without editing it.

A protocol subclasses ``agents.protocols.Protocol``, declares its settings as ``Parameter``s
and implements ``plan(knowledge)``: the next (left, right) wheel-speed command in [-1, 1]^2
(fractions of the motor limit) from what the robot knows (``excite.contracts.RobotKnowledge``,
never the hidden truth). The wall guard every protocol acts through keeps it off the walls.

On the command line it is ``module:Class`` with optional ``:KEY=VALUE`` settings, wherever a
protocol name goes (the module must be importable, e.g. from the current folder)::

    cd examples
    excite protocols custom_protocol:Sweep
    excite compare --protocols custom_protocol:Sweep:turn=0.6,umbmark --episodes 20
    excite simulate --protocol custom_protocol:Sweep --segments 30 --out sweep.csv

``agents.catalog.register("sweep", "custom_protocol:Sweep")`` gives it a short name.
Run this file to compare it with UMBmark on a few episodes of the ideal environment:
``python examples/custom_protocol.py [OUT_DIR]``.
"""

from __future__ import annotations

import sys
import tempfile

import numpy as np

from agents.protocols import SPEED, WALL_MARGIN, Parameter, Protocol
from excite.contracts import RobotKnowledge


class Sweep(Protocol):
    """Wheel commands that turn around the circle: forward, arcs, a spin, backwards, a spin
    the other way, ... (every maneuver in turn, so every parameter gets excited)."""

    parameters = (
        SPEED,
        Parameter("turn", float, 0.4, "rotation of the command (left, right) per segment "
                  "(rad)", 0.05, 3.0, grid=4),
        WALL_MARGIN,
    )
    speed: float
    turn: float

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        # pi/4: both wheels forward (straight); 3 pi/4: left back, right forward (a spin)
        angle = np.pi / 4 + self.turn * self.step_index
        return self.speed * np.array([np.cos(angle), np.sin(angle)])


def main(out: str) -> int:
    """Compare Sweep with UMBmark on the ideal environment; the results go to ``out``."""
    from excite.cli import main as excite

    return excite(["compare", "--protocols", "custom_protocol:Sweep:turn=0.6,umbmark",
                   "--env", "excite/DiffDriveCalibIdeal-v0", "--episodes", "2",
                   "--segments", "8", "--workers", "1", "--tuned", "none", "--out", out])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp()))
