"""Ctrl-C on ``railgsa run`` as a terminal sends it: how many tries end with exit code 0.

Each try starts ``railgsa run`` as the leader of its own process group (a terminal's foreground
job), waits until both nodes logged their start-up line, waits a random 0-``--jitter`` s and
sends SIGINT to the whole process group, as a terminal's Ctrl-C does. A try passes when
``railgsa run`` exits 0 without a traceback within ``--timeout`` s and no process of the group
is left. Prints one line per failing try (its return code and the last lines of its output)
and at the end ``exit 0: N of M``.

    python benchmarks/stress_run_ctrl_c.py [--tries 50] [--jitter 1.0] [--timeout 60]

Every try runs in a reserved ROS domain with localhost-only discovery. The machine's load is
printed with the result (the count is meant under the load a train computer sees).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import tempfile
import time

from railgsa_ros.system import CLI_MODULE, isolated_domain, ros_env

NODES = ('irregularity_node', 'uncertainty_node')
#: both nodes from one file, no odometry: they start fast and stay idle
PARAMS = ('/**:\n  ros__parameters:\n    use_odom: false\n    speed_mps: 40.0\n'
          '    min_design_speed_mps: 40.0\n')
STARTUP_S = 120.0  #: longest wait for both start-up lines, s


def started(log: Path) -> bool:
    """Whether both nodes logged their start-up line (``... -> <outputs>``)."""
    text = log.read_text('utf-8', 'replace')
    return all(any(f'[{n}]' in ln and ' -> ' in ln for ln in text.splitlines()) for n in NODES)


def group_alive(pgid: int) -> bool:
    """Whether any process of group ``pgid`` is still running."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def one_try(params: Path, log: Path, jitter: float, timeout: float,
            rng: random.Random) -> tuple[int | None, str]:
    """Start ``railgsa run``, Ctrl-C its group once ready; (return code or None, output)."""
    with open(log, 'wb') as out:
        proc = subprocess.Popen([sys.executable, '-m', CLI_MODULE, 'run', '--params', str(params)],
                                stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=ros_env(), start_new_session=True)
    deadline = time.monotonic() + STARTUP_S
    while not started(log) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    if proc.poll() is None:
        time.sleep(rng.uniform(0.0, jitter))
        os.killpg(proc.pid, signal.SIGINT)
    try:
        rc: int | None = proc.wait(timeout)
    except subprocess.TimeoutExpired:
        rc = None
    for _ in range(50):  # the children end after railgsa run
        if not group_alive(proc.pid):
            break
        time.sleep(0.1)
    else:
        os.killpg(proc.pid, signal.SIGKILL)
        rc = None if rc == 0 else rc
    return rc, log.read_text('utf-8', 'replace')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--tries', type=int, default=50)
    parser.add_argument('--jitter', type=float, default=1.0,
                        help='longest random wait after readiness, s')
    parser.add_argument('--timeout', type=float, default=60.0,
                        help='longest wait for the exit after Ctrl-C, s')
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    passed = 0
    with tempfile.TemporaryDirectory() as tmp, isolated_domain():
        params = Path(tmp) / 'params.yaml'
        params.write_text(PARAMS)
        for k in range(args.tries):
            rc, output = one_try(params, Path(tmp) / f'run{k}.log', args.jitter, args.timeout,
                                 rng)
            if rc == 0 and 'Traceback' not in output:
                passed += 1
            else:
                tail = ' | '.join(output.strip().splitlines()[-3:])
                print(f'try {k}: exit {rc}: {tail}', flush=True)
    load = ', '.join(f'{x:.1f}' for x in os.getloadavg())
    print(f'exit 0: {passed} of {args.tries} (load average {load}, {os.cpu_count()} cores)')
    return 0 if passed == args.tries else 1


if __name__ == '__main__':
    sys.exit(main())
