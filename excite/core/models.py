"""Segment models: what a motion segment's measured increment is, as a function of the
parameters. The single place where prediction, analytic Jacobian, parameter names, units,
estimation transforms and information scales live; calibration, online estimation, the
information measures and the planners take a model.

Two models (docs/conventions.md, "Sensor pose"):

* :data:`AXLE` (``"axle"``, 3 parameters r_L, r_R, b in m): the external sensor measures the
  body frame's own motion, the lesson's arc o = (dx, dy, dtheta).
* :data:`SENSOR_POSE` (``"sensor_pose"``, 6 parameters r_L, r_R, b, l_x, l_y [m],
  l_theta [rad]): the sensor is mounted at l = (l_x, l_y, l_theta) in the body frame and
  measures its own motion in its own frame at the segment's start,
  s = (-l) (+) o (+) l, i.e. s_xy = R(-l_theta) (o_xy + (R(dtheta) - I) l_xy), s_theta = dtheta
  (Censi et al., T-RO 2013). With l = 0 it is the axle model.

:class:`FixedSensorPoseModel` is the 3-parameter model of a sensor at a known pose.

Arrays are batch-first: parameters theta (..., P), wheel increments (..., N); ``predict``
gives (..., N, 3) and ``jacobian`` (..., N, 3, P). ``evaluate`` is the kernel, channel-major:
predictions (3, ..., N) and derivatives (3, P, ..., N), the layout solvers want.

Sub-steps: a segment cut from a log need not be one arc (the curvature changes within it).
With ``substeps=True`` the wheel increments are (..., N, K): each segment's K consecutive
sub-increments (zero-padded: a zero sub-increment is the identity), and the body's motion is
their composition o = a_1 (+) a_2 (+) ... (+) a_K (:func:`compose_substeps`); the sensor
transform then applies to o as before. With K = 1 it is the single arc. Each sub-step is an
arc corrected for the change of its speed and turn rate within it (:func:`curvature_change`,
from its neighbours): one arc per sub-step erred by O(h^2) of the sub-step h over a segment,
the corrected one by O(h^3).

Wheel Jacobian: ``wheel_jacobian`` gives the derivatives of the measured increment by the wheel
increments themselves, (..., N, 2) -> (..., N, 3, 2) (m/rad, rad/rad), or by each sub-increment
with ``substeps``: (..., N, K, 3, 2). It carries noise that enters through the wheels (slip,
encoder quantization) into the measured increments (:mod:`excite.calibration.noise`).

Estimation transforms (how each parameter is stepped, and what "relative" means):
``log`` for lengths that are positive (r_L, r_R, b), ``identity`` for offsets (l_x, l_y: may
be 0; measured in units of a length scale, the nominal b), ``angle`` for l_theta (wrapped to
(-pi, pi]). ``column_scale`` gives the factors that make the Jacobian relative
(docs/conventions.md):
the value itself for ``log`` parameters, the nominal b for offsets, 1 rad for angles.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.core import se2
from excite.core.kinematics import Arc, Params, sinc_family_scalar, wrap_angle

__all__ = [
    "AXLE",
    "SENSOR_POSE",
    "AxleModel",
    "FixedSensorPoseModel",
    "SegmentModel",
    "SensorPose",
    "SensorPoseModel",
    "body_to_sensor",
    "compose_substeps",
    "single_arc_error",
    "increment_jacobian",
    "substep_derivatives",
    "sensor_to_body",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SensorPose:
    """Pose of the external pose sensor in the body frame: x forward, y left (m), theta
    counter-clockwise (rad, wrapped to (-pi, pi])."""

    x: float
    y: float
    theta: float

    def __post_init__(self) -> None:
        values = float(self.x), float(self.y), float(self.theta)
        if not all(map(math.isfinite, values)):
            raise ValueError(f"sensor pose must be finite (x, y in m, theta in rad), got {values}")
        object.__setattr__(self, "x", values[0])
        object.__setattr__(self, "y", values[1])
        object.__setattr__(self, "theta", float(wrap_angle(values[2])))

    def as_array(self) -> FloatArray:
        return np.array([self.x, self.y, self.theta])


class SegmentModel(ABC):
    """A model of one segment's measured increment (dx, dy, dtheta) given the wheel
    increments and P parameters theta (see the module doc for shapes and transforms)."""

    name: str
    names: tuple[str, ...]
    units: tuple[str, ...]
    transforms: tuple[str, ...]

    @property
    def size(self) -> int:
        return len(self.names)

    @abstractmethod
    def evaluate(self, dphi_L: ArrayLike, dphi_R: ArrayLike, theta: ArrayLike,
                 jacobian: bool = True, substeps: bool = False
                 ) -> tuple[FloatArray, FloatArray | None]:
        """Predictions (3, ..., N) and, if asked, derivatives (3, P, ..., N) by theta; with
        ``substeps`` the increments are (..., N, K) sub-increments (see the module doc)."""

    @abstractmethod
    def evaluate_scalar(self, dphi_L: float, dphi_R: float,
                        theta: tuple[float, ...]) -> tuple[tuple[float, float, float],
                                                          tuple[tuple[float, ...], ...]]:
        """:meth:`evaluate` of one segment in pure Python, the fast form for the one-filter
        update (:func:`excite.estimators.online.update_scalar`) and the EKF: the prediction
        (dx, dy, dtheta) and the three Jacobian rows (each P floats), equal to
        :meth:`evaluate`'s up to rounding (tests/unit/core/test_fast_forms.py)."""

    def predict(self, dphi_L: ArrayLike, dphi_R: ArrayLike, theta: ArrayLike) -> FloatArray:
        """Predicted measured increments (..., N, 3): dx, dy (m), dtheta (rad)."""
        prediction, _ = self.evaluate(dphi_L, dphi_R, theta, jacobian=False)
        return np.moveaxis(prediction, 0, -1)

    def jacobian(self, dphi_L: ArrayLike, dphi_R: ArrayLike, theta: ArrayLike) -> FloatArray:
        """d(dx, dy, dtheta)/d theta of each segment, (..., N, 3, P) in the parameters' units."""
        _, jac = self.evaluate(dphi_L, dphi_R, theta)
        return np.moveaxis(jac, (0, 1), (-2, -1))

    @abstractmethod
    def evaluate_wheels(self, dphi_L: ArrayLike, dphi_R: ArrayLike, theta: ArrayLike,
                        substeps: bool = False) -> FloatArray:
        """Derivatives (3, 2, ..., N) of the predictions by (dphi_L, dphi_R) (m/rad, rad/rad);
        with ``substeps`` by each sub-increment: (3, 2, ..., N, K) (see the module doc)."""

    def wheel_jacobian(self, dphi_L: ArrayLike, dphi_R: ArrayLike, theta: ArrayLike,
                       substeps: bool = False) -> FloatArray:
        """d(dx, dy, dtheta)/d(dphi_L, dphi_R) of each segment, (..., N, 3, 2); with
        ``substeps`` by each sub-increment, (..., N, K, 3, 2). Units m/rad and rad/rad."""
        jac = self.evaluate_wheels(dphi_L, dphi_R, theta, substeps)
        return np.moveaxis(jac, (0, 1), (-2, -1))

    def column_scale(self, nominal: ArrayLike) -> FloatArray:
        """Factors (..., P) that make Jacobian columns relative at ``nominal``
        (docs/conventions.md):
        the value for log parameters, the nominal b for offsets, 1 rad for angles."""
        nominal = np.asarray(nominal, dtype=float)
        b = nominal[..., 2:3]
        columns = []
        for i, transform in enumerate(self.transforms):
            if transform == "log":
                columns.append(nominal[..., i:i + 1])
            elif transform == "identity":
                columns.append(b)
            else:
                columns.append(np.ones_like(b))
        return np.concatenate(columns, axis=-1)

    def step(self, theta: ArrayLike, delta: ArrayLike, scale: ArrayLike) -> FloatArray:
        """theta moved by ``delta`` in relative units: log parameters multiplied by exp(delta),
        offsets moved by delta * scale, angles by delta (then wrapped)."""
        theta, delta = np.asarray(theta, dtype=float), np.asarray(delta, dtype=float)
        scale = np.asarray(scale, dtype=float)
        out = np.empty(np.broadcast_shapes(theta.shape, delta.shape))
        for i, transform in enumerate(self.transforms):
            if transform == "log":
                out[..., i] = theta[..., i] * np.exp(delta[..., i])
            elif transform == "identity":
                out[..., i] = theta[..., i] + delta[..., i] * scale[..., i]
            else:
                out[..., i] = wrap_angle(theta[..., i] + delta[..., i])
        return out

    def split(self, theta: ArrayLike) -> tuple[Params, SensorPose | None]:
        """The wheel parameters and the sensor pose (None for the axle model) of theta (P,)."""
        theta = np.asarray(theta, dtype=float).reshape(-1)
        return Params(*theta[:3]), None


