"""Scenario runner: ideal-sensor runs reproduce the forward model and the profile at chainage."""

import time

import numpy as np
import pytest

from railgsa_ros.errors import ConfigError
from railgsa_ros.imu import PRESETS, G, accel_covariance
from railgsa_ros.scenario import MIN_SIM_RATE_HZ, run_scenario
from railgsa_ros.simulate import simulate
from railgsa_ros.track import apply_defects, make_profile, paper_profile, save_csv, squat
from railgsa_ros.vehicle import VehicleParams


def test_ideal_paper_run_equals_forward_simulation_at_the_stamps():
    v, rate = 10.0, 500.0
    run = run_scenario('paper', v, 14.0, rate, 'ideal', seed=0, start_ns=123)
    q = round(run.sim_rate_hz / rate)
    assert run.sim_rate_hz == MIN_SIM_RATE_HZ and q == 4
    n = run.stamps_ns.size
    assert n == 7000 and run.n_dropped == 0 and run.frame_id == 'imu_link'
    t = np.arange(n) / rate
    np.testing.assert_array_equal(run.stamps_ns, np.rint(t * 1e9).astype(np.int64) + 123)
    np.testing.assert_allclose(run.chainage_m, v * t, rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(run.speed_mps, v)
    # truth: the analytic profile under the wheel
    np.testing.assert_allclose(run.truth_u_m, paper_profile(v * t), rtol=0, atol=1e-12)
    # accel: the forward model on the analytic profile, sampled at the stamps
    t_sim = np.arange(n * q) / run.sim_rate_hz
    a_s, _ = simulate(paper_profile(v * t_sim), 1 / run.sim_rate_hz, VehicleParams())
    peak = np.abs(a_s).max()
    # the 80 dB anti-alias FIR passes the band below 0.4 rate with ripple 1e-4
    np.testing.assert_allclose(run.accel[:, 2] - G, a_s[::q], rtol=0, atol=1e-4 * peak)
    np.testing.assert_array_equal(run.accel[:, :2], 0.0)


def test_csv_profile_with_defects_truth_at_chainage(tmp_path):
    x, u = make_profile('german-high', 400.0, 0.25, seed=3)
    path = tmp_path / 'track.csv'
    save_csv(path, x + 1000.0, u)  # chainage origin kept from the file
    defects = 'weld@1100,dip@1200:len=8:depth=6e-3'
    run = run_scenario(f'file:{path}', 20.0, 15.0, 1000.0, 'ideal', seed=1, defects=defects)
    assert run.chainage_m[0] == 1000.0
    expected = apply_defects(run.chainage_m, np.interp(run.chainage_m, x + 1000.0, u), defects)
    np.testing.assert_allclose(run.truth_u_m, expected, rtol=0, atol=1e-15)
    dip = (run.chainage_m > 1200) & (run.chainage_m < 1208)
    assert np.min(run.truth_u_m[dip] - np.interp(run.chainage_m[dip], x + 1000.0, u)) \
        == pytest.approx(-6e-3, abs=1e-6)


def test_speed_profile_gives_integrated_chainage():
    duration = 20.0
    run = run_scenario('german-low', [10.0, 30.0], duration, 200.0, 'ideal', seed=2)
    t = run.t_true_s
    np.testing.assert_allclose(run.speed_mps, 10.0 + t, rtol=1e-12)
    # trapezoidal integration of a linear speed is exact: s = 10 t + t^2 / 2
    np.testing.assert_allclose(run.chainage_m, 10.0 * t + 0.5 * t ** 2, rtol=1e-10, atol=1e-9)
    assert run.sim_rate_hz == 2000.0  # 20 * 30 m/s / 1 m = 600 Hz < minimum


def test_simulation_rate_follows_the_shortest_defect():
    run = run_scenario('paper', 50.0, 0.5, 4000.0, 'ideal', defects='squat@10')
    assert run.sim_rate_hz >= 20 * 50.0 / 0.03 and run.sim_rate_hz % 4000.0 == 0
    assert run.sim_rate_hz - 4000.0 < 20 * 50.0 / 0.03
    # truth = paper profile + squat at the chainage of each sample (12.5 mm apart)
    dip = run.truth_u_m - paper_profile(run.chainage_m)
    np.testing.assert_allclose(dip, squat(run.chainage_m, 10.0), rtol=0, atol=1e-12)
    assert dip.min() < -0.5 * 2e-4  # a sample lands within 6.25 mm of the 30 mm squat's centre


@pytest.mark.parametrize('sensor', sorted(PRESETS))
def test_preset_runs_are_consistent(sensor):
    # a chip setting (name@ODR) is its chip's filter at that output rate; the models re-rate
    rate = PRESETS[sensor].output_rate_hz if '@' in sensor else 400.0
    run = run_scenario('german-low', 20.0, 30.0, rate, sensor, seed=5)
    n_total = 30.0 * rate
    assert run.stamps_ns.size + run.n_dropped == n_total
    for name in ('accel', 't_true_s', 'speed_mps', 'chainage_m', 'truth_u_m'):
        assert getattr(run, name).shape[0] == run.stamps_ns.size
    assert run.accel_covariance == accel_covariance(run.sensor)
    assert run.sensor.output_rate_hz == rate
    assert abs(np.mean(run.accel[:, 2]) - G) < 0.02 * G
    again = run_scenario('german-low', 20.0, 30.0, rate, sensor, seed=5)
    np.testing.assert_array_equal(run.accel, again.accel)
    np.testing.assert_array_equal(run.stamps_ns, again.stamps_ns)


def test_sixty_second_run_is_fast():
    start = time.perf_counter()
    run = run_scenario('german-high', 30.0, 60.0, 1000.0, 'adxl355', seed=0)
    elapsed = time.perf_counter() - start
    assert run.stamps_ns.size + run.n_dropped == 60_000
    assert elapsed < 2.0  # ~0.05 s measured; generous for a shared machine


@pytest.mark.parametrize(('kwargs', 'match'), [
    ({'speed_mps': -1.0}, 'speed'),
    ({'speed_mps': [[1.0]]}, 'speed'),
    ({'duration_s': 0.0}, 'duration'),
    ({'profile_spec': 'german-medium'}, 'profile'),
    ({'sensor': 'mpu9250'}, 'sensor'),
    ({'defects': 'bump@1'}, 'defects'),
])
def test_bad_arguments(kwargs, match):
    args = {'profile_spec': 'paper', 'speed_mps': 10.0, 'duration_s': 5.0, 'rate_hz': 200.0,
            'sensor': 'ideal'}
    args.update(kwargs)
    with pytest.raises(ConfigError, match=match):
        run_scenario(**args)
