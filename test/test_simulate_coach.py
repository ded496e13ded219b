"""Forward simulation of the coach: the wheelset bank against scipy.signal.lsim, a run's
wheelset delays at variable speed, the gyro's pitch rate in the bag (REP 103/145)."""

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from railgsa_ros.bag import IMU_TOPIC, read_stamped
from railgsa_ros.bag.messages import IMU, IMU_FIELDS
from railgsa_ros.cli.simulate import simulate_bag
from railgsa_ros.imu import G, gyro_covariance, imu_spec
from railgsa_ros.models import load_model
from railgsa_ros.models.coach import CoachGeometry, CoachModel, ImuPosition
from railgsa_ros.scenario import run_scenario
from railgsa_ros.simulate import simulate_model

COACH_FILE = Path(__file__).resolve().parents[1] / 'config' / 'vehicles' / 'coach.yaml'
MODEL = CoachModel(geometry=CoachGeometry(imus=(ImuPosition('front', 9.5),
                                                ImuPosition('centre', 0.0))))


def lsim_channels(model, u, t):
    """The model's channels (C, T) by scipy's lsim (linear interpolation of u (W, T))."""
    a, b, c, d = model.state_space(model.theta)
    return signal.lsim((a, b, c, d), u.T, t, interp=True)[1].T


def test_wheelset_bank_equals_lsim_of_the_state_space():
    dt = 1 / 2000
    t = np.arange(4000) * dt
    rng = np.random.default_rng(3)
    u = np.cumsum(rng.normal(0.0, 2e-5, (4, t.size)), axis=1)  # four different profiles
    u -= u[:, :1]  # from rest on the undisturbed track
    out = simulate_model(u, dt, MODEL)
    ref = lsim_channels(MODEL, u, t)
    assert out.shape == (3, t.size)
    for channel in range(3):
        scale = np.abs(ref[channel]).max()
        np.testing.assert_allclose(out[channel], ref[channel], atol=1e-8 * scale)
    # parameter sets are an axis: two vehicles at once equal two single runs
    theta = np.stack([MODEL.theta, MODEL.theta * 1.1])
    both = simulate_model(u, dt, MODEL, theta)
    np.testing.assert_allclose(both[1], simulate_model(u, dt, MODEL, theta[1]), rtol=1e-12,
                               atol=1e-15)


def test_run_at_variable_speed_sees_each_wheelset_at_its_delay():
    # ideal sensor: the car-body channels are the exact response to the delayed profiles (up to
    # the anti-alias filter's passband ripple); the truth is the leading wheelset's profile
    run = run_scenario('german-low', np.array([8.0, 30.0, 15.0]), 6.0, 1000.0, 'ideal', seed=4,
                       vehicle=MODEL)
    assert run.vehicle is MODEL
    np.testing.assert_array_equal(run.truth_u_m, run.track(run.chainage_m))
    assert run.chainage_m[0] == pytest.approx(21.56)  # every wheelset starts on the profile
    wheels = np.stack([run.track(run.chainage_m - d) for d in MODEL.wheel_offsets_m])
    # from equilibrium on the first position = from rest with the first position subtracted
    # (accelerations and rates are zero at equilibrium)
    wheels -= wheels[:, :1]
    ref = lsim_channels(MODEL, wheels, run.t_true_s - run.t_true_s[0])
    skip = 200  # the first 0.2 s: the FIR's held start
    accel = run.accel[skip:, 2] - G
    np.testing.assert_allclose(accel, ref[0, skip:], atol=3e-3 * ref[0].std())
    np.testing.assert_allclose(run.gyro[skip:, 1], ref[1, skip:], atol=3e-3 * ref[1].std())
    np.testing.assert_array_equal(run.gyro[:, [0, 2]], 0.0)
    # the further IMU at the car centre, at the primary's stamps, with its own (ideal) gyro
    assert run.imu_names == ('centre',) and run.imu_accel.shape == (run.accel.shape[0], 1, 3)
    centre = MODEL.channels.index('accel_z:centre')
    np.testing.assert_allclose(run.imu_accel[skip:, 0, 2] - G, ref[centre, skip:],
                               atol=3e-3 * ref[centre].std())
    np.testing.assert_array_equal(run.imu_gyro[:, 0], run.gyro)
    # not the leading wheelset alone: the others change the answer by far more than the tolerance
    alone = lsim_channels(MODEL, wheels * np.array([[1.0], [0.0], [0.0], [0.0]]),
                          run.t_true_s - run.t_true_s[0])
    assert np.std(alone[0, skip:] - ref[0, skip:]) > 0.3 * ref[0].std()


