"""The railgsa command line: discovery, fast help, simulate/bode/demo, errors and exit codes."""

from __future__ import annotations

from pathlib import Path
import pkgutil
import re
import subprocess
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from railgsa_ros import cli
from railgsa_ros.bag import read_imu, read_stamped
from railgsa_ros.bag.messages import POINT_STAMPED
from railgsa_ros.cli import simulate
from railgsa_ros.cli.main import main
from railgsa_ros.scenario import run_scenario

HEAVY = ('numpy', 'scipy', 'matplotlib', 'rosbags', 'rclpy', 'mcap')


def railgsa(*args: str) -> subprocess.CompletedProcess:
    """Run ``python -m railgsa_ros.cli.main`` as a user would."""
    return subprocess.run([sys.executable, '-m', 'railgsa_ros.cli.main', *args],
                          capture_output=True, text=True, timeout=120)


def test_help_lists_every_subcommand_without_heavy_imports() -> None:
    modules = sorted(m.name.replace('_', '-') for m in pkgutil.iter_modules(cli.__path__)
                     if m.name != 'main' and not m.name.startswith('_'))
    assert {'bode', 'demo', 'simulate'} <= set(modules)
    result = railgsa('--help')
    assert result.returncode == 0
    listed = set(re.findall(r'^    ([\w-]+)', result.stdout, re.MULTILINE))
    assert set(modules) <= listed
    probe = ('import sys; from railgsa_ros.cli.main import build_parser; build_parser(); '
             f'print(sorted(m for m in {HEAVY!r} if m in sys.modules))')
    loaded = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True,
                            check=True).stdout.strip()
    assert loaded == '[]'


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_simulate_writes_the_scenario(tmp_path: Path, storage: str) -> None:
    out = tmp_path / 'run'
    args = ['--profile', 'german-high', '--speed', '25', '--duration', '3', '--rate', '500',
            '--sensor', 'adxl355', '--seed', '7', '--defects', 'dip@30:len=6:depth=0.003',
            '--odom-rate', '25', '--start-time', '100']
    assert main(['simulate', '--out', str(out), '--storage', storage, *args]) == 0
    run = run_scenario('german-high', 25.0, 3.0, 500.0, 'adxl355', 7,
                       defects='dip@30:len=6:depth=0.003', start_ns=100 * 10**9)
    with AnyReader([out]) as reader:
        msgs: dict[str, list] = {}
        for conn, t, raw in reader.messages():
            msgs.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    imu = msgs['/imu/data']
    assert [t for t, _ in imu] == run.stamps_ns.tolist()
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in imu]
    assert stamps == run.stamps_ns.tolist()
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                    for _, m in imu])
    np.testing.assert_array_equal(acc, run.accel)
    first = imu[0][1]
    assert first.header.frame_id == 'imu_link'
    assert first.orientation_covariance[0] == -1
    np.testing.assert_allclose(first.linear_acceleration_covariance[[0, 4, 8]],
                               run.accel_covariance, rtol=1e-15)
    truth = msgs['/track/irregularity_truth']
    np.testing.assert_array_equal([m.point.x for _, m in truth], run.chainage_m)
    np.testing.assert_array_equal([m.point.z for _, m in truth], run.truth_u_m)
    odom = msgs['/odom']
    assert len(odom) == pytest.approx(3 * 25, abs=2)
    np.testing.assert_array_equal([m.twist.twist.linear.x for _, m in odom], 25.0)
    if storage == 'mcap':
        (mcap_file,) = out.glob('*.mcap')
        with mcap_file.open('rb') as f:
            decoded = [(m.channel.topic, m.decoded_message) for m in make_reader(
                f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
        mz = [m.linear_acceleration.z for topic, m in decoded if topic == '/imu/data']
        np.testing.assert_array_equal(mz, run.accel[:, 2])
        tz = [m.point.z for topic, m in decoded if topic == '/track/irregularity_truth']
        np.testing.assert_array_equal(tz, run.truth_u_m)


def test_simulate_summary_and_bad_arguments(tmp_path: Path,
                                            capsys: pytest.CaptureFixture) -> None:
    ok = railgsa('simulate', '--out', str(tmp_path / 'ok'), '--duration', '1', '--profile',
                 'paper', '--speed', '10', '--sensor', 'ideal')
    assert ok.returncode == 0, ok.stderr
    assert '/imu/data' in ok.stdout and 'sensor_msgs/msg/Imu' in ok.stdout
    assert len(ok.stdout.splitlines()) <= 24
    bad_yaml = tmp_path / 'vehicle.yaml'
    bad_yaml.write_text('vehicle: {m_s: -1, m_us: 1100, k_s: 2.13e+6, k_us: 1.42e+8, c: 1.2e+5}')
    blocker = tmp_path / 'a_file'
    blocker.write_text('x')
    cases = {
        ('--speed', '-3'): '--speed',
        ('--duration', 'nan'): '--duration',
        ('--sensor', 'lis3dh'): 'lis3dh',
        ('--profile', 'swiss-9'): 'swiss-9',
        ('--profile', 'file:/no/such.csv'): '/no/such.csv',
        ('--defects', 'crater@5'): 'crater',
        ('--vehicle', str(bad_yaml)): 'm_s',
        ('--storage', 'sqlite3', '--compression', 'zstd'): 'zstd',
        ('--out', str(tmp_path / 'ok')): 'already exists',
        ('--out', str(blocker / 'bag')): 'a_file/bag',
    }
    before = sorted(p.name for p in tmp_path.iterdir())
    for extra, fragment in cases.items():
        argv = ['simulate', '--duration', '1', '--out', str(tmp_path / 'new'), *extra]
        assert main(argv) == 2, extra
        err = capsys.readouterr().err
        assert err.startswith('error: ') and fragment in err, (extra, err)
        assert len(err.strip().splitlines()) == 1, extra
        assert sorted(p.name for p in tmp_path.iterdir()) == before, extra
    # The installed entry point: one line, no traceback.
    result = railgsa('simulate', '--out', str(tmp_path / 'new'), '--sensor', 'lis3dh')
    assert result.returncode == 2
    assert result.stderr.startswith('error: ') and 'lis3dh' in result.stderr
    assert result.stderr.count('\n') == 1 and 'Traceback' not in result.stderr
    with pytest.raises(SystemExit) as usage:
        main(['simulate', '--out', str(tmp_path / 'new'), '--speed', 'fast'])
    assert usage.value.code == 2 and "invalid float value: 'fast'" in capsys.readouterr().err


def test_keyboard_interrupt_exits_130_and_leaves_nothing(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture) -> None:
    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr('railgsa_ros.bag.run.RunEncoder.encode_rows', interrupted)
    assert main(['simulate', '--out', str(tmp_path / 'b'), '--duration', '1']) == 130
    assert list(tmp_path.iterdir()) == []
    assert capsys.readouterr().err == ''
    monkeypatch.setattr(simulate, 'simulate_bag', interrupted)
    assert main(['simulate', '--out', str(tmp_path / 'b')]) == 130


def test_bode_table_matches_the_characteristic_polynomial(tmp_path: Path) -> None:
    result = railgsa('bode', '--out', str(tmp_path / 'fig' / 'bode.png'))
    assert result.returncode == 0, result.stderr
    png = (tmp_path / 'fig' / 'bode.png').read_bytes()
    assert png[:8] == b'\x89PNG\r\n\x1a\n' and len(png) > 20_000
    # Independent truth: det(M s^2 + C s + K) of the two-mass model with Table 1 values.
    m_s, m_us, k_s, k_us, c = 9875.0, 1100.0, 2.13e6, 1.42e8, 1.2e5
    den = np.polysub(np.polymul([m_s, c, k_s], [m_us, c, k_s + k_us]),
                     np.polymul([c, k_s], [c, k_s]))
    poles = np.roots(den)
    upper = poles[poles.imag > 0]
    freqs = sorted(np.abs(upper) / (2 * np.pi))
    zetas = [-p.real / abs(p) for p in sorted(upper, key=abs)]
    rows = re.findall(r'^(car-body bounce|wheel hop)\s+([\d.]+)\s+([\d.]+)', result.stdout,
                      re.MULTILINE)
    assert [r[0] for r in rows] == ['car-body bounce', 'wheel hop']
    np.testing.assert_allclose([float(r[1]) for r in rows], freqs, atol=1e-3)
    np.testing.assert_allclose([float(r[2]) for r in rows], zetas, atol=1e-4)
    assert freqs[0] == pytest.approx(2.33, abs=0.01) and freqs[1] == pytest.approx(57.3, abs=0.1)
    zeros_s = re.search(r'zeros of G_s\s+\[rad/s\]: (.*)', result.stdout).group(1)
    assert zeros_s == f'{-k_s / c:.4g}, 0, 0'
    zeros_us = re.search(r'zeros of G_us\s+\[rad/s\]: (.*)', result.stdout).group(1).split(', ')
    pair = np.roots([m_s, c, k_s])  # wheel: s^2 (m_s s^2 + c s + k_s) over the same denominator
    assert zeros_us[2:] == ['0', '0']
    np.testing.assert_allclose([complex(z) for z in zeros_us[:2]], np.sort_complex(pair),
                               rtol=1e-3)
    vehicle = tmp_path / 'v.yaml'
    vehicle.write_text('vehicle: {m_s: 9875.0, m_us: 1100.0, k_s: 2.13e+6, k_us: 1.42e+8}')
    bad = railgsa('bode', '--vehicle', str(vehicle), '--out', str(tmp_path / 'x.png'))
    assert bad.returncode == 2 and 'missing field(s) c' in bad.stderr
    assert not (tmp_path / 'x.png').exists()
    fmt = railgsa('bode', '--out', str(tmp_path / 'x.doc'))
    assert fmt.returncode == 2 and "unsupported image format '.doc'" in fmt.stderr


@pytest.mark.ros
def test_demo_runs_the_system_and_replaces_its_outputs(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture) -> None:
    from railgsa_ros.cli.demo import NODES, OUTPUTS, last_diagnostics

    out = tmp_path / 'demo'
    for stale in ('live_bag', 'logs', 'review'):  # outputs of an earlier run are replaced
        (out / stale).mkdir(parents=True)
        (out / stale / 'old').write_text('old')
    assert main(['demo', '--out', str(out), '--duration', '9']) == 0  # > band delay (~7.2 s)
    printed = capsys.readouterr().out
    assert '/track/irregularity_truth' in printed and 'wheel hop' in printed
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUTS)
    assert f'report: {out / "review" / "report.html"}' in printed
    assert (out / 'review' / 'report.html').is_file()
    imu = read_imu(out / 'simulated_bag')
    irr = read_stamped(out / 'live_bag', '/track/irregularity', POINT_STAMPED.msgtype)
    assert f'/track/irregularity: {irr.stamps_ns.size} of {imu.stamps_ns.size} samples' in printed
    statuses = last_diagnostics(out / 'live_bag')
    for node, task in zip(NODES, ('inversion', 'uncertainty'), strict=True):
        inp, work = statuses[f'{node}: imu input'], statuses[f'{node}: {task}']
        assert (f'{node}: received {inp["received"]}, accepted {inp["accepted"]}, rejected '
                f'{inp["rejected"]}, gaps {inp["gap"]}, published {work["published"]}') in printed
    # everything irregularity_node published was recorded (whether every IMU sample reached the
    # nodes is the integration tests' business: test_integration_replay.py)
    assert int(statuses['irregularity_node: inversion']['published']) == irr.stamps_ns.size > 0
    assert not any((out / stale / 'old').exists() for stale in ('live_bag', 'logs', 'review'))


def test_summary_of_a_bag_without_imu_or_truth(tmp_path: Path) -> None:
    from railgsa_ros.bag import BagWriter
    from railgsa_ros.bag.cdr import encode
    from railgsa_ros.bag.messages import VECTOR3_STAMPED

    stamps = np.arange(11, dtype=np.int64) * 100_000_000
    with BagWriter(tmp_path / 'other', 'sqlite3') as bag:
        bag.add_topic('/v', VECTOR3_STAMPED.msgtype)
        bag.write_batches({'/v': (stamps, encode(VECTOR3_STAMPED, stamps, ['b'], np.ones(3)))})
    text = simulate.format_summary(tmp_path / 'other')
    assert re.search(r'/v\s+geometry_msgs/msg/Vector3Stamped\s+11\s+10\.0', text)
    assert 'duration 1.000 s' in text and 'accel' not in text and 'truth' not in text


def test_atomic_output_replaces_or_keeps_the_old_output(tmp_path: Path) -> None:
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.fileio import atomic_output

    target = tmp_path / 'result.txt'
    target.write_text('old')
    with pytest.raises(RuntimeError), atomic_output(target, overwrite=True) as tmp:
        tmp.write_text('half')
        raise RuntimeError
    assert target.read_text() == 'old' and list(tmp_path.iterdir()) == [target]
    with atomic_output(target, overwrite=True) as tmp:
        tmp.mkdir()  # a file may become a directory (bags are directories)
        (tmp / 'x').write_text('new')
    assert (target / 'x').read_text() == 'new' and list(tmp_path.iterdir()) == [target]
    with pytest.raises(ConfigError, match='nothing was written'), \
            atomic_output(tmp_path / 'empty'):
        pass
    assert list(tmp_path.iterdir()) == [target]


def test_output_cut_by_a_pipe_ends_quietly(tmp_path: Path) -> None:
    """``railgsa bode | head -1``: the reader has left (here before the first write), the
    command ends with 141 (128 + SIGPIPE) and no traceback."""
    import os
    import subprocess
    import sys

    read, write = os.pipe()
    os.close(read)
    try:
        proc = subprocess.run([sys.executable, '-m', 'railgsa_ros.cli.main', 'bode', '--out',
                               str(tmp_path / 'bode.png')], stdout=write,
                              stderr=subprocess.PIPE, timeout=60)
    finally:
        os.close(write)
    assert proc.returncode == 141 and b'Traceback' not in proc.stderr, proc.stderr


def test_bode_of_a_coach_file_prints_its_modes_delays_and_nulls(tmp_path: Path) -> None:
    from railgsa_ros.models import load_model

    coach_file = Path(__file__).resolve().parents[1] / 'config' / 'vehicles' / 'coach.yaml'
    result = railgsa('bode', '--vehicle', str(coach_file), '--speed', '25',
                     '--out', str(tmp_path / 'coach.png'))
    assert result.returncode == 0, result.stderr
    assert (tmp_path / 'coach.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    coach = load_model(coach_file)
    rows = re.findall(r'^([a-z][a-z -]+(?:, [a-z0-9, ]+)?)\s+([\d.]+)\s+([\d.]+)$',
                      result.stdout, re.MULTILINE)
    np.testing.assert_allclose([float(r[1]) for r in rows], [m.f_hz for m in coach.modes()],
                               atol=1e-3)
    assert [r[0].strip() for r in rows[:2]] == ['car-body bounce', 'car-body pitch']
    assert '(delays at 25 m/s [s]: 0, 0.1024, 0.76, 0.8624)' in result.stdout
    # a bogie's wheelsets cancel at 2a/(2n+1), a = 2.56 m; the pitch rate also at L/n, L = 19 m
    assert 'nulls of accel_z [m]: 5.12, 1.71, 1.02\n' in result.stdout
    assert 'nulls of pitch_rate [m]: 19, 9.5, 6.33, 5.12, 4.75,' in result.stdout
    bad = railgsa('bode', '--vehicle', str(coach_file), '--speed', '0',
                  '--out', str(tmp_path / 'x.png'))
    assert bad.returncode == 2 and '--speed: must be a positive number' in bad.stderr


def test_simulate_a_coach_file_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    coach = Path(__file__).resolve().parents[1] / 'config' / 'vehicles' / 'coach.yaml'
    assert main(['simulate', '--vehicle', str(coach), '--sensor', 'bmi088', '--duration', '1',
                 '--out', str(tmp_path / 'bag')]) == 0
    out = capsys.readouterr().out
    assert '/imu/data' in out and 'truth chainage 21.6-' in out  # every wheelset on the track
    stream = read_imu(tmp_path / 'bag')
    assert stream.accel.shape == (400, 3)