def _broadcast_increments(dphi_L: ArrayLike, dphi_R: ArrayLike) -> tuple[FloatArray, FloatArray]:
    phi_L = np.asarray(dphi_L, dtype=float)
    phi_R = np.asarray(dphi_R, dtype=float)
    return np.broadcast_arrays(phi_L, phi_R) if phi_L.shape != phi_R.shape else (phi_L, phi_R)


def _parameter(theta: FloatArray, i: int, trailing: int = 1) -> FloatArray | float:
    """Parameter i of theta (..., P), shaped to broadcast with increments that have
    ``trailing`` axes more (..., N) or (..., N, K)."""
    return float(theta[i]) if theta.ndim == 1 else theta[(..., i) + (None,) * trailing]


def _central(a: FloatArray) -> FloatArray:
    """a_(k+1) - a_(k-1) along the last axis (sub-steps), a zero beyond either end."""
    out = np.zeros_like(a)
    if a.shape[-1] > 1:
        np.subtract(a[..., 2:], a[..., :-2], out=out[..., 1:-1])
        out[..., 0] = a[..., 1]
        out[..., -1] = -a[..., -2]
    return out


def curvature_change(arc: Arc, b: FloatArray | float, prediction: FloatArray,
                     jac: FloatArray | None) -> tuple[FloatArray, FloatArray]:
    """Correct consecutive sub-step arcs (``arc``: (..., K), equal durations h, of wheel
    separation ``b``, m) for the change of speed and turn rate within each, in place:
    ``prediction`` (3, ..., K) and ``jac`` (3, 3, ..., K, by r_L, r_R, b; or None).

    An arc takes speed v and turn rate w as constant over its sub-step. With v + v' t and
    w + w' t the increment's lateral part differs, to leading order, by
    h^3 (v' w - v w') / 12 in the sub-step's frame (nothing along it, nothing in heading),
    which vanishes at constant curvature. The rates from the neighbours by central
    differences, (ds_(k+1) - ds_(k-1)) / 2h and the same of dtheta, give
    dy_k += ((ds_(k+1) - ds_(k-1)) dtheta_k - ds_k (dtheta_(k+1) - dtheta_(k-1))) / 24 (m).
    A zero beyond a segment's ends (its padding too) halves the term of its first and last
    sub-step, an O(h^3) error of two sub-steps; the O(h^2) error of every sub-step is gone
    (synthetic smooth driving, 1 s segments: 1.5e-5 m to 2.5e-7 m at h = 20 ms). Returns the
    central differences of ds and dtheta (m, rad; (..., K)) it used."""
    ds, dth = arc.ds, arc.dtheta
    change_ds, change_th = _central(ds), _central(dth)
    prediction[1] += (change_ds * dth - ds * change_th) / 24.0
    if jac is None:
        return change_ds, change_th
    # the parameters move ds and dtheta through 0.5 phi_L, 0.5 phi_R (d_ds) and -phi_L / b,
    # phi_R / b, -dtheta / b (d_dtheta): their central differences from two of the wheels'
    half_L, half_R = _central(arc.d_ds[0]), _central(arc.d_ds[1])
    changes = ((half_L, -2.0 * half_L / b), (half_R, 2.0 * half_R / b), (0.0, -change_th / b))
    for k, (change_g_ds, change_g_th) in enumerate(changes):
        g_ds, g_th = arc.d_ds[k], arc.d_dtheta[k]
        jac[1, k] += (change_g_ds * dth + change_ds * g_th - g_ds * change_th
                      - ds * change_g_th) / 24.0
    return change_ds, change_th


