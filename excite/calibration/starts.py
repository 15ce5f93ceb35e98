"""Closed-form first estimates: no initial guess is ever needed from the user.

* :func:`initial_estimate` (axle model): translations are linear in the radii given the
  measured heading change, headings linear in r/b.
* :func:`sensor_pose_estimate` (sensor-pose model, any l_theta in (-pi, pi]): Censi et al.'s
  two steps (T-RO 2013): the wheel ratios r_L/b, r_R/b from the heading changes (the sensor
  turns as the body does), then b and the sensor pose from the translations, a quadratic in
  (b, l_x, l_y, cos l_theta, sin l_theta) minimised on the circle cos^2 + sin^2 = 1 (here in
  closed form: the linear unknowns eliminated, the smallest eigenvector of the 2x2 rest).
* :func:`first_estimates`: the start of every fit of one calibration, for the model asked for
  and for the axle model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from excite.calibration.options import SensorPoseOption
from excite.calibration.solver import solve_psd
from excite.core.arrays import FloatArray
from excite.core.kinematics import Params, sinc_family
from excite.core.models import (
    AXLE,
    SENSOR_POSE,
    FixedSensorPoseModel,
    SegmentModel,
    SensorPose,
    sensor_to_body,
)
from excite.logs.segments import Segments

__all__ = ["DEFAULT_NOMINAL", "Starts", "body_frame_estimate", "first_estimates",
           "initial_estimate", "sensor_pose_estimate"]


#: Used only for directions the data cannot determine when no initial guess is given.
DEFAULT_NOMINAL = Params(0.05, 0.05, 0.30)


def _lstsq_from(gram: FloatArray, rhs: FloatArray, ref: FloatArray) -> tuple[FloatArray, int]:
    """Solution of the normal equations gram x = rhs closest to ``ref`` (min-norm correction),
    and the numerical rank of gram."""
    if not np.any(gram):
        return ref.copy(), 0
    lam = np.linalg.eigvalsh(gram)
    rank = int(np.sum(lam > lam[-1] * 1e-12))
    return ref + solve_psd(gram, rhs - gram @ ref), rank


def _wheel_ratios(segments: Segments, ref: FloatArray) -> tuple[FloatArray, int]:
    """(r_L/b, r_R/b) from the heading changes th_k = (r_R/b) dphi_R - (r_L/b) dphi_L, the
    rank of that linear problem, and ``ref`` along what it does not determine."""
    signed = np.stack([-segments.dphi_L, segments.dphi_R])
    gram = signed @ signed.T
    return _lstsq_from(gram, signed @ segments.dtheta, ref)


def initial_estimate(segments: Segments, fallback: Params = DEFAULT_NOMINAL) -> Params:
    """Closed-form first estimate of (r_L, r_R, b) for the axle model, no guess needed.

    With the measured heading change th_k, the translation is linear in the radii:
    (dx, dy)_k = (sinc(th_k), cosc(th_k)) * (r_L dphi_L + r_R dphi_R) / 2; and the heading
    change is linear in r/b: th_k = (r_R/b) dphi_R - (r_L/b) dphi_L. Directions the data do
    not determine are taken from ``fallback`` (keeping its b/r ratio).
    """
    phi_L, phi_R, th = segments.dphi_L, segments.dphi_R, segments.dtheta
    f, g = sinc_family(th, derivatives=False)
    # Translation rows (f, g) * (phi_L, phi_R)/2 . (r_L, r_R): 2x2 normal equations.
    phi = np.stack([phi_L, phi_R])
    w = 0.25 * (f * f + g * g)
    v = 0.5 * (f * segments.dx + g * segments.dy)
    gram = np.einsum("ik,k,jk->ij", phi, w, phi)
    r_ref = np.array([fallback.r_L, fallback.r_R])
    radii, rank_trans = _lstsq_from(gram, np.einsum("ik,k->i", phi, v), r_ref)
    if np.any(radii <= 0):
        radii, rank_trans = r_ref, 0

    b_ref = fallback.b * radii.mean() / r_ref.mean()
    ratios, rank_rot = _wheel_ratios(segments, radii / b_ref)
    if rank_trans == 0 and rank_rot > 0 and np.all(ratios > 0):
        # Nothing translates: only r/b is known; the common scale comes from the fallback.
        return Params(*(ratios * fallback.b), fallback.b)
    b = b_ref
    if rank_rot > 0:
        chord = radii[1] * phi_R - radii[0] * phi_L  # = b * dtheta
        denominator = float(th @ th)
        candidate = float(chord @ th) / denominator if denominator else 0.0
        if np.isfinite(candidate) and 0.5 * b_ref < candidate < 2.0 * b_ref:
            b = candidate
    return Params(radii[0], radii[1], b)


def body_frame_estimate(segments: Segments, pose: SensorPose,
                        fallback: Params = DEFAULT_NOMINAL) -> Params:
    """First estimate of (r_L, r_R, b) for a sensor at a known pose: the measurements turned
    into the body's increments (o = l (+) s (+) (-l)), then :func:`initial_estimate`."""
    body = sensor_to_body(segments.measured, pose)
    return initial_estimate(Segments(segments.dphi_L, segments.dphi_R, *body.T), fallback)


# the rows of [A1 A2] from (f w, g w, cos - 1, sin, s_x, s_y): columns (b, l_x, l_y, cos, sin)
_PICK_X = np.array([[1, 0, 0, 0, 0], [0, 0, 0, 0, 0], [0, 1, 0, 0, 0], [0, 0, -1, 0, 0],
                    [0, 0, 0, -1, 0], [0, 0, 0, 0, 1]], dtype=float)
