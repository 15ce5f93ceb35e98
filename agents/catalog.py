"""The protocol registry and the protocol syntax: the one lookup ``compare``, ``tune`` and
``simulate`` use.

The registry maps a name to an entry point ``"module:Class"`` (like gymnasium's), imported only
when the protocol is used. A protocol is written ``NAME[:KEY=VALUE[:KEY=VALUE...]]`` where NAME
is a registered name or any ``module:Class`` entry point of a :class:`~agents.protocols.Protocol`
subclass, so a user's protocol plugs in without editing excite::

    umbmark:speed=0.2        mypkg.protocols:MyProtocol:gain=3        learned

A new protocol (e.g. a slip-aware planner) is one more registry entry, or a call of
:func:`register`. Like the protocols themselves, this module is light (numpy only).
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from agents.protocols import Protocol, ProtocolError, Value, check_action, resolve_settings
from excite.errors import one_line_repr
from excite.plugins import import_user_module

__all__ = ["PROTOCOLS", "ProtocolError", "ProtocolSpec", "register", "protocol_class",
           "parse_protocol", "parse_protocols", "check_distinct", "make_protocol", "with_policy",
           "default_protocols", "user_supplied", "calling", "Checked"]

#: The packages of excite's own code: errors raised there are excite's bugs, not bad input.
EXCITE_PACKAGES = ("agents", "excite", "envs")

#: Registered protocol names and their entry points, in the order they are listed and run.
PROTOCOLS: dict[str, str] = {
    "straight": "agents.protocols:Straight",
    "spin": "agents.protocols:Spin",
    "straight_spin": "agents.protocols:StraightSpin",
    "umbmark": "agents.protocols:UMBmark",
    "random": "agents.protocols:RandomCommands",
    "arcs": "agents.protocols:Arcs",
    "greedy": "agents.greedy:GreedyPlanner",
    "slip_aware": "agents.slip_aware:SlipAwarePlanner",
    "learned": "agents.learned:LearnedPolicy",
}


def register(name: str, entry_point: str) -> None:
    """Register protocol ``name`` (letters, digits, ``_``) as ``"module:Class"``; loaded on
    first use. Registering a taken name replaces it."""
    if not name.replace("_", "").isalnum():
        raise ProtocolError(f"protocol names are letters, digits and _, got {name!r}")
    if entry_point.count(":") != 1:
        raise ProtocolError(f"an entry point is module:Class, got {entry_point!r}")
    PROTOCOLS[name] = entry_point


def user_supplied(module_name: str) -> bool:
    """Whether a module is a user's (any error its code raises is bad input) rather than
    excite's own (an error there is a bug of excite, reported as such)."""
    return module_name.partition(".")[0] not in EXCITE_PACKAGES


def _through_user_code(exc: BaseException) -> bool:
    """Whether a user's module is on the exception's traceback (the user's code raised it,
    or called into excite's with what made it fail)."""
    tb = exc.__traceback__
    while tb is not None:
        if user_supplied(tb.tb_frame.f_globals.get("__name__", "")):
            return True
        tb = tb.tb_next
    return False


@contextmanager
def calling(label: str, what: str, user: bool) -> Iterator[None]:
    """Run a call into protocol ``label``'s code (``what``: the method): its ProtocolError
    names the protocol; any other exception does too, as a ProtocolError, when the protocol is
    a user's (``user``) and the user's code is on the traceback; otherwise (excite's own
    protocols, or excite's code failing under a user's subclass) it stays an internal error."""
    try:
        yield
    except ProtocolError as exc:
        raise ProtocolError(f"protocol {label}: {exc}") from None
    except Exception as exc:
        if not (user and _through_user_code(exc)):
            raise
        raise ProtocolError(f"protocol {label}: {what} raised {type(exc).__name__}: "
                            f"{exc}") from None


