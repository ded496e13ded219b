"""``railgsa record``: record topics into a rosbag2 MCAP bag (the recorder node)."""

from __future__ import annotations

import argparse
import threading

from railgsa_ros.playback.signals import stop_on_signals


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``record`` subcommand."""
    p = subparsers.add_parser(
        'record', help='record topics into a rosbag2 MCAP bag',
        description='Record topics as raw CDR into a rosbag2 bag directory OUT (OUT_0.mcap, '
                    '... and metadata.yaml, readable by ros2 bag and rosbags) until --duration '
                    'or Ctrl-C / SIGTERM, which finish the bag cleanly.')
    p.add_argument('--out', '-o', required=True, metavar='OUT',
                   help='bag directory to create (must not exist)')
    p.add_argument('--topics', nargs='+', required=True, metavar='T', help='topics to record')
    p.add_argument('--duration', type=float, default=0.0, metavar='S',
                   help='stop after S seconds (default: until interrupted)')
    p.add_argument('--split', type=float, default=60.0, metavar='S',
                   help='start a new storage file every S seconds (default 60); a crash or full '
                   'disk loses at most the file in progress')
    p.add_argument('--no-compress', dest='compress', action='store_false',
                   help='write uncompressed MCAP chunks (default zstd)')
    p.add_argument('--depth', type=int, default=0, metavar='N',
                   help='reader history per topic, messages (default 0: KEEP_ALL, a RELIABLE '
                   'publisher resends what the recorder had no room for, nothing is lost); N > 0: '
                   'KEEP_LAST N, the oldest unwritten messages are overwritten in a burst')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Record; 0 when finished or interrupted (RailGsaError -> exit 2 in the caller)."""
    stop = threading.Event()  # a signal during the imports below stops cleanly too
    with stop_on_signals(stop):
        from railgsa_ros.nodes import recorder

        values = {'out': args.out, 'duration': args.duration, 'split': args.split,
                  'compress': args.compress, 'topics': args.topics, 'depth': args.depth}
        return recorder.run(args=[], parameters=values, stop=stop)