_PICK_Y = np.array([[0, 0, 0, 0, 0], [1, 0, 0, 0, 0], [0, 0, 1, 0, 0], [0, 1, 0, 0, 0],
                    [0, 0, 0, 0, -1], [0, 0, 0, -1, 0]], dtype=float)


def sensor_pose_estimate(segments: Segments,
                         fallback: Params = DEFAULT_NOMINAL) -> tuple[Params, SensorPose]:
    """Closed-form first estimate of (r_L, r_R, b) and the sensor pose (Censi's two steps).

    Step 1: (r_L/b, r_R/b) by linear least squares on the heading changes. Step 2: with those
    ratios each body arc is b * c_k, c_k = (sinc, cosc)(th_k) (r_L dphi_L + r_R dphi_R)/(2b), so
    R(l_theta) s_k = b c_k + (R(th_k) - I) l_xy is linear in x1 = (b, l_x, l_y) and
    x2 = (cos l_theta, sin l_theta): minimise |A1 x1 + A2 x2|^2 over x1, then over |x2| = 1.
    Where the data do not determine something (no turns, no translation) the fallback fills
    it in and the sensor offset is taken as 0; the fit and its verdict take it from there.
    """
    ref = np.array([fallback.r_L, fallback.r_R]) / fallback.b
    ratios, rank = _wheel_ratios(segments, ref)
    if rank < 2 or np.any(ratios <= 0):
        return initial_estimate(segments, fallback), SensorPose(0.0, 0.0, 0.0)
    phi_L, phi_R = segments.dphi_L, segments.dphi_R
    th = ratios[1] * phi_R - ratios[0] * phi_L  # heading change predicted from the ratios
    f, g = sinc_family(th, derivatives=False)
    w = 0.5 * (ratios[0] * phi_L + ratios[1] * phi_R)  # ds / b
    # the x rows (f w, cos - 1, -sin, -s_x, s_y) and the y rows (g w, sin, cos - 1, -s_y, -s_x)
    # of [A1 A2] are signed picks of six arrays: their Gram matrix from the six's
    six = np.stack([f * w, g * w, -th * g, th * f, segments.dx, segments.dy])
    products = six @ six.T
    gram = _PICK_X.T @ products @ _PICK_X + _PICK_Y.T @ products @ _PICK_Y
    g11, g12, g22 = gram[:3, :3], gram[:3, 3:], gram[3:, 3:]
    eliminate = np.linalg.pinv(g11, hermitian=True) @ g12  # x1 = -eliminate @ x2
    schur = g22 - g12.T @ eliminate
    x2 = np.linalg.eigh(0.5 * (schur + schur.T))[1][:, 0]
    x1 = -eliminate @ x2
    if x1[0] < 0:
        x1, x2 = -x1, -x2
    b = float(x1[0])
    if not (np.isfinite(b) and b > 0):
        return initial_estimate(segments, fallback), SensorPose(0.0, 0.0, 0.0)
    pose = SensorPose(float(x1[1]), float(x1[2]), math.atan2(x2[1], x2[0]))
    return Params(ratios[0] * b, ratios[1] * b, b), pose


@dataclass(frozen=True)
class Starts:
    """The first estimates the fits of one calibration start from.

    Attributes
    ----------
    primary : SegmentModel
        The model asked for: the sensor-pose model (``sensor_pose`` "auto" or "estimate"),
        the axle model ("axle") or the model at a given sensor pose (a SensorPose).
    start : ndarray, shape (P,)
        The primary model's start: r_L, r_R, b (m) and, for the sensor-pose model, the
        sensor's x, y (m) and theta (rad) in the body frame.
    fallback : Params
        Fills in what the data do not determine: the initial guess when given, else
        DEFAULT_NOMINAL.
    segments : Segments
        The data the starts are computed from.
    guessed : bool
        Whether ``fallback`` is the user's initial guess (then the axle model starts there).
    """

    primary: SegmentModel
    start: FloatArray
    fallback: Params
    segments: Segments
    guessed: bool

    @cached_property
    def axle(self) -> FloatArray:
        """The axle model's start r_L, r_R, b (m) beside the sensor-pose model: the guess,
        else :func:`initial_estimate` (computed when asked: under "auto" the axle model
        usually starts from the sensor-pose model's fit)."""
        return (self.fallback if self.guessed else initial_estimate(self.segments)).as_array()


def first_estimates(segments: Segments, initial: Params | ArrayLike | None,
                    sensor_pose: SensorPoseOption) -> Starts:
    """The starts of :func:`excite.calibration.pipeline.calibrate`'s fits: the closed forms
    above, or the ``initial`` guess (Params or r_L, r_R, b in m) for the axle model and a
    given sensor pose; the sensor-pose model always starts from Censi's closed form (any
    mounting angle)."""
    fallback = DEFAULT_NOMINAL
    if initial is not None:
        fallback = initial if isinstance(initial, Params) else Params.from_array(initial)
    primary: SegmentModel
    if isinstance(sensor_pose, SensorPose):
        primary = FixedSensorPoseModel(sensor_pose)
        start = (body_frame_estimate(segments, sensor_pose, fallback) if initial is None
                 else fallback).as_array()
    elif sensor_pose == "axle":
        primary = AXLE
        start = (initial_estimate(segments) if initial is None else fallback).as_array()
    else:
        primary = SENSOR_POSE
        wheels, pose = sensor_pose_estimate(segments, fallback)
        start = np.append(wheels.as_array(), pose.as_array())
    return Starts(primary, start, fallback, segments, initial is not None)
