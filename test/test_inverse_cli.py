"""``railgsa invert``: CSV and bag outputs against the pipeline, options, errors, quality."""

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from railgsa_ros.bag import write_run
from railgsa_ros.cli.main import main
from railgsa_ros.input.rate import count_steps
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, vertical
from railgsa_ros.inverse.score import score
from railgsa_ros.inverse.sensor import sensor_delay_s
from railgsa_ros.scenario import run_scenario


def _bag(tmp_path_factory, name, duration_s, seed, defects):
    run = run_scenario('german-low', 25.0, duration_s, 500.0, 'adxl355', seed=seed,
                       defects=defects, start_ns=1_700_000_000 * 10**9)
    path = tmp_path_factory.mktemp('bags') / name
    write_run(path, run)
    return path, run


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    # 20 s: the INVALID warm-up and tail of the band window leave 16 s of output
    return _bag(tmp_path_factory, 'run', 20.0, 2, 'dip@100:len=6:depth=8e-3')


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    return lines, np.loadtxt(lines[1:], delimiter=',', ndmin=2)


def test_csv_with_odometry_tracks_truth(bag, tmp_path):
    path, run = bag
    out = tmp_path / 'u.csv'
    assert main(['invert', str(path), '--csv', str(out), '--method', 'feedback']) == 0
    lines, data = read_csv(out)
    assert lines[0] == 't_s,chainage_m,u_m,quality,km,lat,lon'
    stamps = np.array([int(line.split(',')[0].replace('.', '')) for line in lines[1:]])
    assert np.array_equal(stamps, run.stamps_ns)
    # odometry at 50 Hz, held: chainage within a few cm of the true travel
    travel = run.chainage_m - run.chainage_m[0]
    assert np.max(np.abs(data[:, 1] - travel)) < 0.05
    # the warm-up and the tail are INVALID (u = nan), the cruise in between published (VALID,
    # DEGRADED around the sensor's bridged dropouts)
    quality = data[:, 3]
    assert quality[0] == quality[-1] == 2 and np.all(np.isnan(data[quality == 2, 2]))
    valid = np.flatnonzero(quality != 2)
    assert np.all(np.diff(valid) == 1) and valid.size > 0.6 * run.stamps_ns.size
    assert np.sum(quality == 0) > 0.3 * run.stamps_ns.size
    s = score(data[valid, 1] + run.chainage_m[0], data[valid, 2], run.chainage_m,
              run.truth_u_m, margin_m=20.0)
    assert s.rmse < 0.3e-3 and s.correlation > 0.95


def test_csv_is_the_streaming_pipeline(bag, tmp_path):
    path, run = bag
    out = tmp_path / 'u.csv'
    assert main(['invert', str(path), '--csv', str(out), '--speed', '25']) == 0
    _, data = read_csv(out)
    steps = np.diff(run.stamps_ns)  # the CLI takes the rate from the bag's stamps
    rate = count_steps(steps, float(np.median(steps)), 3.0).rate_hz
    # the policy's noise: the IMU-reported variance (it shapes the bridging of dropouts)
    pipe = InversionPipeline(InversionConfig(rate_hz=rate, speed_mps=25.0), None,
                             run.accel_covariance, stuck_s=0.5)
    outs = [pipe.push(run.stamps_ns, vertical(run.accel, 'z')), pipe.flush()]
    valid = data[:, 3] != 2
    assert np.allclose(data[valid, 2], np.concatenate([o.u_m for o in outs])[valid], rtol=0,
                       atol=1e-12)


def test_bag_output_has_the_node_topic(bag, tmp_path):
    path, run = bag
    out = tmp_path / 'inv'
    assert main(['invert', str(path), '--out', str(out), '--speed', '25']) == 0
    with AnyReader([out]) as reader:
        msgs = [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]
        assert {c.topic for c in reader.connections} == {'/track/irregularity'}
    assert len(msgs) == run.stamps_ns.size
    t, msg = msgs[10]
    assert msg.header.frame_id == 'track'
    assert t == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == run.stamps_ns[10]
    assert msg.point.x == pytest.approx(25.0 * (run.stamps_ns[10] - run.stamps_ns[0]) * 1e-9)
    # the live node's encoding: point.y = quality code, point.z = NaN when INVALID
    codes = np.array([m.point.y for _, m in msgs])
    u = np.array([m.point.z for _, m in msgs])
    assert {0.0, 2.0} <= set(codes) <= {0.0, 1.0, 2.0} and codes[10] == 2.0
    assert np.all(np.isnan(u[codes == 2])) and np.all(np.isfinite(u[codes != 2]))


def test_errors_name_the_file(bag, tmp_path, capsys):
    path, _ = bag
    assert main(['invert', str(tmp_path / 'missing'), '--csv', str(tmp_path / 'x.csv')]) == 2
    assert 'missing' in capsys.readouterr().err
    params = tmp_path / 'p.yaml'
    params.write_text('irregularity_node:\n  ros__parameters:\n    gain: -3.0\n')
    assert main(['invert', str(path), '--csv', str(tmp_path / 'x.csv'), '--params',
                 str(params), '--method', 'feedback']) == 2
    err = capsys.readouterr().err
    assert 'p.yaml' in err and 'gain' in err
    assert main(['invert', str(path), '--csv', str(tmp_path / 'x.csv'), '--imu-topic',
                 '/nope']) == 2
    assert not (tmp_path / 'x.csv').exists()


