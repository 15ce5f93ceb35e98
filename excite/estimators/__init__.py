"""Online estimators by name, for the environment's loop and the comparison (numpy/scipy
only: no gymnasium or pymunk).

Every estimator follows one protocol (:class:`excite.contracts.Estimator`):
``update(dphi_L, dphi_R, dx, dy, dtheta)`` after each segment, then ``params`` (Params) and
``covariance``; an estimator of the sensor pose adds ``theta`` (all P parameters). The
built-ins:

* ``online``: :class:`excite.OnlineEstimator`, the iterated information filter on
  log-parameters (the environment's default);
* ``ekf``: :class:`~excite.estimators.ekf.ExtendedKalmanFilter`, the textbook EKF on the
  parameters themselves;
* ``window``: :class:`~excite.estimators.window.SlidingWindowSmoother`, Gauss–Newton over
  the last W segments with the older ones marginalised into the prior.

A spec names one: a built-in with optional ``:key=value`` settings (``window:size=20``,
``ekf:prior_std=0.01``; the keys are those of :data:`OPTIONS`), or ``module:factory``, a
callable ``factory(nominal, sigma) -> estimator`` importable from ``module``
(:data:`excite.contracts.EstimatorFactory`, the environment's ``estimator_factory``:
nominal is Params on the axle model and the six sensor-pose parameters when the sensor pose
is estimated; sigma (sigma_x [m], sigma_y [m], sigma_theta [rad])).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from excite.contracts import Estimator
from excite.core.kinematics import Params
from excite.core.models import AXLE, SENSOR_POSE, SegmentModel
from excite.errors import EstimatorError, one_line_repr
from excite.estimators.ekf import ExtendedKalmanFilter
from excite.estimators.online import OnlineEstimator
from excite.estimators.window import SlidingWindowSmoother
from excite.plugins import import_user_module

__all__ = [
    "DEFAULT_ESTIMATOR",
    "ESTIMATORS",
    "OPTIONS",
    "CheckedEstimator",
    "check_contract",
    "EstimatorSpec",
    "check_distinct",
    "ExtendedKalmanFilter",
    "SlidingWindowSmoother",
    "estimator_factory",
    "make_estimator",
    "model_for",
    "parse_estimators",
]


#: The built-in estimators by name; each is constructed as cls(nominal, sigma=..., model=...).
ESTIMATORS: dict[str, type] = {
    "online": OnlineEstimator,
    "ekf": ExtendedKalmanFilter,
    "window": SlidingWindowSmoother,
}
#: The estimator of a comparison given none (the environment's default).
DEFAULT_ESTIMATOR = "online"
#: The settings a built-in takes in its spec (``name:key=value``): keyword arguments of its
#: constructor.
OPTIONS: dict[str, tuple[str, ...]] = {
    "online": ("prior_std", "iterations"),
    "ekf": ("prior_std",),
    "window": ("prior_std", "size", "iterations"),
}


def model_for(nominal: Params | ArrayLike) -> SegmentModel:
    """The segment model of a nominal parameter set: the axle model for Params or 3 values,
    the sensor-pose model for 6."""
    size = 3 if isinstance(nominal, Params) else np.size(nominal)
    for model in (AXLE, SENSOR_POSE):
        if size == model.size:
            return model
    raise EstimatorError(f"nominal must have 3 (axle) or 6 (sensor pose) parameters, "
                         f"got {size}")


def _number(text: str) -> int | float:
    """A setting's value: an int when it reads as one, else a float."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    raise EstimatorError(f"estimator setting value {text!r} is not a number")


