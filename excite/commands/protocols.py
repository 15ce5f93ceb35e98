"""``excite protocols``: the registered protocols, their parameters, defaults and ranges."""

from __future__ import annotations

import argparse
import re

from excite.commands.args import UsageError
from excite.commands.exit_status import EXIT_OK

SYNTAX = ("Write a protocol NAME[:KEY=VALUE...] (e.g. umbmark:speed=0.2), a user's protocol "
          "module:Class[:KEY=VALUE...];\nexcite tune tries the values of the parameters "
          "marked tuned.")
HEADERS = ("parameter", "type", "default", "range", "tuned", "meaning")


def _summary(doc: str | None) -> str:
    """The first sentence of a docstring, on one line."""
    text = " ".join((doc or "").split())
    match = re.match(r"(.+?\.)(?=\s+[A-Z`]|$)", text)
    return match.group(1) if match else text


def run(args: argparse.Namespace) -> int:
    from agents.catalog import PROTOCOLS, protocol_class

    names = args.names or list(PROTOCOLS)
    for name in names:
        registered = name.partition(":")[0]
        if ":" in name and registered in PROTOCOLS:
            raise UsageError(f"{name}: excite protocols takes a name ({registered}) or a "
                             "user's module:Class; settings (NAME:KEY=VALUE) go where a "
                             "protocol runs (compare, simulate, live)")
    classes = {name: protocol_class(name) for name in names}
    rows = {name: [(p.name, p.kind.__name__, p.format(p.default) or '""',
                    f"[{p.format(p.low)}, {p.format(p.high)}]" if p.low is not None else "",
                    f"{len(p.tuning_values())} values" if p.grid else "", p.meaning)
                   for p in cls.parameters] for name, cls in classes.items()}
    every = [HEADERS, *(row for group in rows.values() for row in group)]
    widths = [max(len(row[i]) for row in every) for i in range(len(HEADERS) - 1)]

    def line(cells: tuple[str, ...]) -> str:
        return "    " + "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=False))

    for name, cls in classes.items():
        print(f"{name}  ({PROTOCOLS.get(name, name)}): {_summary(cls.__doc__)}")
        print(line(HEADERS) + "  " + HEADERS[-1])
        for row in rows[name]:
            print(line(row) + "  " + row[-1])
    print(f"\n{SYNTAX}")
    return EXIT_OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    prot = sub.add_parser("protocols", help="list the protocols and their parameters",
                          description="Describe calibration protocols: each parameter's type, "
                          "default, range, whether excite tune tunes it, and its meaning.")
    prot.add_argument("names", nargs="*", metavar="NAME",
                      help="protocols to describe: registered names (%(protocols)s) or a "
                      "user's module:Class; default: every registered protocol")
    prot.set_defaults(handler=run)
