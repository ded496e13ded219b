"""Cost of checking MCAP chunk CRCs in the reader's fast path (``bag.reader._mcap_topics``).

A bag of ``--seconds`` of 1 kHz Imu is written by our recorder (``BagRecorder``: chunk CRCs
stored, a chunk per second), uncompressed and zstd. The fast path reads it with the CRC check
(as shipped) and with it disabled (the baseline, in the same run, after one warm-up read); best
of ``--repeat``. The machine is shared: the load average is printed next to the numbers.

Usage: python benchmarks/bench_crc.py [--seconds 600] [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import tempfile
import time
from unittest import mock

from mcap.stream_reader import get_chunk_data_stream
import numpy as np

from railgsa_ros.bag import reader
from railgsa_ros.bag.cdr import encode
from railgsa_ros.bag.messages import IMU, IMU_FIELDS
from railgsa_ros.playback.recording import BagRecorder, TopicSpec

NS = 1_000_000_000


def write_bag(path: Path, seconds: int, compress: bool) -> list[Path]:
    """``seconds`` of 1 kHz Imu (gravity plus noise on z) through BagRecorder."""
    n = seconds * 1000
    stamps = 1_700_000_000 * NS + np.arange(n, dtype=np.int64) * 1_000_000
    values = np.zeros((n, IMU.n_doubles))
    values[:, IMU_FIELDS['linear_acceleration'].start + 2] = 9.81 + 0.01 * np.random.default_rng(
        0).standard_normal(n)
    bag = BagRecorder(path, split_s=seconds + 1.0, compress=compress)
    bag.add_topic(TopicSpec('/imu/data', IMU.msgtype))
    for start in range(0, n, 1000):
        for stamp, data in zip(stamps[start:start + 1000],
                               encode(IMU, stamps[start:start + 1000], ['imu'],
                                      values[start:start + 1000]), strict=True):
            bag.write('/imu/data', int(stamp), data)
        bag.tick(int(stamps[min(start + 999, n - 1)]))
    bag.close()
    return sorted(path.glob('*.mcap'))


def read_time(files: list[Path], check: bool, repeat: int) -> float:
    """Best wall time (s) of the fast path over ``files``, with or without the CRC check."""
    def unchecked(chunk, validate_crc=False):
        return get_chunk_data_stream(chunk, validate_crc=False)

    best = float('inf')
    with mock.patch.object(reader, 'get_chunk_data_stream',
                           get_chunk_data_stream if check else unchecked):
        for _ in range(repeat):
            start = time.perf_counter()
            reader._mcap_topics(files, {'/imu/data': IMU.msgtype})
            best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=int, default=600)
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args()
    print(f'{args.seconds} s of 1 kHz Imu; load average {os.getloadavg()[0]:.1f}')
    print(f'{"chunks":<10}{"CRC checked s":>15}{"unchecked s":>13}{"ratio":>8}')
    with tempfile.TemporaryDirectory() as tmp:
        for compress in (False, True):
            files = write_bag(Path(tmp) / f'bag_{compress}', args.seconds, compress)
            read_time(files, False, 1)  # warm the page cache and the imports
            baseline = read_time(files, False, args.repeat)
            checked = read_time(files, True, args.repeat)
            print(f'{"zstd" if compress else "plain":<10}{checked:>15.3f}{baseline:>13.3f}'
                  f'{checked / baseline:>8.2f}')


if __name__ == '__main__':
    main()