@dataclass(frozen=True)
class EstimatorSpec:
    """A parsed estimator spec, callable as ``factory(nominal, sigma)`` (picklable: a
    ``module:factory`` is re-imported where it is called). Make one with
    :func:`estimator_factory`.

    name: the built-in's name, or ``module:factory``; settings: the built-in's keyword
    arguments as (key, value) pairs.
    """

    name: str
    settings: tuple[tuple[str, int | float], ...] = ()

    @property
    def label(self) -> str:
        """The spec written back (``window:size=20``, ``mypkg.est:factory``); it names the
        estimator in results."""
        return self.name + "".join(f":{key}={value}" for key, value in self.settings)

    def __call__(self, nominal: Params | ArrayLike, sigma: ArrayLike) -> Estimator:
        if self.name in ESTIMATORS:
            return ESTIMATORS[self.name](nominal, sigma=sigma, model=model_for(nominal),
                                         **dict(self.settings))
        factory = _import_factory(self.name)
        try:
            estimator = factory(nominal, sigma)
        except Exception as exc:  # a user's code: any failure is bad input, named
            raise EstimatorError(f"estimator {self.label}: its factory raised "
                                 f"{type(exc).__name__}: {exc}") from None
        return CheckedEstimator(self.label, estimator)


def check_contract(label: str, estimator: object) -> None:
    """EstimatorError (one line, naming the estimator ``label``) unless ``estimator`` has
    ``update``, ``params`` and ``covariance`` and its ``update`` takes the segment's five
    positional values (a signature that cannot be read is left to the call)."""
    missing = [name for name in ("update", "params", "covariance")
               if not hasattr(estimator, name)]
    if missing:
        raise EstimatorError(f"estimator {label}: its factory returned "
                             f"{one_line_repr(estimator)}, not an estimator (it has no "
                             f"{', '.join(missing)})")
    update = estimator.update  # type: ignore[attr-defined]
    try:
        signature = inspect.signature(update)
    except TypeError:  # not callable
        raise EstimatorError(f"estimator {label}: its update is "
                             f"{one_line_repr(update)}, not a method") from None
    except ValueError:  # callable without a readable signature (a builtin)
        return
    try:
        signature.bind(0.0, 0.0, 0.0, 0.0, 0.0)
    except TypeError:
        raise EstimatorError(f"estimator {label}: its update{signature} does not take "
                             "the segment's five values update(dphi_L, dphi_R, dx, dy, "
                             "dtheta) (rad, rad, m, m, rad)") from None


class CheckedEstimator:
    """A user's estimator (``module:factory``) checked against the protocol
    (:class:`excite.contracts.Estimator`) when wrapped and at every call: an object without
    ``update``, ``params`` or ``covariance``, an ``update`` that does not take the segment's
    five values, an exception in ``update`` or in reading ``params``, ``covariance`` or
    ``theta``, params that are not 3 finite values, or a covariance that is not a finite
    square matrix is an EstimatorError naming the estimator (``label``), not a failure deep
    inside the environment. The user's object is ``estimator``; its other attributes read
    through."""

    def __init__(self, label: str, estimator: Estimator) -> None:
        self.label, self.estimator = label, estimator
        check_contract(label, estimator)

    def __getattr__(self, name: str) -> object:
        """Any other attribute is the user's estimator's (``n_segments``, ...)."""
        if name == "estimator":  # not set yet (unpickling): no endless recursion
            raise AttributeError(name)
        return getattr(self.estimator, name)

    def _call(self, what: str, function: Callable[[], object]) -> object:
        try:
            return function()
        except Exception as exc:
            raise EstimatorError(f"estimator {self.label}: {what} raised "
                                 f"{type(exc).__name__}: {exc}") from None

    def update(self, dphi_L: float, dphi_R: float, dx: float, dy: float,
               dtheta: float) -> None:
        self._call("update", lambda: self.estimator.update(dphi_L, dphi_R, dx, dy, dtheta))

    @property
    def params(self) -> Params:
        value = self._call("params", lambda: self.estimator.params)
        array = self._call("params", lambda: np.asarray(
            value.as_array() if isinstance(value, Params) else value, dtype=float))
        if array.shape != (3,) or not np.isfinite(array).all():
            raise EstimatorError(f"estimator {self.label}: params is {one_line_repr(value)}, not 3 "
                                 "finite values (r_L, r_R, b in m)")
        return value if isinstance(value, Params) else Params.from_array(array)

    @property
    def covariance(self) -> np.ndarray:
        value = self._call("covariance", lambda: self.estimator.covariance)
        array = self._call("covariance", lambda: np.asarray(value, dtype=float))
        if array.ndim != 2 or array.shape[0] != array.shape[1] or array.shape[0] < 3 or (
                not np.isfinite(array).all()):
            raise EstimatorError(f"estimator {self.label}: covariance is {one_line_repr(value)}, "
                                 "not a finite square matrix over at least the 3 wheel "
                                 "parameters")
        return array

    @property
    def theta(self) -> np.ndarray | None:
        """The estimator's ``theta`` (all model parameters), None when it has none."""
        value = self._call("theta", lambda: getattr(self.estimator, "theta", None))
        if value is None:
            return None
        array = self._call("theta", lambda: np.asarray(value, dtype=float))
        if array.ndim != 1 or not np.isfinite(array).all():
            raise EstimatorError(f"estimator {self.label}: theta is {one_line_repr(value)}, not "
                                 "finite values")
        return array