def _shifted(a: FloatArray, by: int) -> FloatArray:
    """a_(k - by) along the last axis (sub-steps), a zero beyond either end."""
    out = np.zeros_like(a)
    if by > 0:
        out[..., by:] = a[..., :-by]
    else:
        out[..., :by] = a[..., -by:]
    return out


def _curvature_change_by_wheels(out: FloatArray, arc: Arc, changes: tuple[FloatArray, FloatArray],
                                c: FloatArray, s: FloatArray, d_ds: tuple, d_dtheta: tuple
                                ) -> None:
    """Add to the composition's derivatives by each wheel sub-increment (3, 2, ..., K),
    in place, what it moves through :func:`curvature_change` (``changes``: the central
    differences of ds and dtheta it returned): the lateral term of its own sub-step and of
    its two neighbours (m/rad), each turned by that sub-step's heading (``c``, ``s``: its
    cosine and sine, (..., K)). ``d_ds``, ``d_dtheta``: ds and dtheta of a sub-step by each
    wheel's sub-increment (m/rad, rad/rad)."""
    ds, dth = arc.ds, arc.dtheta
    change_ds, change_th = changes
    for w in range(2):
        a, b = d_ds[w], d_dtheta[w]
        own = (change_ds * b - a * change_th) / 24.0  # of this sub-step's term
        cross = (a * dth - ds * b) / 24.0  # of the next sub-step's term, by this one's
        after = _shifted(cross, 1)  # on the term of sub-step k - 1, by sub-increment k
        before = -_shifted(cross, -1)  # on the term of sub-step k + 1, by sub-increment k
        out[0, w] -= s * own + _shifted(s, 1) * after + _shifted(s, -1) * before
        out[1, w] += c * own + _shifted(c, 1) * after + _shifted(c, -1) * before


