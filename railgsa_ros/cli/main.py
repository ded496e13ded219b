"""Entry point of ``railgsa``: discovers the subcommand modules and maps errors to exit codes.

RailGsaError -> ``error: <message>`` on stderr and exit code 2 (no traceback), also for a command
whose pip extra is not installed (cli/_extras.py); Ctrl-C -> 130;
an InputWarning (data skipped and counted) -> ``warning: <message>`` on stderr.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
import warnings

from railgsa_ros import __version__, cli
from railgsa_ros.cli._extras import check_extra
from railgsa_ros.errors import InputWarning, RailGsaError
from railgsa_ros.threads import limit_blas_threads

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  #: 128 + SIGPIPE, as a shell tool ended by ``| head``


def build_parser() -> argparse.ArgumentParser:
    """The ``railgsa`` parser with one subparser per module of ``railgsa_ros.cli``."""
    parser = argparse.ArgumentParser(
        prog='railgsa',
        description='Vertical track irregularity from car-body acceleration: simulation, '
                    'inversion, uncertainty and sensitivity.')
    parser.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    subparsers = parser.add_subparsers(title='commands', metavar='COMMAND', dest='command',
                                       required=True)
    for info in sorted(pkgutil.iter_modules(cli.__path__), key=lambda m: m.name):
        if info.name == 'main' or info.name.startswith('_'):
            continue
        module = importlib.import_module(f'{cli.__name__}.{info.name}')
        if hasattr(module, 'register'):
            module.register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``railgsa`` with ``argv`` (default: sys.argv[1:]); returns the exit code."""
    limit_blas_threads()
    with warnings.catch_warnings():
        show = warnings.showwarning
        warnings.showwarning = lambda message, category, *rest, **kw: print(
            f'warning: {message}', file=sys.stderr) if issubclass(category, InputWarning) \
            else show(message, category, *rest, **kw)
        warnings.simplefilter('always', InputWarning)
        try:
            args = build_parser().parse_args(argv)
            check_extra(args.command, args)
            return int(args.func(args) or 0)
        except RailGsaError as exc:
            print(f'error: {exc}', file=sys.stderr)
            return EXIT_USAGE
        except KeyboardInterrupt:
            return EXIT_INTERRUPTED
        except BrokenPipeError:  # the reader of our output left (``railgsa bode | head``)
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no flush error
            return EXIT_BROKEN_PIPE


if __name__ == '__main__':
    sys.exit(main())