def _import_factory(spec: str) -> Callable[..., Estimator]:
    """The callable ``factory`` of ``module:factory`` (attribute paths may be dotted)."""
    module_name, _, path = spec.partition(":")
    try:
        target = import_user_module(module_name)
    except Exception as exc:  # a user's module (built-ins are never imported here)
        raise EstimatorError(f"estimator {spec!r}: cannot import module {module_name!r} "
                             f"({type(exc).__name__}: {exc})") from None
    for attribute in path.split("."):
        if not hasattr(target, attribute):
            raise EstimatorError(f"estimator {spec!r}: module {module_name!r} has no "
                                 f"{path!r}")
        target = getattr(target, attribute)
    if not callable(target):
        raise EstimatorError(f"estimator {spec!r}: {path!r} is not callable")
    return target


def estimator_factory(spec: str) -> EstimatorSpec:
    """The factory(nominal, sigma) of a spec (module doc): ``online``, ``ekf``, ``window``,
    a built-in with settings (``window:size=20:iterations=5``) or ``module:factory``.
    Raises EstimatorError (one line) for an unknown name or setting or a factory that does
    not import."""
    name, _, rest = spec.strip().partition(":")
    if name in ESTIMATORS:
        settings = []
        for item in filter(None, rest.split(":")):
            key, equals, value = item.partition("=")
            if not equals or key not in OPTIONS[name]:
                raise EstimatorError(f"estimator {spec!r}: {item!r} is not a setting of "
                                     f"{name!r} (known: {', '.join(OPTIONS[name])}, as "
                                     f"key=value)")
            settings.append((key, _number(value)))
        return EstimatorSpec(name, tuple(settings))
    if not rest:
        raise EstimatorError(f"unknown estimator {spec!r}; known: {', '.join(ESTIMATORS)}, "
                             "or module:factory")
    _import_factory(spec.strip())
    return EstimatorSpec(spec.strip())


def make_estimator(spec: str, nominal: Params | ArrayLike, sigma: ArrayLike) -> Estimator:
    """A fresh estimator of a spec (see :func:`estimator_factory`) started at ``nominal``
    (Params, or the model's parameters) with measurement noise ``sigma`` (sigma_x [m],
    sigma_y [m], sigma_theta [rad])."""
    return estimator_factory(spec)(nominal, sigma)


def parse_estimators(text: str) -> list[EstimatorSpec]:
    """The specs of a comma-separated list (``online,ekf,window:size=20,mypkg.est:factory``),
    each checked by :func:`estimator_factory`; EstimatorError (one line) for an empty item or
    a spec given twice."""
    items = text.split(",")
    if not all(item.strip() for item in items):
        raise EstimatorError(f"estimators {text!r}: empty name in the list")
    return check_distinct([estimator_factory(item) for item in items])


def check_distinct(specs: list[EstimatorSpec]) -> list[EstimatorSpec]:
    """``specs`` if there is at least one and no label appears twice, else EstimatorError."""
    if not specs:
        raise EstimatorError("no estimator given")
    seen: set[str] = set()
    for spec in specs:
        if spec.label in seen:
            raise EstimatorError(f"estimators must be distinct: {spec.label} is given twice")
        seen.add(spec.label)
    return specs