def compose_substeps(prediction: FloatArray, jac: FloatArray | None
                     ) -> tuple[FloatArray, FloatArray | None]:
    """The composition a_1 (+) ... (+) a_K of body increments (3, ..., K) along the last
    axis, and its derivatives (3, P, ..., K) -> (3, P, ...) by the chain rule: with
    Theta_k the heading before sub-step k, X = sum_k R(Theta_k) a_k,xy and
    Theta = sum_k a_k,theta (m, rad). The derivatives are those of
    :func:`substep_derivatives` summed over the sub-steps, each sum taken in one pass."""
    c, s, world = _world_substeps(prediction)
    total = world[0].sum(axis=-1), world[1].sum(axis=-1)
    out = np.stack([total[0], total[1], prediction[2].sum(axis=-1)])
    if jac is None:
        return out, None
    tail_x, tail_y = _tails(world, total)

    def dot(weight: FloatArray, rows: FloatArray) -> FloatArray:  # sum_k weight_k rows_pk
        return np.einsum("...k,p...k->p...", weight, rows)

    out_jac = np.stack([dot(c, jac[0]) - dot(s, jac[1]) - dot(tail_y, jac[2]),
                        dot(s, jac[0]) + dot(c, jac[1]) + dot(tail_x, jac[2]),
                        jac[2].sum(axis=-1)])
    return out, out_jac


def substep_derivatives(prediction: FloatArray, jac: FloatArray,
                        world: tuple | None = None) -> FloatArray:
    """Derivatives (3, Q, ..., K) of the composition a_1 (+) ... (+) a_K (body increments
    (3, ..., K), :func:`compose_substeps`) by Q quantities each of which moves only its own
    sub-step k, given d a_k / d q (3, Q, ..., K): R(Theta_k) d a_k,xy + J (X - W_<=k)
    d a_k,theta, with W_<=k the displacement up to and including sub-step k (m, rad).
    ``world``: :func:`_world_substeps` of ``prediction`` when the caller has it."""
    c, s, world = _world_substeps(prediction) if world is None else world
    tail_x, tail_y = _tails(world, (world[0].sum(axis=-1), world[1].sum(axis=-1)))
    return np.stack([c * jac[0] - s * jac[1] - tail_y * jac[2],
                     s * jac[0] + c * jac[1] + tail_x * jac[2], jac[2]])


