"""The argument parser of ``excite`` and its subcommands: usage errors as one line, and help
texts that name what a registry holds.

A help text may contain a field that :class:`HelpFormatter` fills in only when help is shown:
``%(protocols)s`` (the names of :data:`agents.catalog.PROTOCOLS`) and ``%(robot_presets)s``
(the names of :data:`envs.robot.PRESETS`). Those registries live outside excite's core, so
building the parser (``excite --version``, every command) never imports them; both modules are
light (numpy), so ``excite COMMAND --help`` imports no gymnasium, pymunk or torch. Registries in
excite's core (environment ids, estimators) are named directly in the help texts.
"""

from __future__ import annotations

import argparse
import re
import textwrap
from collections.abc import Callable

from excite.commands.args import UsageError

__all__ = ["Parser", "HelpFormatter", "CommandsHelpFormatter", "FIELDS"]


def _protocol_names() -> str:
    from agents.catalog import PROTOCOLS

    return ", ".join(PROTOCOLS)


def _robot_presets() -> str:
    from envs.robot import PRESETS

    return ", ".join(PRESETS)


#: The help-text fields and the names each stands for, looked up when help is shown.
FIELDS: dict[str, Callable[[], str]] = {"protocols": _protocol_names,
                                        "robot_presets": _robot_presets}


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, with the :data:`FIELDS` of a help text filled in, and lines
    broken at spaces only (never inside a name such as excite/DiffDriveCalib-v0)."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return textwrap.fill(" ".join(text.split()), width, initial_indent=indent,
                             subsequent_indent=indent, break_on_hyphens=False)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = super()._get_help_string(action) or ""
        for field, names in FIELDS.items():
            if f"%({field})s" in text:
                text = text.replace(f"%({field})s", names())
        return text


class CommandsHelpFormatter(argparse.RawDescriptionHelpFormatter):
    """The formatter of ``excite --help``: description and epilog as written (wrapped by the
    caller), each command's name and one-line help in two columns."""

    def add_argument(self, action: argparse.Action) -> None:
        super().add_argument(action)
        names = [self._format_action_invocation(a) for a in self._iter_indented_subactions(action)]
        if names and action.help is not argparse.SUPPRESS:  # argparse measures the commands
            # at their group's indent, though it shows them two columns further in
            self._action_max_length = max(self._action_max_length,
                                          max(map(len, names)) + self._current_indent + 2)


#: A value of numbers that starts with a minus sign (``--area -2,-2,2,2``, ``--sensor-pose
#: -0.1,0,0``, ``--time-offset -1e-3``): argparse takes it for an unknown option unless it is
#: one plain number.
_NEGATIVE_NUMBERS = re.compile(
    r"^-(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?:,\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)*$")


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (UsageError, exit status 2), whose help
    is formatted by :class:`HelpFormatter` unless told otherwise, and whose positional
    arguments may come between options (``excite calibrate a.bag --left-wheel l b.bag``:
    argparse's intermixed parsing, in a command's parser; the top parser's command comes
    first)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self._intermixing = False

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        if self._subparsers is not None or self._intermixing:
            return super().parse_known_args(args, namespace)
        self._intermixing = True  # parse_known_intermixed_args calls this method back
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._intermixing = False

    def _parse_optional(self, arg_string):  # type: ignore[override]
        """A value of numbers with a leading minus sign is a value, not an option."""
        if _NEGATIVE_NUMBERS.match(arg_string):
            return None
        return super()._parse_optional(arg_string)

    def error(self, message: str):  # one line, no usage dump
        raise UsageError(message)
