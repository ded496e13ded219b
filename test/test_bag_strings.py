"""Strings in messages are bounded (``cdr.MAX_STRING``): a message with a longer frame_id is
malformed, counted and left out; the rest of the bag or batch is read.

Before, one 50,000-character frame_id among a bag's IMU messages made every row of the decoded
frame_id column 200 kB wide (6 GB and 100 s for a 49,876-sample bag), and a 20 MB one made the
column too large to allocate: the whole bag was refused.
"""

from __future__ import annotations

import struct
import tracemalloc

import numpy as np
import pytest

from railgsa_ros.bag.cdr import MAX_STRING, encode
from railgsa_ros.bag.messages import IMU, IMU_FIELDS, typestore
from railgsa_ros.bag.reader import iter_imu, read_imu
from railgsa_ros.errors import InputWarning
from railgsa_ros.nodes.imu_conversion import imu_batch

N = 2000
START_NS = 1_700_000_000 * 10**9
# index -> frame_id: over the cap but for 1700 (255 characters and the NUL: at the cap)
LONG = {500: 'x' * 50_000, 1200: 'y' * 20_000_000, 1700: 'z' * (MAX_STRING - 1),
        1800: 'w' * MAX_STRING}
OVER = [500, 1200, 1800]


def _messages() -> tuple[np.ndarray, np.ndarray, list[bytes]]:
    """(stamps, accel z, CDR Imu messages): 1 kHz, frame 'imu_link' but for LONG."""
    stamps = START_NS + np.arange(N, dtype=np.int64) * 1_000_000
    acc_z = 9.81 + 1e-4 * np.arange(N)
    values = np.zeros((N, IMU.n_doubles))
    values[:, IMU_FIELDS['linear_acceleration'].start + 2] = acc_z
    data = encode(IMU, stamps, ['imu_link'], values)
    for i, frame in LONG.items():
        data[i] = encode(IMU, stamps[i:i + 1], [frame], values[i:i + 1])[0]
    return stamps, acc_z, data


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_message_with_a_huge_frame_id_is_malformed_and_the_rest_read(tmp_path, storage):
    """MCAP (the vectorised fast path, then rosbags) and sqlite3 (rosbags): the two messages
    whose frame_id is over the cap are counted in one warning and left out; every other one is
    read, the one exactly at the cap (255 characters and the NUL) too; memory stays small."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    stamps, acc_z, data = _messages()
    bag = tmp_path / 'bag'
    with Writer(bag, version=9, storage_plugin=StoragePlugin[storage.upper()]) as writer:
        conn = writer.add_connection('/imu/data', IMU.msgtype, typestore=typestore())
        for stamp, raw in zip(stamps, data, strict=True):
            writer.write(conn, int(stamp), raw)
    keep = np.ones(N, bool)
    keep[OVER] = False
    tracemalloc.start()
    try:
        with pytest.warns(InputWarning, match=r'^3 malformed sensor_msgs/msg/Imu message\(s\) '
                                              r'skipped \(empty, truncated or a string over 256 '
                                              r'bytes; first at log time 1700000000\.500000 s'):
            stream = read_imu(bag, odom_topic=None)
        with pytest.warns(InputWarning):
            pieces = list(iter_imu(bag, odom_topic=None, chunk=700))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(stream.stamps_ns, stamps[keep])
    np.testing.assert_array_equal(stream.accel[:, 2], acc_z[keep])
    assert set(stream.frame_ids) == {'imu_link', LONG[1700]}
    np.testing.assert_array_equal(np.concatenate([p.stamps_ns for p in pieces]), stamps[keep])
    assert peak < 200e6  # the bag's 20 MB message read twice, and a little more


def test_the_live_intake_counts_a_huge_frame_id_as_malformed():
    """The nodes' intake (``imu_batch``, with and without rclpy's fallback deserialiser in
    the nodes): the messages over the cap counted malformed, the others decoded."""
    stamps, acc_z, data = _messages()

    reached = []

    def fallback(raw: bytes):
        """A general deserialiser (as rclpy's) that reads any length of frame_id."""
        reached.append(len(raw))
        sec, nsec, count = struct.unpack_from('<iII', raw, 4)
        body = 4 + (12 + count + 7) // 8 * 8
        return (sec * 10**9 + nsec, nsec, (raw[16:15 + count].decode(),),
                np.frombuffer(raw, '<f8', IMU.n_doubles, body))

    for batch in (data[495:505], data[1195:1205], data[:]):
        first = data.index(batch[0])
        expect = [i for i in range(first, first + len(batch)) if i not in OVER]
        got, malformed = imu_batch(batch, fallback)
        assert malformed == len(batch) - len(expect)
        np.testing.assert_array_equal(got.stamps_ns, stamps[expect])
        np.testing.assert_array_equal(got.accel[:, 2], acc_z[expect])
        assert got.frame_ids.dtype.itemsize <= 4 * MAX_STRING
    for i in LONG:  # a batch of one, as a node gets them
        assert imu_batch([data[i]], fallback)[1] == (i in OVER)
    assert reached and max(reached) < 1000  # the 50 kB and 20 MB ones never deserialised