def test_gyro_in_the_bag_present_with_a_gyro_and_absent_without(tmp_path):
    _, run = simulate_bag(tmp_path / 'bmi', vehicle=str(COACH_FILE), sensor='bmi088',
                          duration=2.0)
    values = read_stamped(tmp_path / 'bmi', IMU_TOPIC, IMU.msgtype).values
    omega = values[:, IMU_FIELDS['angular_velocity']]
    np.testing.assert_array_equal(omega, run.gyro)
    cov = values[:, IMU_FIELDS['angular_velocity_covariance']]
    spec = imu_spec('bmi088')
    np.testing.assert_array_equal(cov[:, [0, 4, 8]], gyro_covariance(spec))
    # the zero-rate offset and white noise of the datasheet-like gyro around a small pitch rate
    assert omega[:, 1].mean() == pytest.approx(spec.gyro_bias, abs=5e-4)
    assert np.sqrt(gyro_covariance(spec)) == pytest.approx(np.std(omega[:, 0]), rel=0.1)
    _, run = simulate_bag(tmp_path / 'adxl', vehicle=str(COACH_FILE), sensor='adxl355',
                          duration=1.0)
    assert run.gyro is None
    values = read_stamped(tmp_path / 'adxl', IMU_TOPIC, IMU.msgtype).values
    np.testing.assert_array_equal(values[:, IMU_FIELDS['angular_velocity_covariance'].start],
                                  -1.0)


def test_further_imus_get_their_own_topics_in_the_bag(tmp_path):
    coach = tmp_path / 'coach2.yaml'
    further = '\n  - {name: centre, x_m: 0.0}\n  - {name: rear, x_m: -9.5} '
    coach.write_text(COACH_FILE.read_text().replace('    x_m: 9.5 ', '    x_m: 9.5' + further))
    _, run = simulate_bag(tmp_path / 'bag', vehicle=str(coach), sensor='adxl355', duration=1.0)
    assert run.imu_names == ('centre', 'rear') and run.imu_gyro is None
    for k, name in enumerate(run.imu_names):
        data = read_stamped(tmp_path / 'bag', f'/imu/{name}/data', IMU.msgtype)
        np.testing.assert_array_equal(data.stamps_ns, run.stamps_ns)
        assert set(data.strings[0]) == {f'imu_link_{name}'}
        values = data.values
        np.testing.assert_array_equal(values[:, IMU_FIELDS['linear_acceleration']],
                                      run.imu_accel[:, k])
        np.testing.assert_array_equal(
            values[:, IMU_FIELDS['angular_velocity_covariance'].start], -1.0)
    # another position and another sensor: not a copy of the primary
    assert not np.array_equal(run.imu_accel[:, 0, 2], run.accel[:, 2])


def test_quarter_car_runs_have_no_gyro_and_coach_files_load_as_coaches():
    run = run_scenario('german-low', 20.0, 0.5, 400.0, 'bmi088', vehicle=None)
    assert run.gyro is None and run.gyro_covariance == -1.0
    assert load_model(COACH_FILE).kind == 'coach'


def test_coach_stream_chunks_equal_the_one_shot_run():
    from railgsa_ros.scenario import Run, RunStream

    args = ('german-low', np.array([5.0, 25.0]), 3.0, 400.0, 'bmi088')
    whole = run_scenario(*args, seed=6, vehicle=MODEL)
    chunks = Run.concat(list(RunStream(*args, seed=6, vehicle=MODEL, chunk_s=0.7)))
    for name in ('stamps_ns', 'accel', 'gyro', 'imu_accel', 'imu_gyro', 'truth_u_m'):
        np.testing.assert_array_equal(getattr(chunks, name), getattr(whole, name), name)
