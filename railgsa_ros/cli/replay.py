"""``railgsa replay``: play a rosbag2 bag into ROS 2 with its recorded timing (bag_replay_node)."""

from __future__ import annotations

import argparse
import threading

from railgsa_ros.playback.signals import stop_on_signals
from railgsa_ros.playback.waiting import WAIT_S

DEFAULT_CLOCK_HZ = 40.0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``replay`` subcommand (argument names as ``ros2 bag play``)."""
    p = subparsers.add_parser(
        'replay', help='play a rosbag2 bag (MCAP or sqlite3) with its original timing',
        description='Publish the messages of a rosbag2 bag (directory, .mcap or .db3; MCAP '
                    'chunks plain, zstd or lz4) with the recorded inter-message timing, as raw '
                    'CDR. Exits when the bag is played (never with --loop).')
    p.add_argument('bag', metavar='BAG', help='bag directory, .mcap or .db3 file')
    p.add_argument('-r', '--rate', type=float, default=1.0, metavar='R',
                   help='playback rate, x real time (default 1)')
    p.add_argument('-l', '--loop', action='store_true', help='replay forever')
    p.add_argument('--start', '--start-offset', dest='start', type=float, default=0.0,
                   metavar='S', help='skip the first S seconds of the bag (default 0)')
    p.add_argument('-d', '--duration', '--playback-duration', dest='duration', type=float,
                   default=0.0, metavar='D', help='play D seconds of bag time (default: all)')
    p.add_argument('--topics', nargs='+', default=[], metavar='T',
                   help='topics to play (default: all)')
    p.add_argument('-m', '--remap', nargs='+', action='extend', default=[], metavar='FROM:=TO',
                   help='publish topic FROM as TO')
    p.add_argument('--clock', nargs='?', type=float, const=DEFAULT_CLOCK_HZ, default=0.0,
                   metavar='HZ', help='publish /clock at HZ of wall time for use_sim_time '
                   f'(default {DEFAULT_CLOCK_HZ:g} Hz when given)')
    wait = p.add_mutually_exclusive_group()
    wait.add_argument('--wait-timeout', '--wait-for-subscribers', dest='wait_timeout',
                      type=float, default=WAIT_S, metavar='S',
                      help='before playing, wait up to S seconds until every topic has '
                      '--min-subscribers and every subscriber already in the ROS graph is '
                      f'matched, so that none misses the first messages (default {WAIT_S:g})')
    wait.add_argument('--no-wait', dest='wait_timeout', action='store_const', const=0.0,
                      help='play at once, without waiting for subscribers')
    p.add_argument('--min-subscribers', type=int, default=1, metavar='N',
                   help='wait for N subscribers on every played topic (default 1)')
    p.add_argument('--reliable', action='store_true',
                   help='publish every topic RELIABLE with a history of 10 s at the replay rate '
                   '(for faster-than-real-time replays into reliable subscribers)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Play the bag; 0 when done or interrupted (RailGsaError -> exit 2 in the caller)."""
    stop = threading.Event()  # a signal during the imports below stops cleanly too
    with stop_on_signals(stop):
        from railgsa_ros.nodes import bag_replay_node

        values = {'bag_path': args.bag, 'rate': args.rate, 'loop': args.loop,
                  'start_offset': args.start, 'duration': args.duration, 'clock_hz': args.clock,
                  'wait_for_subscribers': args.wait_timeout,
                  'min_subscribers': args.min_subscribers, 'reliable': args.reliable}
        values.update({k: v for k, v in (('topics', args.topics), ('remaps', args.remap)) if v})
        return bag_replay_node.run(args=[], parameters=values, stop=stop)
