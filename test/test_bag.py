"""rosbag2 I/O: CDR coding against rosbags, round trips, foreign writers, REP 145, bad bags."""

from __future__ import annotations

import io
from pathlib import Path
import shutil
from types import SimpleNamespace
import zlib

from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as McapRos2Writer
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosReliability
import zstandard

from railgsa_ros.bag import BagWriter, cdr, read_imu, read_messages, summarize, write_run
from railgsa_ros.bag import reader as reader_module
from railgsa_ros.bag.messages import IMU, IMU_FIELDS, LAYOUTS, flatten, typestore
from railgsa_ros.bag.run import sample_indices
from railgsa_ros.errors import ConfigError, InputError

TS = typestore()
T0 = 1_700_000_000_123_456_789


def make_run(n: int = 1500, rate_hz: float = 1000.0, seed: int = 0) -> SimpleNamespace:
    """A synthetic run with random values (the bag layer does not care about physics)."""
    rng = np.random.default_rng(seed)
    stamps = T0 + np.round(np.arange(n) * 1e9 / rate_hz).astype(np.int64)
    speed = 20.0 + rng.normal(0, 0.1, n)
    accel = rng.normal(0, 0.05, (n, 3)) + np.array([0, 0, 9.81])
    return SimpleNamespace(stamps_ns=stamps, accel=accel,
                           speed_mps=speed, chainage_m=np.cumsum(speed) / rate_hz,
                           truth_u_m=rng.normal(0, 1e-3, n))


