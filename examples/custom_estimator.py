"""An online estimator of your own, tested in the environment's loop and compared with the
built-in ones.

An estimator is any object with ``update(dphi_L, dphi_R, dx, dy, dtheta)`` (one segment: rad,
rad, m, m, rad, the increment in the body frame at the segment's start), ``params``
(``excite.Params``, m) and ``covariance`` (3 x 3, m^2), made fresh for each episode by a
factory ``factory(nominal, sigma)``: nominal the nominal robot's ``Params``, sigma the pose
sensor's noise (sigma_x [m], sigma_y [m], sigma_theta [rad]); see
``excite.contracts.Estimator`` and ``EstimatorFactory``. (On the sensor-pose environment the
factory gets the six nominal parameters instead; this one handles the axle model only.)

On the command line it is ``module:factory`` (the module importable, e.g. from the current
folder)::

    cd examples
    excite compare --estimators custom_estimator:batch_map,online,ekf --episodes 20

Run this file to check its consistency on the ideal environment and compare it with the
built-in online estimator: ``python examples/custom_estimator.py [OUT_DIR]``.
"""

from __future__ import annotations

import sys
import tempfile

import numpy as np

from excite import Params, increment_jacobian, predict_increment


class BatchMap:
    """Maximum a posteriori estimate of (r_L, r_R, b) over every segment so far, re-solved by
    a few Gauss-Newton steps after each segment, with a Gaussian prior at the nominal robot
    (``prior_std``, relative). Simple and exact, but its cost grows with the log."""

    def __init__(self, nominal: Params, sigma, prior_std: float = 0.1, iterations: int = 3):
        self.nominal = nominal.as_array()
        self.weights = 1.0 / np.asarray(sigma, dtype=float) ** 2  # per channel x, y, theta
        self.prior = np.diag(1.0 / (prior_std * self.nominal) ** 2)
        self.iterations = iterations
        self.rows: list[tuple[float, ...]] = []
        self.estimate = self.nominal.copy()
        self.information = self.prior.copy()

    def update(self, dphi_L: float, dphi_R: float, dx: float, dy: float,
               dtheta: float) -> None:
        self.rows.append((dphi_L, dphi_R, dx, dy, dtheta))
        data = np.array(self.rows)
        for _ in range(self.iterations):
            predicted = np.column_stack(predict_increment(data[:, 0], data[:, 1],
                                                          self.estimate))
            residual = data[:, 2:] - predicted
            residual[:, 2] = np.angle(np.exp(1j * residual[:, 2]))  # wrapped heading
            jac = increment_jacobian(data[:, 0], data[:, 1], self.estimate)  # (N, 3, 3)
            weighted = jac * self.weights[None, :, None]
            information = self.prior + np.einsum("nci,ncj->ij", weighted, jac)
            gradient = (np.einsum("nci,nc->i", weighted, residual)
                        - self.prior @ (self.estimate - self.nominal))
            step = np.linalg.solve(information, gradient)
            self.estimate = np.maximum(self.estimate + step, 1e-6 * self.nominal)
        self.information = information

    @property
    def params(self) -> Params:
        return Params.from_array(self.estimate)

    @property
    def covariance(self) -> np.ndarray:
        return np.linalg.inv(self.information)


def batch_map(nominal: Params, sigma) -> BatchMap:
    """The factory: ``--estimators custom_estimator:batch_map``."""
    return BatchMap(nominal, sigma)


def main(out: str, episodes: int = 10) -> int:
    """Check BatchMap's consistency (ANEES against its chi-square bounds) on the ideal
    environment, then compare it with the built-in online estimator; results go to ``out``."""
    from envs.estimator_check import check_estimator
    from excite.cli import main as excite

    report = check_estimator("excite/DiffDriveCalibIdeal-v0", batch_map, episodes=episodes,
                             budget=20)
    print(report.summary())
    return excite(["compare", "--protocols", "arcs", "--estimators",
                   "custom_estimator:batch_map,online", "--env",
                   "excite/DiffDriveCalibIdeal-v0", "--episodes", "2", "--segments", "8",
                   "--workers", "1", "--tuned", "none", "--out", out])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp()))
