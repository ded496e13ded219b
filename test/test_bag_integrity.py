"""Damaged data is an error, never data: MCAP chunk CRCs (our fast path, rosbags, mcap),
recovery of a recording cut short, malformed messages counted and skipped."""

from __future__ import annotations

from io import BytesIO
from pathlib import Path
import struct

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import CRCValidationError
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from railgsa_ros.bag import read_imu
from railgsa_ros.bag.cdr import encode
from railgsa_ros.bag.messages import IMU, IMU_FIELDS
from railgsa_ros.bag.reader import _mcap_topics
from railgsa_ros.cli.main import main
from railgsa_ros.errors import InputError
from railgsa_ros.playback.recording import BagRecorder, TopicSpec

RATE_HZ = 1000
START_NS = 1_700_000_000 * 10**9


def imu_messages(n: int, seed: int = 0, start_ns: int = START_NS) -> tuple[np.ndarray,
                                                                          np.ndarray, list]:
    """(stamps_ns, accel_z, CDR messages) of n Imu at 1 kHz, gravity plus noise on z."""
    rng = np.random.default_rng(seed)
    stamps = start_ns + np.arange(n, dtype=np.int64) * (10**9 // RATE_HZ)
    values = np.zeros((n, IMU.n_doubles))
    acc_z = 9.80665 + 0.01 * rng.standard_normal(n)
    values[:, IMU_FIELDS['linear_acceleration']] = np.column_stack(
        [np.zeros(n), np.zeros(n), acc_z])
    return stamps, acc_z, encode(IMU, stamps, ['imu_link'], values)


def record(path: Path, messages: list, stamps: np.ndarray, compress: bool,
           split_s: float = 60.0) -> BagRecorder:
    """A bag written by our recorder (mcap Writer: chunk CRCs stored), 1 s flushes."""
    bag = BagRecorder(path, split_s=split_s, compress=compress)
    bag.add_topic(TopicSpec('/imu/data', IMU.msgtype))
    last = stamps[0]
    for stamp, data in zip(stamps, messages, strict=True):
        bag.write('/imu/data', int(stamp), data)
        if stamp - last >= 10**9:
            bag.tick(int(stamp))
            last = stamp
    return bag


def chunk_crcs(file: Path) -> list[int]:
    """The uncompressed_crc of every chunk record of an MCAP file."""
    with file.open('rb') as stream:
        indexes = make_reader(stream).get_summary().chunk_indexes
        crcs = []
        for index in indexes:
            stream.seek(index.chunk_start_offset + 9)  # opcode, length
            crcs.append(Chunk.read(ReadDataStream(BytesIO(stream.read(
                index.chunk_length - 9)))).uncompressed_crc)
    return crcs


# ---------------------------------------------------------------------------- chunk CRCs
@pytest.mark.parametrize('compress', [False, True])
def test_corrupted_chunk_is_an_error_in_every_reader(tmp_path, capsys, compress) -> None:
    """One acceleration changed by 0.5 m/s^2 inside a CRC-protected chunk (uncompressed: the
    bytes still decode, as a false peak; zstd: a flipped bit of the compressed frame)."""
    stamps, acc_z, messages = imu_messages(5000)
    bag = tmp_path / 'bag'
    record(bag, messages, stamps, compress).close()
    file = next(bag.glob('*.mcap'))
    assert np.array_equal(read_imu(bag).accel[:, 2], acc_z)  # intact: read exactly
    data = bytearray(file.read_bytes())
    if compress:  # a bit in the middle of the second chunk record
        with file.open('rb') as stream:
            chunk = sorted(make_reader(stream).get_summary().chunk_indexes,
                           key=lambda c: c.chunk_start_offset)[1]
        data[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0x10
    else:
        at = data.find(struct.pack('<d', acc_z[2500]))
        assert at > 0
        data[at:at + 8] = struct.pack('<d', acc_z[2500] + 0.5)
    file.write_bytes(bytes(data))
    with pytest.raises(CRCValidationError if not compress else Exception):
        _mcap_topics([file], {'/imu/data': IMU.msgtype})  # the fast path alone
    with pytest.raises(InputError, match=f'^{bag}: '):
        read_imu(bag)  # our reader: the fast path, then rosbags
    with pytest.raises(Exception, match=r'(?i)checksum|zstandard'), AnyReader([bag]) as reader:
        for _ in reader.messages():
            pass
    with pytest.raises((McapError, Exception)), file.open('rb') as stream:
        for _ in make_reader(stream, validate_crcs=True).iter_messages():
            pass
    out = tmp_path / 'u.csv'
    assert main(['invert', str(bag), '--csv', str(out), '--speed', '20']) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'error: {bag}: ') and err.count('\n') == 1, err
    assert not out.exists()


def test_recorder_chunks_carry_crcs(tmp_path) -> None:
    stamps, _, messages = imu_messages(3000)
    record(tmp_path / 'bag', messages, stamps, compress=False).close()
    crcs = chunk_crcs(next((tmp_path / 'bag').glob('*.mcap')))
    assert len(crcs) >= 3 and all(crcs)