def ros_msg(msgtype: str, stamp_ns: int, strings: tuple[str, ...], body: np.ndarray) -> object:
    """Build a rosbags message from a body vector, independently of cdr.encode."""
    t = TS.types
    header = t['std_msgs/msg/Header'](
        stamp=t['builtin_interfaces/msg/Time'](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id=strings[0])
    vec = t['geometry_msgs/msg/Vector3']
    quat = t['geometry_msgs/msg/Quaternion']
    if msgtype == 'sensor_msgs/msg/Imu':
        return t[msgtype](header=header, orientation=quat(*body[0:4]),
                          orientation_covariance=body[4:13].copy(),
                          angular_velocity=vec(*body[13:16]),
                          angular_velocity_covariance=body[16:25].copy(),
                          linear_acceleration=vec(*body[25:28]),
                          linear_acceleration_covariance=body[28:37].copy())
    if msgtype == 'nav_msgs/msg/Odometry':
        pose = t['geometry_msgs/msg/Pose'](position=t['geometry_msgs/msg/Point'](*body[0:3]),
                                           orientation=quat(*body[3:7]))
        twist = t['geometry_msgs/msg/Twist'](linear=vec(*body[43:46]), angular=vec(*body[46:49]))
        return t[msgtype](
            header=header, child_frame_id=strings[1],
            pose=t['geometry_msgs/msg/PoseWithCovariance'](pose=pose,
                                                           covariance=body[7:43].copy()),
            twist=t['geometry_msgs/msg/TwistWithCovariance'](twist=twist,
                                                             covariance=body[49:85].copy()))
    if msgtype == 'geometry_msgs/msg/PointStamped':
        return t[msgtype](header=header, point=t['geometry_msgs/msg/Point'](*body))
    return t[msgtype](header=header, vector=vec(*body))


STRINGS = {1: [('imu_link',), ('',), ('a',), ('bäh_ü',), ('x' * 13,)],
           2: [('odom', 'base_link'), ('', 'c'), ('map', '')]}


@pytest.mark.parametrize('msgtype', sorted(LAYOUTS))
def test_cdr_matches_rosbags(msgtype: str) -> None:
    layout = LAYOUTS[msgtype]
    rng = np.random.default_rng(1)
    stamps = np.array([0, 1, 10**9 - 1, T0, -1_500_000_000, 2**31 * 10**9 - 1], dtype=np.int64)
    for strings in STRINGS[layout.n_strings]:
        body = rng.normal(size=(stamps.size, layout.n_doubles))
        msgs = [ros_msg(msgtype, int(s), strings, b) for s, b in zip(stamps, body, strict=True)]
        ours = cdr.encode(layout, stamps, strings, body)
        theirs = [bytes(TS.serialize_cdr(m, msgtype)) for m in msgs]
        assert ours == theirs
        big_endian = [bytes(TS.serialize_cdr(m, msgtype, little_endian=False)) for m in msgs]
        mixed = [pair[i % 2] for i, pair in enumerate(zip(theirs, big_endian, strict=True))]
        for raws in (theirs, big_endian, mixed):
            dec = cdr.decode(layout, raws)
            np.testing.assert_array_equal(dec.stamps_ns, stamps[:len(raws)])
            np.testing.assert_array_equal(dec.values, body)
            for j, text in enumerate(strings):
                assert list(dec.strings[j]) == [text] * len(raws)
            assert [flatten(TS.deserialize_cdr(r, msgtype), msgtype)[0] for r in raws] == \
                list(stamps)


@settings(max_examples=60, deadline=None)
@given(frames=st.lists(st.text(st.characters(exclude_characters='\x00',
                                             exclude_categories=('Cs',)), max_size=12),
                      min_size=1, max_size=6),
       stamps=st.lists(st.integers(-2**31 * 10**9, 2**31 * 10**9 - 1), min_size=6, max_size=6),
       values=st.lists(st.floats(allow_nan=False), min_size=37, max_size=37))
def test_cdr_imu_property(frames: list[str], stamps: list[int], values: list[float]) -> None:
    """Any frame ids (unicode, empty; C strings hold no NUL), stamps and values: our bytes are
    rosbags' bytes, and a stream mixing the frame ids decodes back exactly."""
    body = np.array(values)
    raws = []
    for k, stamp in enumerate(stamps):
        frame = frames[k % len(frames)]
        ours = cdr.encode(IMU, [stamp], [frame], body)[0]
        assert ours == bytes(TS.serialize_cdr(ros_msg(IMU.msgtype, stamp, (frame,), body),
                                              IMU.msgtype))
        raws.append(ours)
    dec = cdr.decode(IMU, raws)
    assert dec.stamps_ns.tolist() == stamps
    assert dec.strings[0].tolist() == [frames[k % len(frames)] for k in range(6)]
    np.testing.assert_array_equal(dec.values, np.tile(body, (6, 1)))


@settings(max_examples=150, deadline=None)
@given(data=st.data(), n=st.integers(1, cdr.FEW))
def test_cdr_few_messages_decode_as_the_vectorised_path(data: st.DataObject, n: int) -> None:
    """Up to FEW messages are read one by one: the same stamps, strings and values as the
    vectorised path, and a ValueError exactly where it raises (any endianness, frame ids,
    truncations and overwritten bytes, e.g. a string length past the end)."""
    raws = []
    for _ in range(n):
        frame = data.draw(st.sampled_from(['imu_link', '', 'bäh_ü', 'x' * 13]))
        stamp = data.draw(st.integers(-2**31 * 10**9, 2**31 * 10**9 - 1))
        msg = ros_msg(IMU.msgtype, stamp, (frame,), np.arange(IMU.n_doubles, dtype=float))
        raw = bytearray(TS.serialize_cdr(msg, IMU.msgtype,
                                         little_endian=data.draw(st.booleans())))
        for _ in range(data.draw(st.integers(0, 2))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        raws.append(bytes(raw[:data.draw(st.integers(0, len(raw)))]
                          if data.draw(st.booleans()) else raw))

    def decoded(few: int) -> tuple | str:
        cdr.FEW = few
        try:
            d = cdr.decode(IMU, raws)
        except ValueError:
            return 'ValueError'
        finally:
            cdr.FEW = few_default
        return (d.stamps_ns.tolist(), d.nanosec.tolist(), [t.tolist() for t in d.strings],
                d.values.tobytes() if d.values.dtype == '<f8' else
                d.values.astype('<f8').tobytes())

    few_default = cdr.FEW
    assert decoded(few_default) == decoded(0)


def test_cdr_decodes_mixed_frame_ids_and_rejects_other_encodings() -> None:
    body = np.arange(IMU.n_doubles, dtype=float)
    frames = ['imu_link', 'imu', 'imu_link', 'a_much_longer_frame_name', 'imu']
    raws = [bytes(TS.serialize_cdr(ros_msg(IMU.msgtype, i, (f,), body + i), IMU.msgtype))
            for i, f in enumerate(frames)]
    dec = cdr.decode(IMU, raws)
    assert list(dec.strings[0]) == frames
    np.testing.assert_array_equal(dec.values, body + np.arange(5)[:, None])
    xcdr2 = b'\x00\x07' + raws[0][2:]
    with pytest.raises(ValueError):
        cdr.decode(IMU, [raws[0], xcdr2])
    with pytest.raises(ValueError):
        cdr.decode(IMU, [raws[0][:40]])
    with pytest.raises(ValueError):
        cdr.split_stamps(np.array([2**31 * 10**9]))
    assert cdr.encode(IMU, np.zeros(0, np.int64), ['imu_link'], np.zeros((0, 37))) == []


@pytest.mark.parametrize(('storage', 'compression'),
                         [('mcap', 'zstd'), ('mcap', None), ('sqlite3', None)])
def test_write_run_round_trip(tmp_path: Path, storage: str, compression: str | None) -> None:
    run = make_run()
    path = write_run(tmp_path / 'bag', run, storage, compression, accel_variance=2.5e-5)
    assert (path / 'metadata.yaml').is_file()
    assert sorted(p.suffix for p in path.iterdir()) == sorted(
        ['.yaml', '.mcap' if storage == 'mcap' else '.db3'])
    stream = read_imu(path)
    np.testing.assert_array_equal(stream.stamps_ns, run.stamps_ns)
    np.testing.assert_array_equal(stream.log_time_ns, run.stamps_ns)
    np.testing.assert_array_equal(stream.accel, run.accel)
    assert set(stream.frame_ids) == {'imu_link'}
    np.testing.assert_array_equal(stream.accel_variance(1.0), np.full((1500, 3), 2.5e-5))
    odom_idx = sample_indices(run.stamps_ns, 50.0)
    assert odom_idx.size == 75
    np.testing.assert_array_equal(stream.odom_stamps_ns, run.stamps_ns[odom_idx])
    np.testing.assert_array_equal(stream.speed_mps, run.speed_mps[odom_idx])

    # Independent check with rosbags' own deserialiser and the bag's message definitions.
    with AnyReader([path]) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
        truth = [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()
                 if c.topic == '/track/irregularity_truth']
        imu = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
               if c.topic == '/imu/data']
    assert qos['/imu/data'].reliability == QosReliability.BEST_EFFORT
    assert qos['/imu/data'].depth >= 300
    assert qos['/odom'].reliability == QosReliability.RELIABLE
    assert qos['/track/irregularity_truth'].reliability == QosReliability.RELIABLE
    np.testing.assert_array_equal([m.point.x for _, m in truth], run.chainage_m)
    np.testing.assert_array_equal([m.point.z for _, m in truth], run.truth_u_m)
    assert {m.header.frame_id for _, m in truth} == {'track'}
    np.testing.assert_array_equal([t for t, _ in truth], run.stamps_ns)
    assert imu[0].orientation_covariance[0] == -1 and imu[0].orientation.w == 1
    assert imu[0].angular_velocity_covariance[0] == -1
    np.testing.assert_array_equal(imu[7].linear_acceleration_covariance,
                                  np.diag([2.5e-5] * 3).ravel())

    if storage == 'mcap':
        (mcap_file,) = path.glob('*.mcap')
        with mcap_file.open('rb') as f:
            decoded = list(make_reader(f, decoder_factories=[DecoderFactory()])
                           .iter_decoded_messages(topics=['/imu/data']))
        got = np.array([[m.decoded_message.linear_acceleration.x,
                         m.decoded_message.linear_acceleration.y,
                         m.decoded_message.linear_acceleration.z] for m in decoded])
        np.testing.assert_array_equal(got, run.accel)
        assert [m.decoded_message.header.frame_id for m in decoded[:3]] == ['imu_link'] * 3


def _imu_dict(stamp_ns: int, acc: np.ndarray, cov0: float, frame: str = 'imu_front') -> dict:
    """An Imu message as a plain dict for the mcap_ros2 writer."""
    cov = [cov0, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
    vec = dict(zip('xyz', map(float, acc), strict=True))
    return {'header': {'stamp': {'sec': stamp_ns // 10**9, 'nanosec': stamp_ns % 10**9},
                       'frame_id': frame},
            'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
            'orientation_covariance': [-1.0] + [0.0] * 8,
            'angular_velocity': {'x': 0.0, 'y': 0.0, 'z': 0.0},
            'angular_velocity_covariance': [0.0] * 9,
            'linear_acceleration': vec, 'linear_acceleration_covariance': cov}


def write_foreign_mcap(path: Path, stamps: np.ndarray, acc: np.ndarray,
                       cov0: np.ndarray) -> None:
    """A bare Imu .mcap by mcap_ros2 (zstd, small chunks); log time = stamp + 2 ms."""
    with path.open('wb') as f:
        writer = McapRos2Writer(f, chunk_size=4096)
        schema = writer.register_msgdef(
            IMU.msgtype, TS.generate_msgdef(IMU.msgtype, ros_version=2)[0])
        for s, a, c in zip(stamps.tolist(), acc, cov0, strict=True):
            writer.write_message('/imu/data', schema, _imu_dict(s, a, float(c)),
                                 log_time=s + 2_000_000, publish_time=s)
        writer.finish()


def test_reads_bare_mcap_from_mcap_ros2_writer_with_rep145_sentinels(tmp_path: Path) -> None:
    n = 400
    rng = np.random.default_rng(3)
    stamps = T0 + np.arange(n, dtype=np.int64) * 2_500_000
    acc = rng.normal(size=(n, 3))
    cov0 = np.full(n, 1e-4)
    cov0[10] = -1.0      # REP 145 / Imu.msg: field absent
    cov0[20] = np.nan    # REP 145 text: field absent
    cov0[30] = 0.0       # with the other diagonal entries non-zero: known
    path = tmp_path / 'foreign.mcap'
    write_foreign_mcap(path, stamps, acc, cov0)
    stream = read_imu(path)
    np.testing.assert_array_equal(stream.stamps_ns, stamps)
    np.testing.assert_array_equal(stream.log_time_ns, stamps + 2_000_000)
    absent = np.isin(np.arange(n), [10, 20])
    assert np.all(np.isnan(stream.accel[absent]))
    np.testing.assert_array_equal(stream.accel[~absent], acc[~absent])
    assert set(stream.frame_ids) == {'imu_front'}
    assert stream.speed_mps.size == 0 and stream.odom_stamps_ns.size == 0
    var = stream.accel_variance(7.0)
    assert np.all(np.isnan(var[absent]))
    np.testing.assert_array_equal(var[0], [1e-4, 1e-4, 1e-4])
    # A bag directory without metadata.yaml holding the same file reads the same.
    bare_dir = tmp_path / 'no_metadata'
    bare_dir.mkdir()
    shutil.copy(path, bare_dir / 'foreign_0.mcap')
    np.testing.assert_array_equal(read_imu(bare_dir).accel, stream.accel)
    # Every field absent: no acceleration at all.
    write_foreign_mcap(tmp_path / 'none.mcap', stamps[:5], acc[:5], np.full(5, -1.0))
    with pytest.raises(InputError, match=r'none\.mcap: /imu/data carries no linear acceleration'):
        read_imu(tmp_path / 'none.mcap')


def test_unknown_covariance_and_unstamped_headers(tmp_path: Path) -> None:
    path = write_run(tmp_path / 'unknown', make_run(200), 'mcap', accel_variance=0.0)
    stream = read_imu(path)
    assert stream.stamp_source == 'header'
    np.testing.assert_array_equal(stream.accel_variance(3e-3), np.full((200, 3), 3e-3))
    # Messages with zero header stamps but real log times: the log time is used.
    with BagWriter(tmp_path / 'logtime', 'sqlite3') as bag:
        bag.add_topic('/imu/data', IMU.msgtype)
        body = np.zeros(IMU.n_doubles)
        body[IMU_FIELDS['linear_acceleration']] = (0.0, 0.0, 9.81)
        for k in range(5):
            bag.write('/imu/data', T0 + k * 10**6, ros_msg(IMU.msgtype, 0, ('imu_link',), body))
    stream = read_imu(tmp_path / 'logtime', odom_topic=None)
    assert stream.stamp_source == 'log_time'
    np.testing.assert_array_equal(stream.stamps_ns, T0 + np.arange(5) * 10**6)
    (db3,) = (tmp_path / 'logtime').glob('*.db3')
    np.testing.assert_array_equal(read_imu(db3).accel[:, 2], np.full(5, 9.81))


def test_bag_writer_arbitrary_messages_and_general_reader(tmp_path: Path) -> None:
    t = TS.types
    status = t['diagnostic_msgs/msg/DiagnosticStatus'](
        level=1, name='imu: rate', message='low', hardware_id='sim',
        values=[t['diagnostic_msgs/msg/KeyValue'](key='rate_hz', value='998.1')])
    diag = t['diagnostic_msgs/msg/DiagnosticArray'](
        header=ros_msg('geometry_msgs/msg/PointStamped', 5, ('',), np.zeros(3)).header,
        status=[status])
    vec = ros_msg('geometry_msgs/msg/Vector3Stamped', 7, ('base_link',), np.array([1.0, 2, 3]))
    with BagWriter(tmp_path / 'any', 'mcap', 'zstd') as bag:
        bag.add_topic('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')
        bag.add_topic('/v', 'geometry_msgs/msg/Vector3Stamped')
        bag.write('/v', 7, vec)
        bag.write('/diagnostics', 5, diag)
        with pytest.raises(ConfigError, match='added twice'):
            bag.add_topic('/v', 'geometry_msgs/msg/Vector3Stamped')
    got = list(read_messages(tmp_path / 'any'))
    assert [(topic, stamp) for topic, stamp, _ in got] == [('/diagnostics', 5), ('/v', 7)]
    assert got[0][2].status[0].values[0].value == '998.1'
    assert got[0][2].status[0].level == 1
    assert (got[1][2].vector.x, got[1][2].vector.z) == (1.0, 3.0)
    assert [(s.topic, s.count) for s in summarize(tmp_path / 'any')] == [('/diagnostics', 1),
                                                                         ('/v', 1)]
    assert [x[0] for x in read_messages(tmp_path / 'any', topics=['/v'])] == ['/v']


def test_bag_writer_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    run = make_run(50)
    with pytest.raises(RuntimeError, match='boom'), BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/imu/data', IMU.msgtype)
        bag.write('/imu/data', 1, cdr.encode(IMU, [1], ['imu_link'], np.zeros(37))[0])
        raise RuntimeError('boom')
    assert list(tmp_path.iterdir()) == []
    write_run(tmp_path / 'b', run)
    with pytest.raises(ConfigError, match=r'b: already exists'):
        write_run(tmp_path / 'b', run)
    run.accel = run.accel + 1.0
    write_run(tmp_path / 'b', run, 'sqlite3', overwrite=True)
    np.testing.assert_array_equal(read_imu(tmp_path / 'b').accel, run.accel)
    assert [p.name for p in tmp_path.iterdir()] == ['b']
    parent_is_file = tmp_path / 'b' / 'metadata.yaml' / 'x'
    with pytest.raises(ConfigError, match=r'metadata\.yaml/x: cannot write'):
        write_run(parent_is_file, run)
    def disk_full(*args: object) -> None:
        raise OSError(28, 'No space left on device')

    with monkeypatch.context() as m:
        m.setattr('railgsa_ros.bag.mcap_storage.McapStorage._emit', disk_full)
        with pytest.raises(ConfigError, match=r'c: cannot write \(No space left on device\)'):
            write_run(tmp_path / 'c', run)
    assert [p.name for p in tmp_path.iterdir()] == ['b']
    with pytest.raises(ConfigError, match='zstd needs the mcap storage'):
        BagWriter(tmp_path / 'c', 'sqlite3', 'zstd')
    with pytest.raises(ConfigError, match='storage'):
        BagWriter(tmp_path / 'c', 'rosbag1')


def _bad_bags(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name -> (path, expected message fragment) for unusable inputs."""
    good = write_run(tmp_path / 'good', make_run(300), 'mcap', 'zstd')
    (mcap_file,) = good.glob('*.mcap')
    data = mcap_file.read_bytes()
    truncated = tmp_path / 'truncated.mcap'
    truncated.write_bytes(data[:len(data) // 2])
    corrupt = tmp_path / 'corrupt.mcap'
    corrupt.write_bytes(data[:200] + bytes(len(data) - 400) + data[-200:])
    garbage_db3 = tmp_path / 'garbage.db3'
    garbage_db3.write_bytes(b'this is not sqlite' * 100)
    empty_dir = tmp_path / 'empty_dir'
    empty_dir.mkdir()
    with BagWriter(tmp_path / 'empty_topic') as bag:
        bag.add_topic('/imu/data', IMU.msgtype)
    with BagWriter(tmp_path / 'wrong_type') as bag:
        bag.add_topic('/imu/data', 'geometry_msgs/msg/Vector3Stamped')
    text = tmp_path / 'notes.txt'
    text.write_text('hello')
    return {
        'missing': (tmp_path / 'nope', 'no such bag'),
        'text file': (text, 'not a rosbag2 bag'),
        'empty dir': (empty_dir, 'not a rosbag2 bag'),
        'truncated': (truncated, 'unfinished (no MCAP footer'),
        'corrupt': (corrupt, 'unreadable bag'),
        'garbage db3': (garbage_db3, 'unreadable bag'),
        'empty topic': (tmp_path / 'empty_topic', 'has no messages'),
        'wrong type': (tmp_path / 'wrong_type', 'has type geometry_msgs/msg/Vector3Stamped'),
        'missing topic': (good, 'no topic /imu/raw (topics: /imu/data, /odom, '
                                '/track/irregularity_truth)'),
    }


def test_bad_bags_raise_input_error_naming_the_file(tmp_path: Path) -> None:
    for name, (path, fragment) in _bad_bags(tmp_path).items():
        topic = '/imu/raw' if name == 'missing topic' else '/imu/data'
        with pytest.raises(InputError) as info:
            read_imu(path, imu_topic=topic)
        message = str(info.value)
        assert message.startswith(str(path)), name
        assert fragment in message, (name, message)
        assert '\n' not in message, name


def test_sample_indices_at_odometry_rate() -> None:
    stamps = np.arange(0, 2_000_000_000, 1_000_000, dtype=np.int64)  # 2 s at 1 kHz
    idx = sample_indices(stamps, 50.0)
    np.testing.assert_array_equal(idx, np.arange(0, 2000, 20))
    jittered = stamps + np.random.default_rng(0).integers(-200_000, 200_000, stamps.size)
    idx = sample_indices(np.sort(jittered), 50.0)
    assert 99 <= idx.size <= 100
    assert np.all(np.diff(idx) >= 19) and np.all(np.diff(idx) <= 21)
    assert sample_indices(np.zeros(0, dtype=np.int64), 50.0).size == 0


def test_example_bag_matches_its_command(tmp_path: Path) -> None:
    from railgsa_ros.bag import TRUTH_TOPIC, read_stamped
    from railgsa_ros.cli.main import main

    bags = Path(__file__).resolve().parents[1] / 'bags'
    (command,) = [line.split() for line in (bags / 'README.md').read_text().splitlines()
                  if line.startswith('railgsa simulate ')]
    argv = command[1:]
    out = argv.index('--out') + 1
    original = bags / Path(argv[out]).name
    assert sum(f.stat().st_size for f in original.iterdir()) < 5e6
    argv[out] = str(tmp_path / 'again')
    assert main(argv) == 0
    old, new = read_imu(original), read_imu(tmp_path / 'again')
    assert old.accel.shape == (20_000, 3)
    for field in ('stamps_ns', 'accel', 'covariance', 'odom_stamps_ns', 'speed_mps'):
        np.testing.assert_array_equal(getattr(old, field), getattr(new, field), err_msg=field)
    truth_old = read_stamped(original, TRUTH_TOPIC, 'geometry_msgs/msg/PointStamped')
    truth_new = read_stamped(tmp_path / 'again', TRUTH_TOPIC, 'geometry_msgs/msg/PointStamped')
    np.testing.assert_array_equal(truth_old.values, truth_new.values)
    assert np.ptp(truth_old.values[:, 2]) > 4e-3  # the 4 mm dip is in it


def test_directory_of_split_files_without_metadata(tmp_path: Path) -> None:
    first, second = make_run(300, seed=1), make_run(300, seed=2)
    second.stamps_ns = second.stamps_ns + 300_000_000
    split = tmp_path / 'split'
    split.mkdir()
    for k, run in enumerate((first, second)):
        bag = write_run(tmp_path / f'part{k}', run)
        shutil.copy(next(bag.glob('*.mcap')), split / f'split_{k}.mcap')
    stream = read_imu(split)
    np.testing.assert_array_equal(stream.stamps_ns, np.r_[first.stamps_ns, second.stamps_ns])
    np.testing.assert_array_equal(stream.accel, np.r_[first.accel, second.accel])


def test_write_run_in_chunks_equals_one_piece(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    run = make_run(1000)
    whole = write_run(tmp_path / 'whole', run, 'sqlite3')
    monkeypatch.setattr('railgsa_ros.bag.run.WRITE_CHUNK', 64)
    chunked = write_run(tmp_path / 'chunked', run, 'sqlite3')
    a, b = list(read_messages(whole)), list(read_messages(chunked))
    assert [(t, s) for t, s, _ in a] == [(t, s) for t, s, _ in b]
    assert [s for _, s, _ in b] == sorted(s for _, s, _ in b)
    assert sum(topic == '/odom' for topic, _, _ in b) == 50  # 1 s at 50 Hz


@pytest.mark.parametrize('kind', ['write_run zstd', 'mcap_ros2 writer', 'split files',
                                  'unlisted file'])
def test_mcap_fast_path_reads_what_rosbags_reads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 kind: str) -> None:
    run = make_run(700)
    if kind == 'write_run zstd':  # channels at top level, message indexes after each chunk
        path = write_run(tmp_path / 'bag', run, 'mcap', 'zstd', accel_variance=1e-4)
    elif kind == 'mcap_ros2 writer':  # small zstd chunks holding their own channels
        path = tmp_path / 'foreign.mcap'
        cov0 = np.where(np.arange(700) % 50 == 3, -1.0, 1e-4)
        write_foreign_mcap(path, run.stamps_ns, run.accel, cov0)
    elif kind == 'unlisted file':  # a stray .mcap next to the one metadata.yaml lists
        path = write_run(tmp_path / 'bag', run)
        stray = write_run(tmp_path / 'other', make_run(100, seed=9))
        shutil.copy(next(stray.glob('*.mcap')), path / 'stray.mcap')
    else:  # two files, the later one first by name: log-time order across files
        path = tmp_path / 'split'
        path.mkdir()
        for k, sl in enumerate((slice(350, None), slice(None, 350))):
            part = SimpleNamespace(**{k_: v[sl] for k_, v in vars(run).items()})
            bag = write_run(tmp_path / f'part{k}', part)
            shutil.copy(next(bag.glob('*.mcap')), path / f'split_{k}.mcap')
    fast_calls = []
    fast_path = reader_module._mcap_topics
    monkeypatch.setattr(reader_module, '_mcap_topics',
                        lambda *a: fast_calls.append(fast_path(*a)) or fast_calls[-1])
    fast = read_imu(path)
    assert len(fast_calls) == 1  # the fast path read it: no fallback
    monkeypatch.setattr(reader_module, '_mcap_files', lambda p: None)
    slow = read_imu(path)
    for name in ('stamps_ns', 'log_time_ns', 'accel', 'frame_ids', 'covariance',
                 'odom_stamps_ns', 'speed_mps'):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    assert fast.stamps_ns.size == 700


def test_block_writer_writes_an_indexed_mcap_with_crcs_read_back_by_rosbags(
        tmp_path: Path) -> None:
    # Blocks of rows (two chunks of Imu), messages of varying length given as bytes, and single
    # writes after them: every reader sees the same messages in log-time order (ties: topic
    # order), and every CRC the file stores is the CRC-32 of what it covers (computed here).
    n = 6000
    stamps = T0 + np.arange(n, dtype=np.int64) * 1_000_000
    imu = cdr.encode_rows(IMU, stamps, ['imu_link'], np.random.default_rng(1).normal(size=(n, 37)))
    varied = [bytes([k % 251]) * (k % 7 + 3) for k in range(0, n, 10)]
    with BagWriter(tmp_path / 'b', 'mcap', 'zstd') as bag:
        bag.add_topic('/imu/data', IMU.msgtype)
        bag.add_topic('/v', 'std_msgs/msg/String')
        bag.write_batches({'/imu/data': (stamps, imu), '/v': (stamps[::10], varied)})
        bag.write('/v', int(stamps[-1]) + 5, b'\x00\x01\x00\x00late')
    expected = sorted([(int(t), 0, k, '/imu/data', imu[k].tobytes())
                       for k, t in enumerate(stamps)]
                      + [(int(t), 1, k, '/v', r) for k, (t, r) in enumerate(zip(
                          stamps[::10], varied, strict=True))]
                      + [(int(stamps[-1]) + 5, 1, n, '/v', b'\x00\x01\x00\x00late')])
    with AnyReader([tmp_path / 'b']) as reader:
        got = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
    assert got == [(topic, t, raw) for t, _, _, topic, raw in expected]
    stream = read_imu(tmp_path / 'b')
    np.testing.assert_array_equal(stream.stamps_ns, stamps)
    np.testing.assert_array_equal(stream.accel, cdr.decode(IMU, [r.tobytes() for r in imu])
                                  .values[:, 25:28])

    (file,) = (tmp_path / 'b').glob('*.mcap')
    data = file.read_bytes()
    with file.open('rb') as f:
        reader = make_reader(f, validate_crcs=True)
        assert sum(1 for _ in reader.iter_messages()) == len(expected)
        summary = reader.get_summary()
    assert summary.statistics.message_count == len(expected)
    assert len(summary.chunk_indexes) >= 2
    for index in summary.chunk_indexes:
        at = index.chunk_start_offset + 9
        chunk = Chunk.read(ReadDataStream(io.BytesIO(
            data[at:index.chunk_start_offset + index.chunk_length])))
        raw = zstandard.ZstdDecompressor().decompress(chunk.data,
                                                      max_output_size=chunk.uncompressed_size)
        assert chunk.uncompressed_crc == zlib.crc32(raw) != 0
    data_end = int.from_bytes(data[-28:-20], 'little') - 13  # DataEnd record before the summary
    assert data[data_end] == 0x0F
    assert int.from_bytes(data[data_end + 9:data_end + 13], 'little') == zlib.crc32(
        data[:data_end])
