"""Bag opening for replay (railgsa_ros.playback.source) and recording (playback.recording), no ROS.

Bags are written by rosbags (MCAP, zstd MCAP, sqlite3), by the mcap_ros2 writer (bare file) and by
the plain mcap writer with lz4 chunks; the truth is what each writer was given. The helpers here
are shared with the ROS replay tests.
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys
import textwrap

from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_ros2.decoder import DecoderFactory
import mcap_ros2.writer
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.rosbag2.metadata import dump_qos_v9
import yaml

from railgsa_ros.bag.messages import typestore
from railgsa_ros.errors import ConfigError, InputError
from railgsa_ros.playback.recording import BagRecorder, TopicSpec, message_definition
from railgsa_ros.playback.source import BagSource
from railgsa_ros.qos import record_qos

IMU = 'sensor_msgs/msg/Imu'
T0 = 1_700_000_000 * 10**9
PERIOD = 1_000_000  # ns, 1 kHz


def imu_dict(i: int) -> dict:
    """Imu number i as a plain dict: stamp T0 + i ms, linear_acceleration.z = i."""
    sec, nsec = divmod(T0 + i * PERIOD, 10**9)
    vec = {'x': 0.0, 'y': 0.0, 'z': 0.0}
    return {'header': {'stamp': {'sec': sec, 'nanosec': nsec}, 'frame_id': 'imu_link'},
            'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
            'orientation_covariance': [-1.0] + [0.0] * 8,
            'angular_velocity': vec, 'angular_velocity_covariance': [-1.0] + [0.0] * 8,
            'linear_acceleration': {'x': 0.1, 'y': -0.2, 'z': float(i)},
            'linear_acceleration_covariance': [0.0] * 9}


def imu_cdr(i: int) -> bytes:
    """CDR bytes of Imu number i (rosbags serialiser)."""
    ts = typestore()
    d = imu_dict(i)
    h = d['header']
    msg = ts.types[IMU](
        ts.types['std_msgs/msg/Header'](ts.types['builtin_interfaces/msg/Time'](
            h['stamp']['sec'], h['stamp']['nanosec']), h['frame_id']),
        ts.types['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0, 1.0),
        np.array(d['orientation_covariance']),
        ts.types['geometry_msgs/msg/Vector3'](0.0, 0.0, 0.0),
        np.array(d['angular_velocity_covariance']),
        ts.types['geometry_msgs/msg/Vector3'](0.1, -0.2, float(i)), np.zeros(9))
    return bytes(ts.serialize_cdr(msg, IMU))


def write_rosbags(path: Path, n: int, storage: str = 'mcap', compress: bool = False,
                  reliable: bool = False, extra: dict[str, tuple[str, list[bytes]]] | None = None
                  ) -> list[tuple[str, int, bytes]]:
    """A rosbags bag of n Imu at 1 kHz on /imu/data (plus ``extra`` topics -> (type, raws) at
    10 ms spacing); returns the written (topic, stamp, bytes) in time order."""
    writer = Writer(path, version=9, storage_plugin=StoragePlugin[storage.upper()])
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    written = [('/imu/data', T0 + i * PERIOD, imu_cdr(i)) for i in range(n)]
    for topic, (_, raws) in (extra or {}).items():
        written += [(topic, T0 + j * 10 * PERIOD + 1, raw) for j, raw in enumerate(raws)]
    written.sort(key=lambda w: w[1])
    with writer:
        offered = [record_qos(reliable, 5)]
        conns = {'/imu/data': writer.add_connection('/imu/data', IMU, typestore=typestore(),
                                                    offered_qos_profiles=offered)}
        for topic, (msgtype, _) in (extra or {}).items():
            conns[topic] = writer.add_connection(topic, msgtype, typestore=typestore(),
                                                 offered_qos_profiles=[record_qos(True, 10)])
        for topic, stamp, raw in written:
            writer.write(conns[topic], stamp, raw)
    return written


def write_mcap_ros2(path: Path, n: int) -> list[tuple[str, int, bytes]]:
    """A bare .mcap of n Imu at 1 kHz written by mcap_ros2 (zstd chunks, no QoS metadata); returns
    (topic, stamp, bytes) as read back by the plain mcap reader."""
    with open(path, 'wb') as f:
        writer = mcap_ros2.writer.Writer(f)
        schema = writer.register_msgdef(IMU, message_definition(IMU))
        for i in range(n):
            writer.write_message('/imu/data', schema, imu_dict(i), log_time=T0 + i * PERIOD,
                                 publish_time=T0 + i * PERIOD)
        writer.finish()
    return read_mcap_raw([path])


def write_mcap_lz4(path: Path, n: int) -> list[tuple[str, int, bytes]]:
    """A bare .mcap with lz4 chunks by the plain mcap writer, rosbag2 profile and QoS metadata."""
    raws = [imu_cdr(i) for i in range(n)]
    with open(path, 'wb') as f:
        writer = McapWriter(f, chunk_size=64 * 1024, compression=CompressionType.LZ4)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema(IMU, 'ros2msg', message_definition(IMU).encode())
        channel = writer.register_channel('/imu/data', 'cdr', schema, {
            'offered_qos_profiles': yaml.safe_dump(dump_qos_v9([record_qos(True, 7)]))})
        for i, raw in enumerate(raws):
            writer.add_message(channel, T0 + i * PERIOD, raw, T0 + i * PERIOD)
        writer.finish()
    return [('/imu/data', T0 + i * PERIOD, raw) for i, raw in enumerate(raws)]


def read_mcap_raw(files: list[Path]) -> list[tuple[str, int, bytes]]:
    """(topic, log_time, bytes) of MCAP files by the plain mcap reader (independent of rosbags)."""
    out = []
    for file in files:
        with open(file, 'rb') as f:
            out += [(ch.topic, m.log_time, bytes(m.data))
                    for _, ch, m in make_reader(f).iter_messages(log_time_order=True)]
    return out


BAG_KINDS = ('rosbags-mcap', 'rosbags-mcap-zstd', 'rosbags-sqlite3', 'mcap_ros2-bare',
             'mcap-lz4-bare')


def make_bag(kind: str, tmp: Path, n: int) -> tuple[Path, list[tuple[str, int, bytes]]]:
    """A bag of ``kind`` (one of BAG_KINDS) with n Imu at 1 kHz, and what it holds."""
    if kind == 'mcap_ros2-bare':
        return tmp / 'imu.mcap', write_mcap_ros2(tmp / 'imu.mcap', n)
    if kind == 'mcap-lz4-bare':
        return tmp / 'imu.mcap', write_mcap_lz4(tmp / 'imu.mcap', n)
    storage = 'sqlite3' if kind.endswith('sqlite3') else 'mcap'
    return tmp / 'bag', write_rosbags(tmp / 'bag', n, storage, compress=kind.endswith('zstd'))


@pytest.mark.parametrize('kind', BAG_KINDS)
def test_source_reads_every_writer(kind: str, tmp_path: Path) -> None:
    path, written = make_bag(kind, tmp_path, 300)
    with BagSource(path) as source:
        info = source.topics['/imu/data']
        assert (info.msgtype, info.count) == (IMU, 300)
        assert info.rate_hz == pytest.approx(1000.0, rel=1e-3)
        assert (source.start_ns, source.end_ns) == (T0, T0 + 299 * PERIOD)
        assert list(source.messages(['/imu/data'])) == written
        window = list(source.messages(['/imu/data'], T0 + 100 * PERIOD, T0 + 110 * PERIOD))
        assert window == written[100:110]


def test_recorded_qos_is_exposed(tmp_path: Path) -> None:
    write_mcap_lz4(tmp_path / 'a.mcap', 3)
    with BagSource(tmp_path / 'a.mcap') as source:
        (profile,) = source.topics['/imu/data'].offered_qos
        assert (profile.depth, profile.reliability.name) == (7, 'RELIABLE')


def test_several_files_with_and_without_metadata(tmp_path: Path) -> None:
    bag = tmp_path / 'split'
    recorder = BagRecorder(bag, split_s=0.1)
    recorder.add_topic(TopicSpec('/imu/data', IMU, [record_qos(False, 5)]))
    raws = [imu_cdr(i) for i in range(500)]
    for i, raw in enumerate(raws):
        recorder.write('/imu/data', T0 + i * PERIOD, raw)
    recorder.close()
    files = sorted(bag.glob('*.mcap'))
    assert len(files) == 5
    expected = [('/imu/data', T0 + i * PERIOD, raw) for i, raw in enumerate(raws)]
    with BagSource(bag) as source:
        assert list(source.messages(['/imu/data'])) == expected
    (bag / 'metadata.yaml').unlink()
    with BagSource(bag) as source:
        assert source.topics['/imu/data'].count == 500
        assert list(source.messages(['/imu/data'])) == expected


def test_merges_topics_in_time_order(tmp_path: Path) -> None:
    strings = [bytes(typestore().serialize_cdr(typestore().types['std_msgs/msg/String'](f's{j}'),
                                               'std_msgs/msg/String')) for j in range(5)]
    written = write_rosbags(tmp_path / 'bag', 50, extra={'/note': ('std_msgs/msg/String',
                                                                   strings)})
    with BagSource(tmp_path / 'bag') as source:
        assert sorted(source.topics) == ['/imu/data', '/note']
        assert list(source.messages(['/imu/data', '/note'])) == written
        assert [m[2] for m in source.messages(['/note'])] == strings


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def _corrupt_pages(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[100:len(data) // 2] = b'\xa5' * (len(data) // 2 - 100)
    path.write_bytes(bytes(data))


def damaged_bag(kind: str, tmp: Path) -> tuple[Path, Path]:
    """(bag to open, file the message must name) for each damaged-input case."""
    if kind == 'missing':
        return tmp / 'nope', tmp / 'nope'
    if kind == 'empty-dir':
        (tmp / 'e').mkdir()
        return tmp / 'e', tmp / 'e'
    if kind == 'no-messages':
        with Writer(tmp / 'z', version=9) as writer:
            writer.add_connection('/imu/data', IMU, typestore=typestore())
        return tmp / 'z', tmp / 'z'
    if kind == 'garbage':
        (tmp / 'g.mcap').write_bytes(b'not a bag' * 50)
        return tmp / 'g.mcap', tmp / 'g.mcap'
    storage = 'sqlite3' if kind == 'corrupt-sqlite3' else 'mcap'
    write_rosbags(tmp / 'b', 2000, storage)
    (file,) = (tmp / 'b').glob('b.*[3p]')
    (_truncate if kind == 'truncated-mcap' else _corrupt_pages)(file)
    return tmp / 'b', tmp / 'b'


@pytest.mark.parametrize('kind', ['missing', 'empty-dir', 'no-messages', 'garbage',
                                  'truncated-mcap', 'corrupt-sqlite3'])
def test_bad_bags_raise_input_error_naming_the_file(kind: str, tmp_path: Path) -> None:
    path, named = damaged_bag(kind, tmp_path)
    with pytest.raises(InputError) as err, BagSource(path) as source:
        list(source.messages(list(source.topics)))
    message = str(err.value)
    assert message.startswith(f'{named}:') and '\n' not in message


def test_recording_opens_with_rosbags_and_mcap(tmp_path: Path) -> None:
    bag = tmp_path / 'rec'
    recorder = BagRecorder(bag, split_s=0.25)
    digest = typestore().hash_rihs01(IMU)
    recorder.add_topic(TopicSpec('/imu/data', IMU, [record_qos(False, 5)], digest))
    raws = [imu_cdr(i) for i in range(600)]
    for i, raw in enumerate(raws):
        recorder.write('/imu/data', T0 + i * PERIOD, raw)
        if i == 300:
            recorder.tick(T0 + i * PERIOD)
    recorder.close()
    assert recorder.message_count == 600
    files = sorted(bag.glob('*.mcap'), key=lambda p: int(p.stem.rsplit('_', 1)[1]))
    assert [p.name for p in files] == ['rec_0.mcap', 'rec_1.mcap', 'rec_2.mcap']
    assert [r[2] for r in read_mcap_raw(files)] == raws
    for file in files:
        with open(file, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            assert reader.get_header().profile == 'ros2'
            for _, channel, _, msg in reader.iter_decoded_messages():
                assert channel.message_encoding == 'cdr'
                assert msg.linear_acceleration.y == -0.2
                assert msg.header.frame_id == 'imu_link'
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['message_count'] == 600 and meta['relative_file_paths'] == [p.name for p in files]
    with AnyReader([bag], default_typestore=typestore()) as reader:
        (conn,) = reader.connections
        assert conn.ext.offered_qos_profiles == [record_qos(False, 5)]
        assert conn.digest == digest
        values = [reader.deserialize(raw, IMU).linear_acceleration.z
                  for _, _, raw in reader.messages()]
    assert values == list(range(600))


def test_recorder_refuses_existing_and_unwritable_outputs(tmp_path: Path) -> None:
    (tmp_path / 'there').mkdir()
    with pytest.raises(ConfigError, match=f'^{tmp_path / "there"}: output already exists'):
        BagRecorder(tmp_path / 'there')
    blocker = tmp_path / 'file'
    blocker.write_text('x')
    with pytest.raises(ConfigError, match=f'^{blocker / "bag"}: cannot create the bag'):
        BagRecorder(blocker / 'bag')


FULL_DISK = textwrap.dedent('''
    import resource, sys
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.playback.recording import BagRecorder, TopicSpec
    resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))  # every file <= 200 kB
    rec = BagRecorder(sys.argv[1], split_s=0.2, compress=False)
    rec.add_topic(TopicSpec('/raw', 'std_msgs/msg/String'))
    try:
        for i in range(10**6):  # 1 kHz: 300 small messages, then 64 kB ones
            rec.write('/raw', 10**9 + i * 10**6, bytes([i % 256]) * (512 if i < 300 else 65536))
            if i % 10 == 0:
                rec.tick(10**9 + i * 10**6)
    except ConfigError as exc:
        print(exc)
''')


def test_write_error_keeps_finished_files_readable(tmp_path: Path) -> None:
    """A file-size limit (as a full disk) stops the recorder; the finished file stays readable."""
    bag = tmp_path / 'full'
    out = subprocess.run([sys.executable, '-c', FULL_DISK, str(bag)], capture_output=True,
                         text=True, timeout=60, check=True).stdout.strip()
    assert out.startswith(f'{bag / "full_1.mcap"}: write failed (')
    assert out.endswith('200 messages in 1 finished file(s) of ' f'{bag} stay readable')
    assert (bag / 'full_1.mcap.partial').exists()
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:  # raw bytes (not Strings: BagSource would skip them)
        raws = [bytes(raw) for _, _, raw in reader.messages()]
    assert raws == [bytes([i]) * 512 for i in range(200)]