def _world_substeps(prediction: FloatArray
                    ) -> tuple[FloatArray, FloatArray, tuple[FloatArray, FloatArray]]:
    """For body increments (3, ..., K): cos and sin of Theta_k, the heading before sub-step
    k, and each sub-step's displacement R(Theta_k) a_k,xy (x, y) in the frame of the
    composition's start (m); each (..., K)."""
    dx, dy, dth = prediction
    heading = np.cumsum(dth, axis=-1) - dth  # Theta_k, exclusive
    c, s = np.cos(heading), np.sin(heading)
    return c, s, (c * dx - s * dy, s * dx + c * dy)


def _tails(world: tuple[FloatArray, FloatArray], total: tuple[FloatArray, FloatArray]
           ) -> tuple[FloatArray, FloatArray]:
    """X - W_<=k (x, y), each (..., K): the displacement after sub-step k (m), from the
    sub-steps' displacements ``world`` and their sums ``total`` (:func:`_world_substeps`)."""
    return (total[0][..., None] - np.cumsum(world[0], axis=-1),
            total[1][..., None] - np.cumsum(world[1], axis=-1))


class AxleModel(SegmentModel):
    """The lesson's model: the sensor measures the axle midpoint's arc (3 parameters)."""

    name = "axle"
    names = ("r_L", "r_R", "b")
    units = ("m", "m", "m")
    transforms = ("log", "log", "log")

    def __reduce__(self) -> str:
        return "AXLE"  # one instance: code compares models by identity

    def evaluate(self, dphi_L, dphi_R, theta, jacobian=True, substeps=False):
        return self._evaluated(dphi_L, dphi_R, theta, jacobian, substeps)[:2]

    def evaluate_turning(self, dphi_L, dphi_R, theta, jacobian=True, substeps=False):
        """:meth:`evaluate`, and the turn (sin(dtheta), cos(dtheta) - 1) of each increment
        from the arc's sinc and cosc (dtheta f, -dtheta g), or None for composed sub-steps."""
        prediction, jac, arc = self._evaluated(dphi_L, dphi_R, theta, jacobian, substeps)
        return prediction, jac, (None if arc is None
                                 else (arc.dtheta * arc.f, -arc.dtheta * arc.g))

    def _evaluated(self, dphi_L, dphi_R, theta, jacobian, substeps):
        """:meth:`evaluate`, and the arc of each increment (None for composed sub-steps)."""
        phi_L, phi_R = _broadcast_increments(dphi_L, dphi_R)
        theta = np.asarray(theta, dtype=float)
        trailing = 1 + substeps
        r_L, r_R, b = (_parameter(theta, i, trailing) for i in range(3))
        arc = Arc(phi_L, phi_R, r_L, r_R, b, derivatives=jacobian)
        shape = np.broadcast_shapes(phi_L.shape, theta.shape[:-1] + (1,) * min(phi_L.ndim,
                                                                               trailing))
        prediction = np.empty((3,) + shape)
        prediction[0], prediction[1], prediction[2] = arc.dx, arc.dy, arc.dtheta
        jac = arc.fill_jacobian(np.empty((3, 3) + shape)) if jacobian else None
        if substeps:
            curvature_change(arc, b, prediction, jac)
            return compose_substeps(prediction, jac) + (None,)
        return prediction, jac, arc

    def evaluate_wheels(self, dphi_L, dphi_R, theta, substeps=False):
        phi_L, phi_R = _broadcast_increments(dphi_L, dphi_R)
        theta = np.asarray(theta, dtype=float)
        trailing = 1 + substeps
        r_L, r_R, b = (_parameter(theta, i, trailing) for i in range(3))
        arc = Arc(phi_L, phi_R, r_L, r_R, b)
        # the arc depends on the wheels through ds = (r_L phi_L + r_R phi_R) / 2 and
        # dtheta = (r_R phi_R - r_L phi_L) / b
        d_ds, d_dtheta = (0.5 * r_L, 0.5 * r_R), (-r_L / b, r_R / b)
        shape = np.broadcast_shapes(arc.dx.shape, np.shape(r_L))
        jac = np.empty((3, 2) + shape)
        for w in range(2):
            jac[2, w] = d_dtheta[w]
            jac[0, w] = d_ds[w] * arc.f + arc.ds * arc.fp * d_dtheta[w]
            jac[1, w] = d_ds[w] * arc.g + arc.ds * arc.gp * d_dtheta[w]
        if not substeps:
            return jac
        prediction = np.stack(np.broadcast_arrays(arc.dx, arc.dy, arc.dtheta))
        changes = curvature_change(arc, b, prediction, None)
        world = _world_substeps(prediction)
        out = substep_derivatives(prediction, jac, world)
        _curvature_change_by_wheels(out, arc, changes, world[0], world[1], d_ds, d_dtheta)
        return out

    def evaluate_scalar(self, dphi_L, dphi_R, theta):
        r_L, r_R, b = theta[0], theta[1], theta[2]
        s_L, s_R = r_L * dphi_L, r_R * dphi_R
        ds, th = 0.5 * (s_L + s_R), (s_R - s_L) / b
        f, g, fp, gp = sinc_family_scalar(th)
        t = (-dphi_L / b, dphi_R / b, -th / b)
        a = (0.5 * dphi_L, 0.5 * dphi_R, 0.0)
        kf, kg = ds * fp, ds * gp
        return ((ds * f, ds * g, th),
                (tuple(a[i] * f + kf * t[i] for i in range(3)),
                 tuple(a[i] * g + kg * t[i] for i in range(3)), t))