class Checked:
    """A protocol called as ``compare`` calls it, for a driver that calls ``reset`` and
    ``act`` itself (``excite live``): its errors name it (:func:`calling`) and every action
    is two finite numbers (:func:`agents.protocols.check_action`), never a NaN sent to a
    robot."""

    def __init__(self, protocol: Protocol, label: str) -> None:
        self.protocol, self.label = protocol, label
        self._user = user_supplied(type(protocol).__module__)

    def reset(self, rng: np.random.Generator) -> None:
        with calling(self.label, "reset", self._user):
            self.protocol.reset(rng)

    def act(self, knowledge) -> np.ndarray:
        with calling(self.label, "act", self._user):
            return check_action(self.protocol.act(knowledge))


def protocol_class(name: str) -> type[Protocol]:
    """The class of a registered name or of a ``module:Class`` entry point: a concrete
    Protocol subclass whose parameter defaults pass their own checks. A user's module that
    fails to import is a ProtocolError naming the exception."""
    entry_point = PROTOCOLS.get(name, name)
    if ":" not in entry_point:
        raise ProtocolError(f"unknown protocol {name!r}; choose from {', '.join(PROTOCOLS)} "
                            "or give module:Class")
    module_name, _, attribute = entry_point.partition(":")
    try:
        module = import_user_module(module_name)
    except Exception as exc:
        if (isinstance(exc, ModuleNotFoundError) and exc.name is not None
                and module_name.startswith(exc.name)):
            raise ProtocolError(f"protocol {name!r}: no module named {exc.name!r}") from None
        if not user_supplied(module_name):
            raise  # excite's own (a module it needs is missing: cli names the extra)
        raise ProtocolError(f"protocol {name!r}: importing {module_name} raised "
                            f"{type(exc).__name__}: {exc}") from None
    cls = getattr(module, attribute, None)
    if not (isinstance(cls, type) and issubclass(cls, Protocol)):
        raise ProtocolError(f"protocol {name!r}: {module_name} has no Protocol subclass "
                            f"named {attribute!r}")
    if inspect.isabstract(cls):
        raise ProtocolError(f"protocol {name!r}: {attribute} is abstract (it does not "
                            f"implement {', '.join(sorted(cls.__abstractmethods__))})")
    for parameter in cls.parameters:
        try:
            parameter.check(parameter.default)
        except ProtocolError as exc:
            raise ProtocolError(f"protocol {name!r}: the default of its parameter "
                                f"{parameter.name} is invalid: {exc}") from None
    return cls


@dataclass(frozen=True)
class ProtocolSpec:
    """A protocol with settings: ``name`` (registered, or ``module:Class``) and the settings
    given explicitly, in the order the class declares them (the others keep their defaults).
    ``label`` writes it back in the command-line syntax; it names the protocol in results."""

    name: str
    settings: tuple[tuple[str, Value], ...] = ()

    @classmethod
    def of(cls, name: str, settings: Mapping[str, object] | None = None) -> ProtocolSpec:
        """The spec of ``name`` with ``settings`` checked against its declared parameters."""
        protocol = protocol_class(name)
        given = dict(settings or {})
        checked = resolve_settings(protocol, given)
        return cls(name, tuple((p.name, checked[p.name]) for p in protocol.parameters
                               if p.name in given))

    @property
    def protocol(self) -> type[Protocol]:
        return protocol_class(self.name)

    @property
    def label(self) -> str:
        formats = {p.name: p.format for p in self.protocol.parameters}
        return ":".join([self.name, *(f"{k}={formats[k](v)}" for k, v in self.settings)])

    def resolved(self) -> dict[str, Value]:
        """Every declared parameter with the value this spec runs with."""
        return resolve_settings(self.protocol, dict(self.settings))

    def under(self, defaults: Mapping[str, object]) -> ProtocolSpec:
        """This spec with ``defaults`` added for the keys it does not set (its own settings
        win); keys the protocol does not declare are errors."""
        return ProtocolSpec.of(self.name, {**defaults, **dict(self.settings)})

    def fingerprint(self) -> str | None:
        """A digest of the files this spec's settings name (a policy file), or None."""
        with calling(self.label, "fingerprint", user_supplied(self.protocol.__module__)):
            digest = self.protocol.fingerprint(self.resolved())
        if digest is not None and not isinstance(digest, str):
            raise ProtocolError(f"protocol {self.label}: fingerprint returned "
                                f"{one_line_repr(digest)}, not a str or None")
        return digest

    def declares(self, key: str) -> bool:
        return any(p.name == key for p in self.protocol.parameters)


