"""``railgsa demo``: the main job end to end on simulated data, outputs in one directory.

Simulate a bag, start irregularity_node and uncertainty_node as processes, replay the bag into
them, record their outputs, review the bag offline and print where the report is with a short
summary. Every process runs with localhost discovery in the ROS domain of ``ROS_DOMAIN_ID`` (when
it is unset: a domain reserved for the demo, ``system.session_domain``) and is stopped (SIGINT,
then SIGTERM, then SIGKILL) when the demo ends, also on Ctrl-C or an error.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import shutil
import time
from typing import Any

DEMO_PROFILE = 'german-low'
DEMO_DEFECTS = 'dip@150:len=10:depth=0.004'
#: s after the replay ends until every output and the last diagnostics are recorded: the nodes'
#: idle_flush_s (2 s), ~7,200 delayed outputs at flush_rate_hz (1000/s), 1 s of diagnostics and
#: a margin for a loaded machine
FLUSH_WAIT_S = 14.0
DIP = (150.0, 10.0)  # start, length (m)
SPEED = 20.0
RATE_HZ = 1000.0  # the simulated IMU's rate (adxl355 preset), Hz
OUTPUTS = ('bode.png', 'live_bag', 'logs', 'review', 'simulated_bag')
LIVE_TOPICS = ('/track/irregularity', '/track/irregularity_band', '/track/sensitivity',
               '/diagnostics')
NODES = ('irregularity_node', 'uncertainty_node')
SCORE_MARGIN_M = 80.0  # left out at both ends of the scored part


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``demo`` subcommand."""
    p = subparsers.add_parser(
        'demo', help='run the demonstration: simulate, run the nodes on a replay, review',
        description='Simulate a run (German low disturbance track with a 4 mm dip, ADXL355 at '
                    '1 kHz, 20 m/s) into a rosbag2 bag, draw the Bode diagram, start '
                    'irregularity_node and uncertainty_node, replay the bag into them, record '
                    'their outputs, review the bag (DIR/review/report.html) and summarise. '
                    'Outputs in DIR are replaced on every run.')
    p.add_argument('--out', default='out/demo', metavar='DIR',
                   help='output directory (default out/demo)')
    p.add_argument('--seed', type=int, default=0, metavar='N', help='random seed (default 0)')
    p.add_argument('--duration', type=float, default=20.0, metavar='S',
                   help='length of the simulated run, s (default 20; the nodes emit all but '
                   'the last ~7 s, the band delay)')
    p.set_defaults(func=run)


def _heading(text: str) -> None:
    """Print a step heading."""
    print(f'\n== {text}', flush=True)


def last_diagnostics(bag: Path) -> dict[str, dict[str, str]]:
    """Status name -> key -> value of the last /diagnostics message carrying that status."""
    from railgsa_ros.bag import read_messages

    last: dict[str, dict[str, str]] = {}
    for _, _, msg in read_messages(bag, ['/diagnostics']):
        for status in msg.status:
            last[status.name] = {kv.key: kv.value for kv in status.values}
    return last


def run_live(bag: Path, out: Path, duration_s: float) -> Path:
    """Record the nodes' outputs while the bag is replayed into them; returns the recording."""
    from railgsa_ros.errors import RailGsaError
    from railgsa_ros.system import System, session_domain

    record = out / 'live_bag'
    with session_domain() as domain, System(out / 'logs') as system:
        print(f'ROS_DOMAIN_ID={domain}, localhost discovery; logs in {out / "logs"}',
              flush=True)
        # a reader history of the whole run: the flush bursts of a loaded machine overflowed
        # the default 1000 (562 of 9000 outputs lost at load average 12)
        depth = int(duration_s * RATE_HZ) + 1000
        recorder = system.command('record', '--out', str(record), '--depth', str(depth),
                                  '--topics', *LIVE_TOPICS)
        for node in NODES:
            system.node(node)
        for topic in LIVE_TOPICS[:2]:  # both nodes are up and their outputs are subscribed
            if not recorder.wait_for_line(rf'recording {topic} \(', 120.0):
                raise RailGsaError(f'no publisher of {topic} after 120 s: see {out / "logs"}')
        print(f'replaying {bag} into {", ".join(NODES)} ...', flush=True)
        replay = system.command('replay', str(bag), '--topics', '/imu/data', '/odom',
                                '--wait-timeout', '30')
        if replay.wait(duration_s + 90.0) != 0:
            raise RailGsaError(f'replay failed: see {out / "logs"}')
        # the nodes' last outputs and diagnostics reach the recorder: idle_flush_s (2 s), then
        # the last band delay (~7200 outputs) paced at flush_rate_hz (1000/s), then a margin
        time.sleep(FLUSH_WAIT_S)
        if recorder.stop().rc != 0:
            raise RailGsaError(f'recording failed: see {out / "logs"}')
    return record


