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
from railgsa_ros.errors import InputError, InputWarning
from railgsa_ros.playback.recording import BagRecorder, TopicSpec
from railgsa_ros.playback.source import BagSource

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
    with pytest.raises(InputError, match=f'^{bag}: damaged bag data'), BagSource(bag) as source:
        for _ in source.messages(['/imu/data']):  # the replay
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


# ---------------------------------------------------------------------------- recovery
KILLED_WRITER = '''
import os, signal, sys, time
sys.path.insert(0, sys.argv[2])
from test_bag_integrity import imu_messages
from railgsa_ros.playback.recording import BagRecorder, TopicSpec
from railgsa_ros.playback.source import BagSource
from railgsa_ros.bag.messages import IMU
stamps, _, messages = imu_messages(int(sys.argv[3]))
bag = BagRecorder(sys.argv[1], split_s=2.0, compress=sys.argv[4] == 'zstd')
bag.add_topic(TopicSpec('/imu/data', IMU.msgtype))
for i, (stamp, data) in enumerate(zip(stamps, messages)):
    bag.write('/imu/data', int(stamp), data)
    if i % 1000 == 999:
        bag.tick(int(stamp))  # what the recorder node does every second
os.kill(os.getpid(), signal.SIGKILL)
'''


@pytest.mark.parametrize('compress', ['zstd', 'none'])
def test_recover_after_sigkill_keeps_everything_up_to_the_last_flush(tmp_path, capsys,
                                                                     compress) -> None:
    """A recorder process killed 0.5 s after its last 1 s flush, 1.5 s into its third split
    file: the readers refuse the bag naming the unfinished file; ``railgsa recover`` makes it
    readable by our reader, rosbags and mcap, with every message up to the last flush."""
    import subprocess
    import sys

    n = 5500  # 5.5 s at 1 kHz: files of 2 s, flushes every 1000 messages
    bag = tmp_path / 'rec'
    proc = subprocess.run([sys.executable, '-c', KILLED_WRITER, str(bag),
                           str(Path(__file__).parent), str(n), compress], timeout=120)
    assert proc.returncode == -9
    stamps, acc_z, messages = imu_messages(n)
    unfinished = bag / 'rec_2.mcap'
    with pytest.raises(InputError, match=f'^{bag}: {unfinished.name} is unfinished .*railgsa '
                                         f'recover {bag}'):
        read_imu(bag)
    assert main(['recover', str(bag)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == ['rec_0.mcap: finished, 2000 messages', 'rec_1.mcap: finished, 2000 messages',
                   'rec_2.mcap: recovered, 1000 messages']
    kept = 5000  # everything up to the last flush; the 500 after it were in memory only
    stream = read_imu(bag)
    assert np.array_equal(stream.stamps_ns, stamps[:kept])
    assert np.array_equal(stream.accel[:, 2], acc_z[:kept])
    with AnyReader([bag]) as reader:
        assert [bytes(raw) for _, _, raw in reader.messages()] == messages[:kept]
    got = []
    for file in sorted(bag.glob('*.mcap')):
        with file.open('rb') as f:
            got += [m.data for _, _, m in make_reader(f, validate_crcs=True).iter_messages()]
    assert got == messages[:kept]
    assert (bag / 'rec_2.mcap.orig').exists()  # the original is kept
    assert main(['recover', str(bag)]) == 0  # again: nothing left to do
    assert capsys.readouterr().out.splitlines()[-1] == 'rec_2.mcap: finished, 1000 messages'


def test_recover_drops_a_damaged_chunk_and_keeps_the_rest(tmp_path, capsys) -> None:
    stamps, acc_z, messages = imu_messages(3500)
    bag = tmp_path / 'rec'
    record(bag, messages, stamps, compress=False)  # not closed: unfinished, as killed
    file = bag / 'rec_0.mcap'
    data = bytearray(file.read_bytes())
    at = data.find(struct.pack('<d', acc_z[1500]))
    data[at] ^= 0xFF  # inside the second chunk (flushed after messages 1000, 2000, 3000)
    file.write_bytes(bytes(data))
    assert main(['recover', str(bag)]) == 0
    assert capsys.readouterr().out == 'rec_0.mcap: recovered, 2001 messages, 1 damaged ' \
                                      'chunk(s) dropped\n'
    with AnyReader([bag]) as reader:
        got = [bytes(raw) for _, _, raw in reader.messages()]
    assert got == messages[:1001] + messages[2001:3001]  # the last 499 were never flushed


def test_recover_refuses_what_is_not_a_bag(tmp_path, capsys) -> None:
    assert main(['recover', str(tmp_path / 'missing')]) == 2
    assert 'not a bag directory or .mcap file' in capsys.readouterr().err
    assert main(['recover', str(tmp_path)]) == 2
    assert capsys.readouterr().err == f'error: {tmp_path}: no .mcap file to recover\n'


# ---------------------------------------------------------------------------- malformed messages
@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_reader_counts_and_skips_malformed_messages(tmp_path, capsys, storage) -> None:
    """A 0-byte, a truncated and a header-only Imu among 3000 good ones: the offline reader
    skips exactly those, says so on one warning line, and inverts the rest."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from railgsa_ros.bag.messages import typestore
    from railgsa_ros.bag.reader import iter_imu

    stamps, acc_z, messages = imu_messages(3000)
    bad = {10: b'', 1500: messages[1500][:50], 2999: b'\x00\x01\x00\x00'}
    bag = tmp_path / 'bag'
    with Writer(bag, version=9, storage_plugin=StoragePlugin[storage.upper()]) as writer:
        conn = writer.add_connection('/imu/data', IMU.msgtype, typestore=typestore())
        for i, stamp in enumerate(stamps):
            writer.write(conn, int(stamp), bad.get(i, messages[i]))
    good = np.array([i not in bad for i in range(stamps.size)])
    with pytest.warns(InputWarning, match=r'^3 malformed sensor_msgs/msg/Imu message\(s\) '
                                          r'skipped .* first at log time 1700000000\.010000 s'):
        stream = read_imu(bag)
    assert np.array_equal(stream.stamps_ns, stamps[good])
    assert np.array_equal(stream.accel[:, 2], acc_z[good])
    with pytest.warns(InputWarning):
        pieces = list(iter_imu(bag, chunk=1000))
    assert np.array_equal(np.concatenate([p.stamps_ns for p in pieces]), stamps[good])
    out = tmp_path / 'u.csv'
    assert main(['invert', str(bag), '--csv', str(out), '--speed', '20']) == 0
    err = capsys.readouterr().err
    assert err.startswith('warning: ') and 'malformed sensor_msgs/msg/Imu' in err, err
    assert len(out.read_text().splitlines()) - 1 == good.sum()


def test_recover_counts_a_finished_file_without_statistics(tmp_path, capsys) -> None:
    """Another writer's finished file without summary statistics is counted message by
    message into metadata.yaml next to the recovered one."""
    from mcap.writer import CompressionType, Writer

    from railgsa_ros.playback.recording import message_definition

    stamps, _, messages = imu_messages(2500)
    bag = tmp_path / 'rec'
    record(bag, messages[:2000], stamps[:2000], compress=True)  # unfinished: 1001 flushed
    with (bag / 'rec_1.mcap').open('wb') as stream:
        writer = Writer(stream, compression=CompressionType.NONE, use_statistics=False)
        writer.start(profile='ros2')
        schema = writer.register_schema(IMU.msgtype, 'ros2msg',
                                        message_definition(IMU.msgtype).encode())
        channel = writer.register_channel('/imu/data', 'cdr', schema)
        for stamp, data in zip(stamps[2000:], messages[2000:], strict=True):
            writer.add_message(channel, int(stamp), data, int(stamp))
        writer.finish()
    assert main(['recover', str(bag)]) == 0
    assert capsys.readouterr().out.splitlines() == ['rec_0.mcap: recovered, 1001 messages',
                                                    'rec_1.mcap: finished, 500 messages']
    with AnyReader([bag]) as reader:
        assert reader.message_count == 1501
        assert [bytes(r) for _, _, r in reader.messages()] == messages[:1001] + messages[2000:]


def test_recover_a_recorders_partial_file(tmp_path, capsys) -> None:
    """After a write error the recorder renames the file in progress ``*.mcap.partial``:
    recover turns its complete records into ``*.mcap`` and lists it."""
    stamps, _, messages = imu_messages(2500)
    bag = tmp_path / 'rec'
    record(bag, messages, stamps, compress=True)  # flushed after messages 1000 and 2000
    (bag / 'rec_0.mcap').rename(bag / 'rec_0.mcap.partial')  # as BagRecorder._abandon
    assert main(['recover', str(bag)]) == 0
    assert capsys.readouterr().out == 'rec_0.mcap: recovered, 2001 messages\n'
    with AnyReader([bag]) as reader:
        assert [bytes(r) for _, _, r in reader.messages()] == messages[:2001]


def test_recover_sets_aside_empty_and_unreadable_split_files_and_keeps_the_rest(
        tmp_path, capsys) -> None:
    """A recording split every second whose recorder was killed just after opening a new file
    (0 bytes), with one finished file overwritten by garbage and one cut inside its header:
    recover names and counts the three, sets them aside and keeps every message of the others
    (before, the 0-byte file refused the whole recording: "not an MCAP file")."""
    stamps, _, messages = imu_messages(5000)
    bag = tmp_path / 'rec'
    record(bag, messages, stamps, compress=True, split_s=1.0).close()
    files = sorted(bag.glob('rec_*.mcap'), key=lambda f: int(f.stem.split('_')[1]))
    assert len(files) == 5
    kept = {}  # the messages of each file
    for f in files:
        with AnyReader([f]) as reader:
            kept[f.name] = [bytes(r) for _, _, r in reader.messages()]
    (bag / 'metadata.yaml').unlink()  # as killed: not written yet
    (bag / 'rec_5.mcap').write_bytes(b'')  # the split the kill cut at once
    files[1].write_bytes(b'\x00garbage' * 100)
    files[3].write_bytes(files[3].read_bytes()[:20])  # magic and a cut header record
    assert main(['recover', str(bag)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].startswith('rec_1.mcap: unreadable (not an MCAP file); set aside')
    assert out[3] == 'rec_3.mcap: empty, 12 bytes after the cut; set aside as rec_3.mcap.orig'
    assert out[5] == 'rec_5.mcap: empty; set aside as rec_5.mcap.orig'
    assert out[-1] == ('3 of 6 files skipped (empty or unreadable): rec_1.mcap, rec_3.mcap, '
                       'rec_5.mcap; the other files are readable')
    with AnyReader([bag]) as reader:
        got = [bytes(r) for _, _, r in reader.messages()]
    assert got == kept['rec_0.mcap'] + kept['rec_2.mcap'] + kept['rec_4.mcap']
    assert len(got) > 2500
    assert read_imu(bag).stamps_ns.size == len(got)  # our reader opens it too
