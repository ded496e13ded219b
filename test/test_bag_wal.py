"""sqlite3 bags written in WAL mode (rosbag2's resilient storage preset) and not checkpointed:
the newest messages are only in ``NAME.db3-wal``.

The bag is written by rosbags (the first 3000 IMU messages), then a recorder process switches
the database to WAL mode with automatic checkpoints off (as the resilient preset does), appends
2000 more messages and is killed (SIGKILL) before any checkpoint.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import sqlite3
import subprocess
import sys

import numpy as np
import pytest

from railgsa_ros.bag import read_imu
from railgsa_ros.bag.cdr import encode
from railgsa_ros.bag.messages import IMU, IMU_FIELDS, typestore
from railgsa_ros.cli.main import main
from railgsa_ros.errors import InputError

N, FIRST = 5000, 3000
START_NS = 1_700_000_000 * 10**9
# append messages FIRST.. (given as a .npz of stamps and CDR bytes) in WAL mode, then die
RECORDER = """
import os, signal, sqlite3, sys
import numpy as np
db3, rows = sys.argv[1], np.load(sys.argv[2])
con = sqlite3.connect(db3)
assert con.execute('PRAGMA journal_mode=WAL').fetchone()[0] == 'wal'
con.execute('PRAGMA wal_autocheckpoint=0')
topic = con.execute("SELECT id FROM topics WHERE name = '/imu/data'").fetchone()[0]
con.executemany('INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)',
                [(topic, int(t), d.tobytes()) for t, d in zip(rows['stamps'], rows['data'])])
con.commit()
os.kill(os.getpid(), signal.SIGKILL)
"""


def _imu(n: int) -> tuple[np.ndarray, list[bytes]]:
    stamps = START_NS + np.arange(n, dtype=np.int64) * 1_000_000  # 1 kHz
    values = np.zeros((n, IMU.n_doubles))
    values[:, IMU_FIELDS['linear_acceleration']] = [0.0, 0.0, 9.81]
    return stamps, encode(IMU, stamps, ['imu_link'], values)


@pytest.fixture
def wal_bag(tmp_path) -> tuple[Path, np.ndarray]:
    from rosbags.rosbag2 import StoragePlugin, Writer

    stamps, data = _imu(N)
    bag = tmp_path / 'bag'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection('/imu/data', IMU.msgtype, typestore=typestore())
        for stamp, raw in zip(stamps[:FIRST], data[:FIRST], strict=True):
            writer.write(conn, int(stamp), raw)
    db3 = next(bag.glob('*.db3'))
    rows = tmp_path / 'rows.npz'
    assert len({len(d) for d in data}) == 1  # one frame_id: every message the same length
    np.savez(rows, stamps=stamps[FIRST:],
             data=np.frombuffer(b''.join(data[FIRST:]), np.uint8).reshape(N - FIRST, -1))
    proc = subprocess.run([sys.executable, '-c', RECORDER, str(db3), str(rows)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert db3.with_name(db3.name + '-wal').stat().st_size > 100_000  # the newest messages
    return bag, stamps


def test_a_wal_bag_is_read_with_its_wal(wal_bag):
    """Every message, the 2000 in the log too (before: the first 3000, no error)."""
    bag, stamps = wal_bag
    np.testing.assert_array_equal(read_imu(bag).stamps_ns, stamps)
    np.testing.assert_array_equal(read_imu(next(bag.glob('*.db3'))).stamps_ns, stamps)


def test_a_wal_that_cannot_be_applied_is_refused_in_one_line(wal_bag, capsys):
    """Another process holds a read transaction on the database, so the log cannot be moved
    into it: exit 2 with one line naming the log (never a silently shorter run)."""
    bag, _ = wal_bag
    db3 = next(bag.glob('*.db3'))
    holder = sqlite3.connect(db3)
    try:
        holder.execute('BEGIN')
        assert holder.execute('SELECT count(*) FROM messages').fetchone()[0] == N
        with pytest.raises(InputError, match=f'^{bag}: {db3.name}-wal holds messages not yet '
                                             f'in {db3.name}'):
            read_imu(bag)
        assert main(['invert', str(bag), '--csv', os.devnull, '--speed', '20']) == 2
        err = capsys.readouterr().err
        assert err.startswith(f'error: {bag}: ') and err.count('\n') == 1, err
    finally:
        holder.close()
    assert read_imu(bag).stamps_ns.size == N
