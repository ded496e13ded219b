"""Streaming simulation: chunks equal the one-shot model, bounded state, one line, odometry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from railgsa_ros.bag import read_imu, read_stamped, write_run
from railgsa_ros.bag.messages import ODOMETRY, ODOMETRY_FIELDS, POINT_STAMPED
from railgsa_ros.bag.run import write_run_chunks
from railgsa_ros.imu import imu_spec, measure
from railgsa_ros.scenario import Run, RunStream, run_scenario
from railgsa_ros.simulate import simulate
from railgsa_ros.speed_profile import parse_speed_profile
from railgsa_ros.track import BANDS, apply_defects, line_profile, spectrum_for

STOPS = parse_speed_profile('accel:0-20:6s,cruise:20:6s:ripple=0.5,brake:20-0:6s,stop:3s,'
                            'accel:0-10:4s')
NOISY = imu_spec('adxl355', lsb=0.0, dropout_fraction=0.1)  # no ADC: rounding cannot flip


def one_shot(stream: RunStream, seed: int) -> Run:
    """The run from whole arrays and the one-shot functions (simulate, measure), not the
    stream: the independent reference for the chunked result."""
    n = stream.n_out * stream.q
    t = np.arange(n) / stream.fs_sim
    v = stream.speed(t) if callable(stream.speed) else np.full(n, float(stream.speed))
    chainage = stream.start_m + cumulative_trapezoid(v, dx=1 / stream.fs_sim, initial=0.0)
    u = apply_defects(chainage, stream.line(chainage), stream.defects)
    # linearity: from the equilibrium under u[0], the response to u is that to u - u[0] from
    # rest (a constant input gives zero acceleration: the double zero at s = 0)
    a_s, _ = simulate(u - u[0], 1 / stream.fs_sim, stream.theta)
    imu_seed = int(np.random.SeedSequence(seed).spawn(2)[1].generate_state(1)[0])
    imu = measure(t, a_s, stream.spec, imu_seed)
    pick = np.arange(stream.n_out)[imu.valid] * stream.q
    return Run(stamps_ns=imu.stamps_ns[imu.valid] + stream.start_ns,
               accel=imu.accel[imu.valid], t_true_s=imu.t_true_s[imu.valid],
               speed_mps=v[pick], chainage_m=chainage[pick], truth_u_m=u[pick],
               rate_hz=stream.spec.output_rate_hz, sim_rate_hz=stream.fs_sim,
               accel_covariance=0.0, n_dropped=int(np.sum(~imu.valid)), sensor=stream.spec,
               vehicle=stream.theta, profile='', defects=None, seed=seed)


@pytest.mark.parametrize('case', ['stops', 'squat', 'bmi088'])
def test_chunks_equal_the_one_shot_simulation(case):
    args = {'stops': ('german-high', STOPS, STOPS.duration_s, 500.0, NOISY, None),
            'squat': ('fra-5', 30.0, 4.0, 1000.0, NOISY, 'squat@40,joint@90'),
            'bmi088': ('german-low', 25.0, 8.0, 400.0, imu_spec('bmi088', dropout_fraction=0.1),
                       'dip@60:len=8:depth=4e-3')}
    profile, speed, duration, rate, sensor, defects = args[case]
    stream = RunStream(profile, speed, duration, rate, sensor, seed=5, defects=defects,
                       start_m=250.0, chunk_s=0.37)
    chunks = list(stream)
    assert len(chunks) > 8
    streamed = Run.concat(chunks)
    again = Run.concat(list(stream))  # a second iteration is the same run again
    np.testing.assert_array_equal(again.accel, streamed.accel)
    # the one-shot RunStream (what run_scenario returns) is bit-identical
    whole = run_scenario(profile, speed, duration, rate, sensor, seed=5, defects=defects,
                         start_m=250.0)
    for name in ('stamps_ns', 'accel', 't_true_s', 'speed_mps', 'chainage_m', 'truth_u_m'):
        np.testing.assert_array_equal(getattr(streamed, name), getattr(whole, name), name)
    assert streamed.n_dropped == whole.n_dropped
    # the independent whole-array reference: the same samples, state-space parts to 1e-12
    ref = one_shot(stream, seed=5)
    np.testing.assert_array_equal(streamed.stamps_ns, ref.stamps_ns)
    assert streamed.n_dropped == ref.n_dropped and streamed.n_dropped > 0
    np.testing.assert_allclose(streamed.chainage_m, ref.chainage_m, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(streamed.truth_u_m, ref.truth_u_m, rtol=0, atol=1e-12)
    motion = streamed.accel[:, 2] - np.median(streamed.accel[:, 2])
    lsb = stream.spec.lsb  # bmi088 quantises: a rounding may flip by one code
    np.testing.assert_allclose(streamed.accel, ref.accel, rtol=0,
                               atol=max(1e-12 * np.abs(motion).max(), 1.0001 * lsb))


def test_stream_state_stays_bounded_by_the_chunk():
    stream = RunStream('german-low', 20.0, 30.0, 1000.0, 'adxl355', seed=1, chunk_s=2.0)
    sizes = []
    for chunk in stream:
        sizes.append(chunk.stamps_ns.size)
        mems = stream.imus.accel[0]
        assert mems._buf.shape[0] <= mems.taps.size + 2 * mems.pad
        assert len(stream.line._tiles) <= 4
    assert max(sizes) <= 2.0 * 1000 + mems.half and sum(sizes) > 29_000


def test_bag_written_in_chunks_equals_the_whole_run(tmp_path: Path):
    args = ('german-high', STOPS, STOPS.duration_s, 500.0, 'adxl355')
    whole = run_scenario(*args, seed=2, defects='joint@120')
    write_run(tmp_path / 'whole', whole)
    stream = RunStream(*args, seed=2, defects='joint@120', chunk_s=1.3)
    _, topics = write_run_chunks(tmp_path / 'chunks', stream)
    a, b = read_imu(tmp_path / 'whole'), read_imu(tmp_path / 'chunks')
    for name in ('stamps_ns', 'accel', 'covariance', 'odom_stamps_ns', 'speed_mps'):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)
    truth = read_stamped(tmp_path / 'chunks', '/track/irregularity_truth', POINT_STAMPED.msgtype)
    np.testing.assert_array_equal(truth.values[:, 0], whole.chainage_m)
    counts = {t.topic: t.count for t in topics}
    assert counts['/imu/data'] == whole.stamps_ns.size
    assert counts['/odom'] == a.odom_stamps_ns.size
    # standstill: odometry speed 0 and the chainage held for the whole stop
    stop = (whole.t_true_s > 18.0) & (whole.t_true_s < 21.0)
    assert np.ptp(whole.chainage_m[stop]) == 0.0


def test_odometry_scale_error_scales_speed_and_distance(tmp_path: Path):
    run = run_scenario('german-low', 25.0, 10.0, 500.0, 'ideal', seed=3, start_m=1000.0,
                       odom_scale=1.004)
    write_run(tmp_path / 'bag', run)
    odom = read_stamped(tmp_path / 'bag', '/odom', ODOMETRY.msgtype)
    speed = odom.values[:, ODOMETRY_FIELDS['twist.twist.linear'].start]
    position = odom.values[:, ODOMETRY_FIELDS['pose.pose.position'].start]
    np.testing.assert_allclose(speed, 25.0 * 1.004, rtol=1e-12)
    # odometer: the start chainage plus 1.004 x the distance travelled (25 m/s x t)
    t = (odom.stamps_ns - run.stamps_ns[0]) / 1e9
    np.testing.assert_allclose(position, 1000.0 + 1.004 * 25.0 * t, rtol=0, atol=1e-6)
    assert run.chainage_m[-1] == pytest.approx(1000.0 + 25.0 * (10.0 - 1 / 500.0), abs=1e-9)


def test_runs_with_one_line_seed_see_one_track():
    fast = run_scenario('german-high', 15.0, 12.0, 1000.0, 'ideal', seed=1, line_seed=77)
    slow = run_scenario('german-high', 12.0, 10.0, 500.0, 'ideal', seed=9, line_seed=77,
                        start_m=60.0)
    other = run_scenario('german-high', 12.0, 10.0, 500.0, 'ideal', seed=9, line_seed=78,
                         start_m=60.0)
    common = (slow.chainage_m > 61.0) & (slow.chainage_m < fast.chainage_m[-1])
    x = slow.chainage_m[common]
    # linear interpolation over the fast run's 15 mm steps (across the kinks of the line's
    # 31 mm grid): errors of a few 1e-7 m next to a profile of 3 mm rms
    np.testing.assert_allclose(np.interp(x, fast.chainage_m, fast.truth_u_m),
                               slow.truth_u_m[common], rtol=0, atol=2e-6)
    assert np.sqrt(np.mean((other.truth_u_m[common] - slow.truth_u_m[common]) ** 2)) > 1e-3


@pytest.mark.parametrize('spec', ['german-low', 'fra-5'])
def test_line_profile_band_variance_matches_the_spectrum(spec):
    from scipy.integrate import quad

    line, origin = line_profile(spec, seed=11)
    assert origin == 0.0
    dx = 0.5
    x = 3e5 + np.arange(0.0, 80_000.0, dx)  # far along the line: any tile
    u = line(x)
    spectrum = np.fft.rfft(u - u.mean())
    k = np.fft.rfftfreq(u.size, dx)  # cycles/m
    for lo, hi in BANDS.values():
        sel = (k > 1 / hi) & (k <= 1 / lo)
        measured = 2 * np.sum(np.abs(spectrum[sel]) ** 2) / u.size ** 2
        expected = quad(spectrum_for(spec), 2 * np.pi / hi, 2 * np.pi / lo)[0]
        # independent frequencies: relative standard error about 1 / sqrt(n); 4 of them
        assert measured == pytest.approx(expected, rel=4 / np.sqrt(sel.sum()))
    # continuous across tile boundaries: steps no larger than inside a tile
    fine = line(np.arange(0.0, 6000.0, 0.01))
    steps = np.abs(np.diff(fine))
    assert steps.max() < 10 * np.median(steps) + 1e-6


def test_profile_file_shorter_than_the_run_is_one_line_and_no_bag(tmp_path: Path, capsys):
    from railgsa_ros.cli.main import main
    from railgsa_ros.track import save_csv

    x = np.arange(0.0, 100.0, 0.1)
    save_csv(tmp_path / 'short.csv', x + 50.0, 1e-3 * np.sin(x))
    out = tmp_path / 'bag'
    assert main(['simulate', '--out', str(out), '--profile', f'file:{tmp_path}/short.csv',
                 '--speed', '20', '--duration', '8', '--rate', '200']) == 2
    err = capsys.readouterr().err
    assert 'short.csv: covers 50-149.9 m, the run needs' in err and err.count('\n') == 1
    assert not out.exists()
    assert main(['simulate', '--out', str(out), '--profile', f'file:{tmp_path}/short.csv',
                 '--speed', '20', '--duration', '4', '--rate', '200', '--gnss']) == 0
    assert main(['simulate', '--out', str(tmp_path / 'neg'), '--start-km', '-1', '--gnss']) == 2
    assert '--gnss: the simulated line starts at chainage 0' in capsys.readouterr().err


def test_settled_vehicle_stays_at_rest_on_a_constant_irregularity():
    from railgsa_ros.simulate import vehicle_bank
    from railgsa_ros.vehicle import VehicleParams

    theta = VehicleParams().as_array() * np.array([[1.0] * 5, [1.2, 0.9, 1.1, 0.8, 1.3]])
    bank = vehicle_bank(theta, 1 / 2000.0)
    bank.settle(4e-3)
    settled = bank.state.copy()
    out = bank.process(np.full(3000, 4e-3))
    assert np.abs(out).max() < 1e-9  # m/s^2: at rest (a step of 4 mm would give ~10 m/s^2)
    np.testing.assert_allclose(bank.state, settled, rtol=1e-9, atol=1e-15)
    bank.reset()
    assert np.abs(bank.process(np.full(3000, 4e-3))).max() > 1.0