class SensorPoseModel(SegmentModel):
    """Sensor at l = (l_x, l_y, l_theta) in the body frame, estimated with the wheels
    (6 parameters): s_xy = R(-l_theta) (o_xy + (R(dtheta) - I) l_xy), s_theta = dtheta."""

    name = "sensor_pose"
    names = ("r_L", "r_R", "b", "l_x", "l_y", "l_theta")
    units = ("m", "m", "m", "m", "m", "rad")
    transforms = ("log", "log", "log", "identity", "identity", "angle")

    def __reduce__(self) -> str:
        return "SENSOR_POSE"

    def evaluate(self, dphi_L, dphi_R, theta, jacobian=True, substeps=False):
        theta = np.asarray(theta, dtype=float)
        body, body_jac, turn = AXLE.evaluate_turning(dphi_L, dphi_R, theta[..., :3], jacobian,
                                                     substeps)
        return _to_sensor(body, body_jac, theta[..., 3:], theta.ndim == 1, turn)

    def evaluate_wheels(self, dphi_L, dphi_R, theta, substeps=False):
        theta = np.asarray(theta, dtype=float)
        return _wheels_to_sensor(dphi_L, dphi_R, theta[..., :3], theta[..., 3:], substeps)

    def evaluate_scalar(self, dphi_L, dphi_R, theta):
        body, body_jac = AXLE.evaluate_scalar(dphi_L, dphi_R, theta)
        return _to_sensor_scalar(body, body_jac, theta[3], theta[4], theta[5])

    def split(self, theta):
        theta = np.asarray(theta, dtype=float).reshape(-1)
        return Params(*theta[:3]), SensorPose(*theta[3:6])


class FixedSensorPoseModel(SegmentModel):
    """The sensor-pose model with the sensor at a known pose: 3 parameters r_L, r_R, b."""

    name = "fixed_sensor_pose"
    names = AxleModel.names
    units = AxleModel.units
    transforms = AxleModel.transforms

    def __init__(self, pose: SensorPose):
        self.pose = pose

    def evaluate(self, dphi_L, dphi_R, theta, jacobian=True, substeps=False):
        theta = np.asarray(theta, dtype=float)
        body, body_jac, turn = AXLE.evaluate_turning(dphi_L, dphi_R, theta, jacobian, substeps)
        prediction, jac = _to_sensor(body, body_jac, self.pose.as_array(), True, turn)
        return prediction, (None if jac is None else jac[:, :3])

    def evaluate_wheels(self, dphi_L, dphi_R, theta, substeps=False):
        return _wheels_to_sensor(dphi_L, dphi_R, np.asarray(theta, dtype=float),
                                 self.pose.as_array(), substeps)

    def evaluate_scalar(self, dphi_L, dphi_R, theta):
        body, body_jac = AXLE.evaluate_scalar(dphi_L, dphi_R, theta)
        prediction, rows = _to_sensor_scalar(body, body_jac, self.pose.x, self.pose.y,
                                             self.pose.theta)
        return prediction, tuple(row[:3] for row in rows)

    def split(self, theta):
        return Params(*np.asarray(theta, dtype=float).reshape(-1)[:3]), self.pose