def live_summary(record: Path, run: Any) -> list[str]:
    """Accuracy of the recorded irregularity against the truth and the nodes' counters."""
    import numpy as np

    from railgsa_ros.bag import read_stamped
    from railgsa_ros.bag.messages import POINT_STAMPED
    from railgsa_ros.inverse.score import score

    irr = read_stamped(record, '/track/irregularity', POINT_STAMPED.msgtype)
    lines = [f'  /track/irregularity: {irr.stamps_ns.size} of {run.stamps_ns.size} samples '
             'emitted (the last band delay stays pending)']
    t0 = run.stamps_ns[0]  # chainage from the stamps: right even if a node missed the head
    chainage = np.interp(irr.stamps_ns - t0, run.stamps_ns - t0, run.chainage_m)
    if irr.stamps_ns.size and chainage[-1] - chainage[0] > 2 * SCORE_MARGIN_M + 2 * DIP[1]:
        s = score(chainage, irr.values[:, 2], run.chainage_m, run.truth_u_m, defect=DIP,
                  margin_m=SCORE_MARGIN_M)
        lines.append(f'  live accuracy vs truth (D1): RMSE {s.rmse * 1e3:.3f} mm, correlation '
                     f'{s.correlation:.3f}, dip peak error {s.peak_error * 1e3:.3f} mm')
    else:
        lines.append('  live output too short to score (use a longer --duration)')
    statuses = last_diagnostics(record)
    for node, task in zip(NODES, ('inversion', 'uncertainty'), strict=True):
        inp, work = statuses.get(f'{node}: imu input', {}), statuses.get(f'{node}: {task}', {})
        lines.append(f'  {node}: received {inp.get("received", "?")}, accepted '
                     f'{inp.get("accepted", "?")}, rejected {inp.get("rejected", "?")}, gaps '
                     f'{inp.get("gap", "?")}, published {work.get("published", "?")}')
    return lines


def review_bag(bag: Path, out: Path) -> list[str]:
    """Review the bag (truth from the bag itself) into out/review; summary lines."""
    from railgsa_ros.errors import InputError
    from railgsa_ros.review.build import ReviewOptions, build_review, write_review
    from railgsa_ros.review.exceedances import describe_counts

    try:
        review = build_review(ReviewOptions(bag, truth=bag))
    except InputError as exc:  # a run too short to score against the truth
        print(f'no truth comparison: {exc}')
        review = build_review(ReviewOptions(bag))
    report = write_review(review, out / 'review', overwrite=True)
    levels = ', '.join(f'{k} {v}' for k, v in describe_counts(review.exceedances).items())
    lines = [f'  report: {report}', f'  EN 13848-5 exceedances: {levels}']
    if review.comparison is not None:
        s = review.comparison.score
        lines.append(f'  review accuracy vs truth: RMSE {s.rmse * 1e3:.3f} mm, correlation '
                     f'{s.correlation:.3f}')
    return lines


def run(args: argparse.Namespace) -> int:
    """Run every demonstration step and list the outputs."""
    import importlib.util

    from railgsa_ros.cli.bode import mode_table, plot_bode
    from railgsa_ros.cli.simulate import format_summary, simulate_bag
    from railgsa_ros.vehicle import VehicleParams

    out = Path(args.out)
    _heading(f'1. simulate: {DEMO_PROFILE} + {DEMO_DEFECTS}, adxl355 at 1 kHz, '
             f'{SPEED:g} m/s, {args.duration:g} s')
    bag, sim = simulate_bag(out / 'simulated_bag', DEMO_PROFILE, speed=SPEED,
                            duration=args.duration, sensor='adxl355', seed=args.seed,
                            defects=DEMO_DEFECTS, overwrite=True)
    print(format_summary(bag))
    _heading('2. quarter vehicle (paper Table 1): modes, zeros, Bode diagram')
    params = VehicleParams()
    plot_bode(params, out / 'bode.png')
    print(mode_table(params))
    summary: list[str] = []
    if importlib.util.find_spec('rclpy') is None:
        _heading('3. nodes: skipped, rclpy is not installed (pip install -e .[ros])')
    else:
        _heading('3. irregularity_node + uncertainty_node on a replay of the bag, recorded')
        for stale in (out / 'live_bag', out / 'logs'):
            shutil.rmtree(stale, ignore_errors=True)
        record = run_live(bag, out, args.duration)
        summary += [f'  recording: {record}', *live_summary(record, sim)]
    _heading('4. review of the bag (offline, the nodes\' streaming core)')
    summary += review_bag(bag, out)
    _heading('summary')
    print('\n'.join(summary))
    _heading('outputs')
    for path in sorted(out.iterdir()):
        print(f'  {path}')
    return 0
