"""Users' own code named on the command line as ``module:Name`` (protocols, estimators): the
module is imported as ``python -m`` would see it, from the working folder too.

The ``excite`` command, installed as a console script, does not put the working folder on
``sys.path`` the way ``python -m excite.cli`` does; ``cd examples; excite compare --protocols
custom_protocol:Sweep`` must find ``custom_protocol.py`` there all the same. The folder goes
last on the path, so that it never shadows an installed package.
"""

from __future__ import annotations

import importlib
import os
import sys
from types import ModuleType

__all__ = ["import_user_module"]


def import_user_module(name: str) -> ModuleType:
    """The module ``name``, searched on ``sys.path`` and then in the working folder."""
    here = os.getcwd()
    if here not in sys.path and "" not in sys.path:
        sys.path.append(here)
    return importlib.import_module(name)