def _to_sensor(body: FloatArray, body_jac: FloatArray | None, pose: FloatArray,
               single: bool, turn: tuple[FloatArray, FloatArray] | None = None
               ) -> tuple[FloatArray, FloatArray | None]:
    """The sensor's increment from the body's (3, ..., N) and its derivatives (3, 3, ..., N),
    for a sensor pose (..., 3); derivatives by (r_L, r_R, b, l_x, l_y, l_theta). turn:
    (sin, cos - 1) of the body's heading change when known, else computed here."""
    if single:
        l_x, l_y, l_t = (float(v) for v in pose)
    else:
        l_x, l_y, l_t = (pose[..., i, None] for i in range(3))
    o_x, o_y, th = body
    if turn is None:  # cos - 1 without cancellation
        turn = np.sin(th), -2.0 * np.sin(0.5 * th) ** 2
    sin_th, cos_m1 = turn
    u_x = o_x + cos_m1 * l_x - sin_th * l_y
    u_y = o_y + sin_th * l_x + cos_m1 * l_y
    c, s = np.cos(l_t), np.sin(l_t)
    prediction = np.empty_like(body, shape=(3,) + np.broadcast_shapes(u_x.shape, np.shape(c)))
    prediction[0] = c * u_x + s * u_y
    prediction[1] = c * u_y - s * u_x
    prediction[2] = th
    if body_jac is None:
        return prediction, None
    jac = np.empty((3, 6) + prediction.shape[1:])
    _body_to_sensor_derivatives(body_jac, sin_th, cos_m1, l_x, l_y, c, s, out=jac[:, :3])
    jac[0, 3], jac[1, 3] = c * cos_m1 + s * sin_th, c * sin_th - s * cos_m1  # by l_x
    jac[0, 4], jac[1, 4] = s * cos_m1 - c * sin_th, c * cos_m1 + s * sin_th  # by l_y
    jac[0, 5], jac[1, 5] = prediction[1], -prediction[0]  # by l_theta
    jac[2, 3:] = 0.0
    return prediction, jac


def _body_to_sensor_derivatives(body_jac: FloatArray, sin_th, cos_m1, l_x, l_y, c, s,
                                out: FloatArray | None = None) -> FloatArray:
    """Derivatives (3, Q, ...) of the sensor's increment from those of the body's (3, Q, ...)
    by Q quantities that move the body's arc (sin_th = sin(dtheta), cos_m1 = cos(dtheta) - 1,
    c, s = cos, sin of l_theta; all broadcast over the trailing axes): d u / d(dtheta) =
    dR/d(dtheta) l_xy, turned with each quantity's heading derivative; then R(-l_theta) of
    everything that moves u. out: where to write them (3, Q, ...), or None."""
    rot_x = -sin_th * l_x - (1.0 + cos_m1) * l_y
    rot_y = (1.0 + cos_m1) * l_x - sin_th * l_y
    du_x = body_jac[0] + rot_x * body_jac[2]
    du_y = body_jac[1] + rot_y * body_jac[2]
    if out is None:
        out = np.empty((3,) + np.broadcast_shapes(du_x.shape, np.shape(c)))
    np.multiply(c, du_x, out=out[0])
    out[0] += s * du_y
    np.multiply(c, du_y, out=out[1])
    out[1] -= s * du_x
    out[2] = body_jac[2]
    return out


def _wheels_to_sensor(dphi_L: ArrayLike, dphi_R: ArrayLike, wheels: FloatArray,
                      pose: FloatArray, substeps: bool) -> FloatArray:
    """The sensor-pose models' derivatives by the wheel (sub-)increments (3, 2, ..., N[, K]),
    for wheel parameters (..., 3) and a sensor pose (..., 3)."""
    body, _ = AXLE.evaluate(dphi_L, dphi_R, wheels, jacobian=False, substeps=substeps)
    body_jac = AXLE.evaluate_wheels(dphi_L, dphi_R, wheels, substeps)
    extra = (None,) * (1 + substeps)  # the trailing axes of the increments
    l_x, l_y, l_t = ((float(v) for v in pose) if pose.ndim == 1
                     else (pose[(..., i) + extra] for i in range(3)))
    th = body[2][..., None] if substeps else body[2]
    sin_th, cos_m1 = np.sin(th), -2.0 * np.sin(0.5 * th) ** 2
    return _body_to_sensor_derivatives(body_jac, sin_th, cos_m1, l_x, l_y, np.cos(l_t),
                                       np.sin(l_t))


