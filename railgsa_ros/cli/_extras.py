"""Which pip extra a command needs, and a one-line refusal when it is not installed.

The default install holds what the nodes need on a train; the offline commands that draw, store
or spread work import their libraries lazily, when they run (setup.py's extras). A command run
without its extra stops before any work with ``railgsa review needs the review extra: pip
install 'railgsa_ros[review]'`` (exit 2), not with a traceback.
"""

from __future__ import annotations

import argparse
import importlib.util

from railgsa_ros.errors import RailGsaError

#: extra -> the top-level modules of it that the commands import (setup.py's extras_require)
EXTRA_MODULES = {
    'review': ('matplotlib',),
    'fleet': ('matplotlib', 'duckdb', 'dask', 'distributed'),
}
#: command -> the extra it needs; ``(extra, option)`` when only that option needs it
COMMAND_EXTRAS: dict[str, tuple[str, str | None]] = {
    'review': ('review', None),
    'bode': ('review', None),
    'demo': ('review', None),
    'gsa': ('review', 'plot'),
    'fleet': ('fleet', None),
}


class MissingExtraError(RailGsaError):
    """A command needs a pip extra that is not installed."""

    def __init__(self, command: str, extra: str) -> None:
        super().__init__(f"railgsa {command} needs the {extra} extra: "
                         f"pip install 'railgsa_ros[{extra}]'")


def check_extra(command: str, args: argparse.Namespace) -> None:
    """Raise MissingExtraError when ``command`` with ``args`` needs an extra not installed
    (found without importing it: no command pays for a library it does not use)."""
    extra, option = COMMAND_EXTRAS.get(command, (None, None))
    if extra is None or (option is not None and not getattr(args, option, None)):
        return
    if any(importlib.util.find_spec(m) is None for m in EXTRA_MODULES[extra]):
        raise MissingExtraError(command, extra)
