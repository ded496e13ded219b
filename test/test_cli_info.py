"""``railgsa info BAG``: counts, rates, gaps, GNSS and storage of bags whose contents the test
chose, written by the project's writer (MCAP and sqlite3) and by mcap_ros2 (an independent
writer); bad input is one line and exit 2."""

from __future__ import annotations

from datetime import UTC, datetime
import json
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType
from mcap_ros2.writer import Writer as McapRos2Writer
import numpy as np
import pytest

from railgsa_ros.bag import BagWriter
from railgsa_ros.bag.messages import typestore
from railgsa_ros.cli.main import main

T0 = 1_700_000_000_000_000_000  #: ns, the first IMU stamp
IMU_PERIOD = 2_000_000  #: ns: 500 Hz
DROPPED = np.r_[700:710, 1500:1503]  #: IMU samples not written: gaps of 11 and 4 periods
LATENCY = 1_000_000  #: ns from a header stamp to its log time
FIX_PERIOD = 200_000_000  #: ns: 5 Hz
FIX_STATUS = np.array([-1] * 3 + [0] * 15 + [1] * 2)  #: no fix, then fix, then SBAS


def stamp(store: Any, ns: int) -> Any:
    time = store.types['builtin_interfaces/msg/Time']
    return store.types['std_msgs/msg/Header'](stamp=time(sec=ns // 10**9, nanosec=ns % 10**9),
                                              frame_id='f')


def imu(store: Any, ns: int) -> Any:
    t = store.types
    vec, quat = t['geometry_msgs/msg/Vector3'], t['geometry_msgs/msg/Quaternion']
    return t['sensor_msgs/msg/Imu'](
        header=stamp(store, ns), orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.r_[-1.0, np.zeros(8)],
        angular_velocity=vec(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vec(x=0.0, y=0.0, z=9.81),
        linear_acceleration_covariance=np.zeros(9))


def fix(store: Any, ns: int, status: int, k: int) -> Any:
    t = store.types
    return t['sensor_msgs/msg/NavSatFix'](
        header=stamp(store, ns), status=t['sensor_msgs/msg/NavSatStatus'](status=status,
                                                                           service=1),
        latitude=48.0 + 1e-4 * k, longitude=11.0 + 2e-4 * k, altitude=500.0,
        position_covariance=np.zeros(9), position_covariance_type=0)


def write_bag(path: Path, storage: str, compression: str | None) -> dict[str, np.ndarray]:
    """IMU at 500 Hz (2000 samples minus DROPPED, log time = stamp + LATENCY), NavSatFix at
    5 Hz (20, FIX_STATUS), PointStamped at 100 Hz with zero stamps (400), DiagnosticArray at
    1 Hz (4); returns the log times per topic."""
    store = typestore()
    imu_stamps = np.delete(T0 + IMU_PERIOD * np.arange(2000), DROPPED)
    fixes = T0 + FIX_PERIOD * np.arange(20)
    points = T0 + 10_000_000 * np.arange(400) + 500_000
    diagnostics = T0 + 1_000_000_000 * np.arange(4) + 3_000_000
    point_t = store.types['geometry_msgs/msg/PointStamped']
    zero = store.types['geometry_msgs/msg/Point'](x=0.0, y=0.0, z=0.0)
    diag_t = store.types['diagnostic_msgs/msg/DiagnosticArray']
    with BagWriter(path, storage, compression) as writer:
        for topic, msgtype in (('/imu/data', 'sensor_msgs/msg/Imu'),
                               ('/gnss/fix', 'sensor_msgs/msg/NavSatFix'),
                               ('/unstamped', 'geometry_msgs/msg/PointStamped'),
                               ('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')):
            writer.add_topic(topic, msgtype)
        messages = [*((s + LATENCY, '/imu/data', imu(store, int(s))) for s in imu_stamps),
                    *((s, '/gnss/fix', fix(store, int(s), int(st), k))
                      for k, (s, st) in enumerate(zip(fixes, FIX_STATUS, strict=True))),
                    *((s, '/unstamped', point_t(header=stamp(store, 0), point=zero))
                      for s in points),
                    *((s, '/diagnostics', diag_t(header=stamp(store, int(s)), status=[]))
                      for s in diagnostics)]
        for log_ns, topic, msg in sorted(messages, key=lambda m: m[0]):
            writer.write(topic, int(log_ns), msg)
    return {'/imu/data': imu_stamps + LATENCY, '/gnss/fix': fixes, '/unstamped': points,
            '/diagnostics': diagnostics}


def iso(ns: int) -> str:
    return datetime.fromtimestamp(ns // 1000 / 1e6, tz=UTC).isoformat(timespec='microseconds')


@pytest.mark.parametrize(('storage', 'compression', 'shown'), [
    ('mcap', 'zstd', 'zstd (MCAP chunks)'), ('mcap', None, 'none'), ('sqlite3', None, 'none')])
def test_info_of_a_bag_the_project_wrote(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         storage: str, compression: str | None,
                                         shown: str) -> None:
    logs = write_bag(tmp_path / 'bag', storage, compression)
    assert main(['info', str(tmp_path / 'bag'), '--json']) == 0
    info = json.loads(capsys.readouterr().out)
    assert info['storage'] == storage and info['compression'] == shown
    suffix = '.mcap' if storage == 'mcap' else '.db3'
    assert [Path(name).suffix for name in info['files']] == [suffix]
    first, last = min(t[0] for t in logs.values()), max(t[-1] for t in logs.values())
    assert info['start'] == iso(first) and info['end'] == iso(last)
    assert info['duration_s'] == pytest.approx((last - first) / 1e9, abs=1e-9)
    topics = {t['topic']: t for t in info['topics']}
    assert {t: topics[t]['count'] for t in topics} == {t: len(v) for t, v in logs.items()}
    assert info['messages'] == sum(len(v) for v in logs.values())

    imu_info = topics['/imu/data']
    assert imu_info['times'] == 'header' and imu_info['msgtype'] == 'sensor_msgs/msg/Imu'
    assert imu_info['first'] == iso(T0)  # the header stamps, not the log times
    rate = imu_info['rate']
    assert rate['median_hz'] == pytest.approx(500.0)
    assert rate['max_hz'] == pytest.approx(500.0)
    assert rate['min_hz'] == pytest.approx(500.0 / 11)  # the 10 dropped samples
    assert rate['backwards'] == 0
    gaps = imu_info['gaps']
    assert gaps['count'] == 2 and gaps['threshold_s'] == pytest.approx(0.003)
    assert gaps['largest_s'] == pytest.approx(0.022)
    assert gaps['largest_after_s'] == pytest.approx(699 * 0.002)
    assert gaps['largest_at'] == iso(T0 + 699 * IMU_PERIOD)

    gnss = topics['/gnss/fix']['gnss']
    assert gnss['fixes'] == 17
    assert gnss['status'] == {'no_fix': 3, 'fix': 15, 'sbas_fix': 2}
    assert gnss['first_fix_deg'] == pytest.approx([48.0003, 11.0006])
    assert gnss['last_fix_deg'] == pytest.approx([48.0019, 11.0038])
    assert topics['/gnss/fix']['rate']['median_hz'] == pytest.approx(5.0)
    assert topics['/gnss/fix']['gaps'] is None  # gaps are the IMU's

    # zero header stamps and a type without a decoded layout: the log times
    assert topics['/unstamped']['times'] == 'log_time'
    assert topics['/unstamped']['rate']['median_hz'] == pytest.approx(100.0)
    assert topics['/diagnostics']['times'] == 'log_time'
    assert topics['/diagnostics']['rate']['median_hz'] == pytest.approx(1.0)

    assert main(['info', str(tmp_path / 'bag')]) == 0
    text = capsys.readouterr().out
    assert f'Storage id:        {storage}' in text and 'Messages:          2411' in text
    assert '/imu/data | sensor_msgs/msg/Imu | 1987 msgs | 500 Hz (min 45.4545, max 500' in text
    assert 'gaps over 1.5 periods (3 ms): 2, largest 0.022 s' in text
    assert 'GNSS: 17 fixes of 20 (no_fix 3, fix 15, sbas_fix 2); first 48.0003000, ' \
        '11.0006000; last 48.0019000, 11.0038000' in text


def imu_dict(ns: int) -> dict[str, Any]:
    """An Imu message as a plain dict for the mcap_ros2 writer."""
    zero = {'x': 0.0, 'y': 0.0, 'z': 0.0}
    return {'header': {'stamp': {'sec': ns // 10**9, 'nanosec': ns % 10**9}, 'frame_id': 'imu'},
            'orientation': {**zero, 'w': 1.0}, 'orientation_covariance': [-1.0] + [0.0] * 8,
            'angular_velocity': zero, 'angular_velocity_covariance': [0.0] * 9,
            'linear_acceleration': {**zero, 'z': 9.81},
            'linear_acceleration_covariance': [0.0] * 9}


def test_info_of_a_bare_mcap_from_an_independent_writer(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """mcap_ros2 (no metadata.yaml, lz4 chunks), IMU at 200 Hz whose log times jitter by up to
    3 ms: the rate comes from the header stamps, exact; one stamp written twice."""
    rng = np.random.default_rng(1)
    stamps = T0 + 5_000_000 * np.arange(1000)
    stamps = np.insert(stamps, 300, stamps[299])  # a repeated stamp
    logs = stamps + rng.integers(0, 3_000_000, stamps.size)
    path = tmp_path / 'foreign.mcap'
    definition = typestore().generate_msgdef('sensor_msgs/msg/Imu', ros_version=2)[0]
    with path.open('wb') as f:
        writer = McapRos2Writer(f, chunk_size=8192, compression=CompressionType.LZ4)
        schema = writer.register_msgdef('sensor_msgs/msg/Imu', definition)
        for s, log_ns in zip(stamps.tolist(), np.sort(logs).tolist(), strict=True):
            writer.write_message('/imu', schema, imu_dict(s), log_time=log_ns, publish_time=s)
        writer.finish()
    assert main(['info', str(path), '--json']) == 0
    info = json.loads(capsys.readouterr().out)
    assert info['storage'] == 'mcap' and info['compression'] == 'lz4 (MCAP chunks)'
    assert info['files'] == {'foreign.mcap': path.stat().st_size}
    (topic,) = info['topics']
    assert topic['count'] == 1001 and topic['times'] == 'header'
    assert topic['rate'] == {'median_hz': pytest.approx(200.0), 'min_hz': pytest.approx(200.0),
                             'max_hz': pytest.approx(200.0), 'backwards': 1}
    assert topic['gaps']['count'] == 0 and topic['gaps']['largest_s'] is None
    assert info['duration_s'] == pytest.approx((logs.max() - logs.min()) / 1e9, abs=1e-9)


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    text = tmp_path / 'notes.txt'
    text.write_text('not a bag')
    broken = tmp_path / 'broken.mcap'
    broken.write_bytes(b'\x89MCAP0\r\n' + bytes(100))
    for path, reason in ((tmp_path / 'missing', 'no such bag'), (text, 'not a rosbag2 bag'),
                         (broken, '')):
        assert main(['info', str(path)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f'error: {path}: {reason}') and err.count('\n') == 1, err