def _to_sensor_scalar(body: tuple[float, float, float], body_jac: tuple[tuple[float, ...], ...],
                      l_x: float, l_y: float, l_t: float):
    """:func:`_to_sensor` of one segment in pure Python."""
    o_x, o_y, th = body
    half = math.sin(0.5 * th)
    sin_th, cos_m1 = math.sin(th), -2.0 * half * half
    u_x = o_x + cos_m1 * l_x - sin_th * l_y
    u_y = o_y + sin_th * l_x + cos_m1 * l_y
    c, s = math.cos(l_t), math.sin(l_t)
    s_x, s_y = c * u_x + s * u_y, c * u_y - s * u_x
    rot_x = -sin_th * l_x - (1.0 + cos_m1) * l_y
    rot_y = (1.0 + cos_m1) * l_x - sin_th * l_y
    jx, jy, jt = body_jac
    row_x, row_y = [], []
    for k in range(3):
        du_x, du_y = jx[k] + rot_x * jt[k], jy[k] + rot_y * jt[k]
        row_x.append(c * du_x + s * du_y)
        row_y.append(c * du_y - s * du_x)
    row_x += (c * cos_m1 + s * sin_th, s * cos_m1 - c * sin_th, s_y)
    row_y += (c * sin_th - s * cos_m1, c * cos_m1 + s * sin_th, -s_x)
    return (s_x, s_y, th), (tuple(row_x), tuple(row_y), (jt[0], jt[1], jt[2], 0.0, 0.0, 0.0))


AXLE = AxleModel()
SENSOR_POSE = SensorPoseModel()


def increment_jacobian(dphi_L: ArrayLike, dphi_R: ArrayLike,
                       params: Params | ArrayLike) -> FloatArray:
    """Jacobian d(dx, dy, dtheta)/d(r_L, r_R, b) of each segment, shape (N, 3, 3) (the axle
    model's). Rows: dx, dy, dtheta. Columns: r_L, r_R, b. Units: m/m for the position rows,
    rad/m for the heading row."""
    theta = params.as_array() if isinstance(params, Params) else np.asarray(params, float)
    return AXLE.jacobian(np.atleast_1d(np.asarray(dphi_L, dtype=float)),
                         np.atleast_1d(np.asarray(dphi_R, dtype=float)), theta.reshape(3))


def body_to_sensor(body: ArrayLike, pose: SensorPose | ArrayLike) -> FloatArray:
    """The sensor's increments s (N, 3) from the body's o (N, 3): s = (-l) (+) o (+) l, for
    one sensor pose l (SensorPose) or one per increment ((N, 3): x, y in m, theta in rad)."""
    body = np.asarray(body, dtype=float)
    if isinstance(pose, SensorPose):
        prediction, _ = _to_sensor(body.T, None, pose.as_array(), True)
        return prediction.T
    prediction, _ = _to_sensor(body.T[..., None], None, np.asarray(pose, dtype=float), False)
    return prediction[..., 0].T


def sensor_to_body(measured: ArrayLike, pose: SensorPose) -> FloatArray:
    """The body's increments o (N, 3) from the sensor's s (N, 3) for a known sensor pose:
    o = l (+) s (+) (-l), the inverse of the sensor-pose model's transform."""
    mount = pose.as_array()
    return se2.compose(se2.compose(mount, measured), se2.inverse(mount))


def single_arc_error(sub_dphi_L: ArrayLike, sub_dphi_R: ArrayLike,
                     params: Params) -> FloatArray:
    """How far one arc per segment (the segment's total wheel increments) misses the
    composition of its sub-steps (N, K): the position difference of the body's end pose (m,
    (N,)) at ``params``; 0 for segments of constant curvature."""
    theta = params.as_array()
    whole, _ = AXLE.evaluate(np.sum(sub_dphi_L, axis=-1), np.sum(sub_dphi_R, axis=-1), theta,
                             jacobian=False)
    composed, _ = AXLE.evaluate(sub_dphi_L, sub_dphi_R, theta, jacobian=False, substeps=True)
    return np.hypot(whole[0] - composed[0], whole[1] - composed[1])