def test_relative_topic_names_are_in_the_root_namespace(bag, tmp_path):
    """A bag holds fully qualified names: imu/data and odom mean /imu/data and /odom."""
    path, _ = bag
    for name, topics in (('abs.csv', []), ('rel.csv', ['--imu-topic', 'imu/data',
                                                       '--odom-topic', 'odom'])):
        assert main(['invert', str(path), '--csv', str(tmp_path / name), *topics]) == 0
    assert (tmp_path / 'rel.csv').read_bytes() == (tmp_path / 'abs.csv').read_bytes()


def test_no_odometry_and_no_speed_exits_2_with_one_line(bag, tmp_path, capsys):
    path, _ = bag
    assert main(['invert', str(path), '--csv', str(tmp_path / 'x.csv'), '--odom-topic',
                 '/absent']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'no odometry' in err and '--speed' in err


def test_no_usable_sample_exits_2_with_one_line(bag, tmp_path, capsys):
    """Every sample rejected for its frame (strict policy): exit 2, one line, no traceback, no
    file; every output INVALID (a run shorter than the band window): written, flagged, warned."""
    path, _ = bag
    params = tmp_path / 'p.yaml'
    params.write_text('irregularity_node:\n  ros__parameters:\n    frame_id: other\n'
                      '    wrong_frame_policy: reject\n')
    out = tmp_path / 'x.csv'
    assert main(['invert', str(path), '--csv', str(out), '--params', str(params)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'no usable IMU sample' in err
    assert 'wrong_frame' in err and not out.exists()
    short = write_run(tmp_path / 'short', run_scenario('german-low', 25.0, 1.0, 500.0,
                                                       'adxl355', seed=2))
    assert main(['invert', str(short), '--csv', str(out)]) == 0
    assert 'every output is INVALID' in capsys.readouterr().err
    _, data = read_csv(out)
    assert np.all(data[:, 3] == 2) and np.all(np.isnan(data[:, 2]))


def test_rate_hz_disagreeing_with_the_bag_exits_2(bag, tmp_path, capsys):
    path, _ = bag
    params = tmp_path / 'p.yaml'
    params.write_text('irregularity_node:\n  ros__parameters:\n    rate_hz: 1000.0\n')
    assert main(['invert', str(path), '--csv', str(tmp_path / 'x.csv'), '--params',
                 str(params)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'rate_hz 1000' in err and 'measured' in err


def test_bands_are_the_uncertainty_stream(bag, tmp_path):
    """--bands columns equal uncertainty_node's streaming code (pushed in odd chunks) on the
    same samples, and the band brackets its own PCE mean."""
    from railgsa_ros.bag import read_imu
    from railgsa_ros.uncertainty import UncertaintyConfig, UncertaintyStream
    from railgsa_ros.uncertainty.stream import Band

    path, _ = bag
    out = tmp_path / 'u.csv'
    assert main(['invert', str(path), '--csv', str(out), '--bands']) == 0
    lines, data = read_csv(out)
    assert lines[0] == 't_s,chainage_m,u_m,quality,lower_m,mean_m,upper_m,km,lat,lon'
    import argparse

    from railgsa_ros.cli import invert

    parser = argparse.ArgumentParser()
    invert.register(parser.add_subparsers())
    inp = invert.load_inputs(parser.parse_args(['invert', str(path), '--csv', str(out)]))
    live = UncertaintyStream(UncertaintyConfig(inversion=inp.config, qoi=''), inp.vehicle,
                             options=inp.options)
    rec = read_imu(path)  # the whole stream at once, fed in odd batches below
    parts = [live.odometry(rec.odom_stamps_ns, rec.speed_mps).band]
    edges = np.cumsum(np.random.default_rng(1).integers(1, 900, rec.stamps_ns.size))
    for lo, hi in zip(np.concatenate([[0], edges]), edges, strict=False):
        if lo >= rec.stamps_ns.size:
            break
        parts.append(live.imu(rec.stamps_ns[lo:hi], rec.accel[lo:hi], rec.frame_ids[lo:hi],
                              rec.covariance[lo:hi]).band)
    ref = Band.concat([*parts, live.flush().band])
    stamps = np.array([int(line.split(',')[0].replace('.', '')) for line in lines[1:]])
    assert np.array_equal(stamps, ref.stamps_ns)
    np.testing.assert_array_equal(data[:, 3], ref.quality)
    for col, want in zip(data[:, 4:7].T, (ref.lower_m, ref.mean_m, ref.upper_m), strict=True):
        np.testing.assert_allclose(col, want, rtol=1e-8, atol=1e-12)  # nan where INVALID
    ok = data[:, 3] != 2
    assert np.all(data[ok, 4] <= data[ok, 5]) and np.all(data[ok, 5] <= data[ok, 6])


def test_bands_in_the_output_bag(bag, tmp_path):
    path, _ = bag
    out = tmp_path / 'nodes'
    assert main(['invert', str(path), '--out', str(out), '--bands']) == 0
    with AnyReader([out]) as reader:
        stamps = {c.topic: [] for c in reader.connections}
        for conn, t, _ in reader.messages(connections=reader.connections):
            stamps[conn.topic].append(t)
    assert set(stamps) == {'/track/irregularity', '/track/irregularity_band'}
    assert stamps['/track/irregularity'] == stamps['/track/irregularity_band']


@pytest.fixture(scope='module')
def long_bag(tmp_path_factory):
    return _bag(tmp_path_factory, 'long', 40.0, 4, 'dip@500:len=6:depth=8e-3')


def test_grid_csv_is_the_profile_on_distance(long_bag, tmp_path):
    """--grid 0.25: chainage multiples of 0.25 m, D1 on distance against the truth band-passed
    the same way; t_s (when the wheel passed) increases; a custom band is accepted."""
    from railgsa_ros.inverse.score import band_distance

    path, run = long_bag
    out = tmp_path / 'g.csv'
    assert main(['invert', str(path), '--csv', str(out), '--grid', '0.25']) == 0
    lines, data = read_csv(out)
    assert lines[0].startswith('t_s,chainage_m,u_m')
    chain, u = data[:, 1], data[:, 2]
    assert np.allclose(np.round(chain / 0.25) * 0.25, chain, atol=1e-9)
    assert np.all(np.diff(chain) > 0) and np.all(np.diff(data[:, 0]) > 0)
    x = np.arange(run.chainage_m[0], run.chainage_m[-1], 0.25)
    truth = band_distance(np.interp(x, run.chainage_m, run.truth_u_m), 0.25)
    here = chain + run.chainage_m[0]
    ok = np.isfinite(u) & (here > x[0] + 100) & (here < x[-1] - 100)
    assert ok.sum() > 1000
    err = u[ok] - np.interp(here[ok], x, truth)
    assert np.sqrt(np.mean(err ** 2)) < 0.05e-3
    assert main(['invert', str(path), '--csv', str(tmp_path / 'c.csv'), '--grid', '0.25',
                 '--band', '2:70']) == 0


def test_grid_bag_has_the_grid_topic(long_bag, tmp_path):
    path, _ = long_bag
    csv, out = tmp_path / 'g.csv', tmp_path / 'g.mcap'
    assert main(['invert', str(path), '--csv', str(csv), '--grid', '0.5']) == 0
    assert main(['invert', str(path), '--out', str(out), '--grid', '0.5']) == 0
    _, data = read_csv(csv)
    with AnyReader([out]) as reader:
        conns = [c for c in reader.connections if c.topic == '/track/irregularity_grid']
        assert len(conns) == 1 and conns[0].msgcount == data.shape[0]
        x = [reader.deserialize(raw, c.msgtype).point.x
             for c, _, raw in reader.messages(connections=conns)]
    np.testing.assert_allclose(x, data[:, 1], atol=1e-4)


def test_bad_band_and_grid_exit_2(long_bag, tmp_path, capsys):
    path, _ = long_bag
    for extra in (['--band', 'd9'], ['--band', '70:2'], ['--grid', '0'],
                  ['--grid', '2', '--band', 'd1'], ['--grid', '0.25', '--bands'],
                  ['--sensor-delay', 'adxl999'], ['--sensor-delay', '-1'],
                  ['--sensor-delay', 'bmi088'], ['--sensor-delay', 'bmi088@300Hz']):
        assert main(['invert', str(path), '--csv', str(tmp_path / 'x.csv'), *extra]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and any(
            word in err for word in ('band', 'grid', 'sensor'))


def test_sensor_delay_preset_advances_the_profile(bag, tmp_path):
    """--sensor-delay bmi088@400Hz-osr4 (a 40 Hz cut-off: 2.613 / (2 pi 40 Hz) = 10.4 ms at
    low frequency, 0.26 m at 25 m/s) equals that many seconds: the output is the same samples,
    advanced by the delay against no compensation."""
    path, _ = bag
    outs = {}
    tau = sensor_delay_s('bmi088@400Hz-osr4')
    assert tau == pytest.approx(2.6131 / (2 * np.pi * 40.0), rel=0.02)
    for name, value in (('none', '0'), ('preset', 'bmi088@400Hz-osr4'), ('seconds', repr(tau))):
        out = tmp_path / f'{name}.csv'
        assert main(['invert', str(path), '--csv', str(out), '--sensor-delay', value]) == 0
        outs[name] = read_csv(out)[1]
    np.testing.assert_allclose(outs['preset'][:, 2], outs['seconds'][:, 2], rtol=0, atol=1e-12)
    late, early = outs['none'], outs['preset']
    ok = np.isfinite(late[:, 2]) & np.isfinite(early[:, 2])
    lag = np.argmax(np.correlate(early[ok, 2], late[ok, 2][50:-50], 'valid')) - 50
    assert lag == pytest.approx(-tau * 500, abs=1.0)  # samples at 500 Hz: advanced
