"""Drawing of the arena, the robot, its trail and the current estimate (matplotlib, lazy)."""

from __future__ import annotations

import math

import numpy as np

from envs.robot import DEFAULT_CHASSIS_SIZE, RobotSpec
from excite.core.kinematics import Params


class ArenaRenderer:
    """Renders frames as uint8 RGB arrays (H, W, 3); ``human=True`` also shows a window."""

    def __init__(self, arena_size: float, human: bool = False, size_px: int = 480):
        import matplotlib

        if not human:
            matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        self._plt = plt
        self.human = human
        self.fig = plt.figure(figsize=(size_px / 100, size_px / 100), dpi=100)
        if not human:
            FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes((0.02, 0.02, 0.96, 0.88))
        half = 0.5 * arena_size
        self.half = half

    def draw(self, path: np.ndarray, pose: np.ndarray, robot: RobotSpec, estimate: Params,
             sigma_min: float, n_segments: int, budget: int) -> np.ndarray:
        ax, half = self.ax, self.half
        ax.clear()
        ax.set_xlim(-half * 1.05, half * 1.05)
        ax.set_ylim(-half * 1.05, half * 1.05)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.plot([-half, half, half, -half, -half], [-half, -half, half, half, -half], "k-", lw=3)
        ax.plot(path[:, 0], path[:, 1], "-", color="tab:blue", lw=1, alpha=0.7)
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        rot = np.array([[c, -s], [s, c]])
        hl, hw = 0.5 * robot.chassis_length, 0.5 * robot.chassis_width
        body = np.array([[-hl, -hw], [hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw]]) @ rot.T + (x, y)
        ax.fill(body[:, 0], body[:, 1], color="tab:orange", alpha=0.6)
        for side, radius in ((1, robot.r_L), (-1, robot.r_R)):
            wheel = np.array([[-radius, 0.0], [radius, 0.0]]) + (0.0, side * robot.b / 2)
            wheel = wheel @ rot.T + (x, y)
            ax.plot(wheel[:, 0], wheel[:, 1], "k-", lw=4)
        scale = robot.chassis_length / DEFAULT_CHASSIS_SIZE  # heading arrow sized to the robot
        ax.arrow(x, y, 0.25 * scale * c, 0.25 * scale * s, width=0.02 * scale, color="k")
        self.fig.suptitle(
            f"segment {n_segments}/{budget}   sigma_min {sigma_min:.1f}\n"
            f"estimate r_L {estimate.r_L * 1e3:.2f} mm, r_R {estimate.r_R * 1e3:.2f} mm, "
            f"b {estimate.b * 1e3:.1f} mm", fontsize=9)
        self.fig.canvas.draw()
        frame = np.asarray(self.fig.canvas.buffer_rgba())[:, :, :3].copy()
        if self.human:
            self._plt.pause(0.001)
        return frame

    def close(self) -> None:
        self._plt.close(self.fig)
