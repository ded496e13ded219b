"""What the benchmark scripts share: Markdown table headers and the run options."""

from __future__ import annotations

import argparse


def header(*columns: str) -> None:
    """Print a Markdown table header: the column names, then the separator row."""
    print('| ' + ' | '.join(columns) + ' |')
    print('|' + '---|' * len(columns))


def run_options(doc: str, length_m: float) -> argparse.ArgumentParser:
    """A parser described by the first line of ``doc`` with ``--length`` (track length, m) and
    ``--seed``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument('--length', type=float, default=length_m, help='track length, m')
    parser.add_argument('--seed', type=int, default=1)
    return parser