def parse_protocol(text: str) -> ProtocolSpec:
    """``NAME[:KEY=VALUE...]`` as a checked spec; NAME is a registered name, else
    ``module:Class``."""
    parts = [part.strip() for part in text.strip().split(":")]
    entry_point = parts[0] not in PROTOCOLS and len(parts) > 1 and "=" not in parts[1]
    first_setting = 2 if entry_point else 1
    name = ":".join(parts[:first_setting])
    if not name:
        raise ProtocolError(f"a protocol needs a name before its settings, got {text!r}")
    protocol = protocol_class(name)
    declared = {p.name: p for p in protocol.parameters}
    settings: dict[str, Value] = {}
    for part in parts[first_setting:]:
        key, equals, value = part.partition("=")
        key = key.strip()
        if not equals:
            raise ProtocolError(f"{name}: settings are KEY=VALUE, got {part!r}")
        if key not in declared:
            known = ", ".join(declared) or "none"
            raise ProtocolError(f"{name} has no parameter {key!r} (its parameters: {known}; "
                                "see excite protocols)")
        if key in settings:
            raise ProtocolError(f"{name}: {key} is set twice in {text!r}")
        try:
            settings[key] = declared[key].parse(value.strip())
        except ProtocolError as exc:
            raise ProtocolError(f"{name}: {exc}") from None
    return ProtocolSpec.of(name, settings)


def check_distinct(specs: Iterable[ProtocolSpec]) -> list[ProtocolSpec]:
    """``specs`` as a list, or ProtocolError if two of them run the same protocol with the
    same settings (e.g. ``umbmark`` and ``umbmark:speed=0.5``, its default)."""
    specs = list(specs)
    seen: dict[tuple, str] = {}
    for spec in specs:
        key = (spec.protocol, tuple(spec.resolved().items()))
        if key in seen:
            raise ProtocolError(f"protocols must be distinct: {seen[key]} and {spec.label} "
                                "are the same protocol with the same settings")
        seen[key] = spec.label
    return specs


def parse_protocols(text: str) -> list[ProtocolSpec]:
    """Comma-separated protocols (``a,b:key=value,...``), each distinct."""
    parts = text.split(",")
    if not all(part.strip() for part in parts):
        raise ProtocolError(f"protocols {text!r}: empty name in the list")
    return check_distinct(parse_protocol(part) for part in parts)


def make_protocol(spec: str | ProtocolSpec) -> Protocol:
    """Build a protocol from its spec (or its text, ``NAME[:KEY=VALUE...]``)."""
    spec = parse_protocol(spec) if isinstance(spec, str) else spec
    settings = spec.resolved()
    user = user_supplied(spec.protocol.__module__)
    with calling(spec.label, "unavailable", user):
        reason = spec.protocol.unavailable(settings)
    if reason:
        raise ProtocolError(reason)
    with calling(spec.label, "__init__", user):
        return spec.protocol(**settings)


def with_policy(specs: Iterable[ProtocolSpec], policy: str | None) -> list[ProtocolSpec]:
    """``specs`` with ``policy`` (``--policy PATH``) as the ``policy`` setting of each that
    declares one and does not set it; unchanged when ``policy`` is None. ProtocolError when
    none declares one (the policy would be silently ignored)."""
    specs = list(specs)
    if not policy:
        return specs
    if not any(spec.declares("policy") for spec in specs):
        raise ProtocolError(f"--policy {policy}: none of the protocols ("
                            f"{', '.join(spec.label for spec in specs)}) takes a policy; add "
                            "learned to them or leave --policy out")
    return [spec.under({"policy": policy}) if spec.declares("policy") else spec
            for spec in specs]


def default_protocols(policy: str | None = None) -> list[ProtocolSpec]:
    """Every registered protocol that can be built here (``learned`` only if a policy is
    shipped or given), with ``policy`` as in :func:`with_policy`."""
    specs = with_policy((ProtocolSpec(name) for name in PROTOCOLS), policy)
    return [spec for spec in specs if spec.protocol.unavailable(spec.resolved()) is None]
