"""``railgsa recover``: rewrite a bag cut short by a killed recorder into a readable one."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``recover`` subcommand."""
    p = subparsers.add_parser(
        'recover', help='make a recording cut short (SIGKILL, power cut) readable again',
        description='Rewrite every unfinished MCAP file of the bag directory BAG (no footer: '
                    'its recorder was killed) from its complete records, up to about its last '
                    'second with railgsa record, keeping the original as NAME.mcap.orig, and '
                    'write metadata.yaml for all files. Finished files are left alone; '
                    'empty and unreadable files are set aside as NAME.mcap.orig and counted.')
    p.add_argument('bag', metavar='BAG', help='bag directory (or a bare .mcap file)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Recover and print one line per file."""
    from railgsa_ros.playback.recover import recover_bag

    reports = recover_bag(args.bag)
    for r in reports:
        extra = ''.join([f', {r.bad_chunks} damaged chunk(s) dropped' if r.bad_chunks else '',
                         f', {r.cut_bytes} bytes after the cut' if r.cut_bytes else ''])
        if r.status in ('empty', 'unreadable'):
            why = f' ({r.reason})' if r.reason else ''
            print(f'{r.name}: {r.status}{why}{extra}; set aside as {r.name}.orig')
        else:
            print(f'{r.name}: {r.status}, {r.messages} messages{extra}')
    skipped = [r.name for r in reports if r.status in ('empty', 'unreadable')]
    if skipped:
        print(f'{len(skipped)} of {len(reports)} files skipped (empty or unreadable): '
              f'{", ".join(skipped)}; the other files are readable')
    return 0
