"""Users' own code named on the command line as ``module:Name`` (protocols, estimators): the
module is imported as ``python -m`` would see it, from the working folder too.

The ``excite`` command, installed as a console script, does not put the working folder on
``sys.path`` the way ``python -m excite.cli`` does; ``cd examples; excite compare --protocols
custom_protocol:Sweep`` must find ``custom_protocol.py`` there all the same. The folder goes
last on the path, so that it never shadows an installed package, and only while the module
is imported.
"""

from __future__ import annotations

import importlib
import os
import sys
from types import ModuleType

__all__ = ["import_user_module"]


def import_user_module(name: str) -> ModuleType:
    """The module ``name``, searched on ``sys.path`` and then in the working folder (on the
    path for this import only: a folder there named like an optional package, a
    ``tensorboard/`` of logs, must not stand in for it later)."""
    here = os.getcwd()
    if here in sys.path or "" in sys.path:
        return importlib.import_module(name)
    sys.path.append(here)
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(here)
