"""The 10-DOF coach model against closed-form answers: rigid lift, wheelbase and bogie-spacing
nulls, decoupled modes, lever arms, and its state space."""

from pathlib import Path

import numpy as np
import pytest

from railgsa_ros.errors import ConfigError
from railgsa_ros.models import load_model
from railgsa_ros.models.coach import (
    PARAM_NAMES,
    CoachGeometry,
    CoachModel,
    CoachParams,
    ImuPosition,
)

COACH_FILE = Path(__file__).resolve().parents[1] / 'config' / 'vehicles' / 'coach.yaml'
GEOMETRY = CoachGeometry(imus=(ImuPosition('centre', 0.0), ImuPosition('front', 9.5),
                               ImuPosition('rear', -6.0)))
MODEL = CoachModel(geometry=GEOMETRY)
L, A = GEOMETRY.bogie_spacing_m, GEOMETRY.wheelbase_m


def theta_with(**values):
    """The nominal theta with some parameters replaced."""
    theta = MODEL.theta.copy()
    for name, value in values.items():
        theta[PARAM_NAMES.index(name)] = value
    return theta


def test_uniform_lift_raises_every_body_without_pitch():
    # every wheelset lifted by 1 mm: the static answer is the rigid-body one
    a, b, c, d = MODEL.state_space(MODEL.theta)
    x = np.linalg.solve(a, -b @ np.full(4, 1e-3))
    np.testing.assert_allclose(x[[0, 2, 4, 6, 7, 8, 9]], 1e-3, rtol=1e-9)
    np.testing.assert_allclose(x[[1, 3, 5]], 0.0, atol=1e-12)
    np.testing.assert_allclose(x[10:], 0.0, atol=1e-12)
    np.testing.assert_allclose(c @ x + d @ np.full(4, 1e-3), 0.0, atol=1e-9)  # at rest


def test_frequency_response_equals_the_state_space_transfer_matrix():
    theta = np.stack([MODEL.theta, theta_with(k_p=2e6, c_s=3e4, m_c=40000.0)])
    f = np.array([0.3, 0.7, 1.3, 4.0, 11.6, 60.0, 167.0, 400.0])  # (sI - A) loses digits below
    s = 2j * np.pi * f
    h = MODEL.frequency_response(theta, s)
    assert h.shape == (2, len(MODEL.channels), 4, f.size)
    for p in range(2):
        a, b, c, d = MODEL.state_space(theta[p])
        for k, sk in enumerate(s):
            direct = c @ np.linalg.solve(sk * np.eye(20) - a, b) + d
            np.testing.assert_allclose(h[p, :, :, k], direct, rtol=1e-7,
                                       atol=1e-12 * np.abs(direct).max())


def test_theta_axes_broadcast_like_a_loop():
    rng = np.random.default_rng(1)
    theta = MODEL.theta * rng.uniform(0.8, 1.2, (2, 3, 10))
    f = np.linspace(0.2, 30.0, 7)
    batch = MODEL.track_response(theta, f, 25.0)
    for i in range(2):
        for j in range(3):
            np.testing.assert_allclose(batch[i, j], MODEL.track_response(theta[i, j], f, 25.0),
                                       rtol=1e-12)


def test_every_car_body_signal_vanishes_at_twice_the_wheelbase():
    v = 30.0
    f_null = v / (2 * A)
    h = MODEL.track_response(MODEL.theta, np.array([f_null, 1.1 * f_null]), v)
    scale = np.abs(MODEL.track_response(MODEL.theta, np.linspace(0.5, 20, 50), v)).max(-1)
    np.testing.assert_array_less(np.abs(h[:, 0]), 1e-9 * scale)
    assert np.all(np.abs(h[:, 1]) > 1e-3 * scale)


def test_car_centre_bounce_and_pitch_rate_nulls_at_the_bogie_spacing_fractions():
    v = 40.0
    centre, rate = MODEL.channels.index('accel_z'), MODEL.channels.index('pitch_rate')
    bounce_nulls = v / (2 * L / np.array([1, 3, 5]))  # wavelength 2L/(2n+1)
    pitch_nulls = v / (L / np.array([1, 2, 3]))  # wavelength L/n
    h_bounce = MODEL.track_response(MODEL.theta, bounce_nulls, v)
    h_pitch = MODEL.track_response(MODEL.theta, pitch_nulls, v)
    peak = np.abs(MODEL.track_response(MODEL.theta, np.linspace(0.3, 5, 80), v)).max(-1)
    np.testing.assert_array_less(np.abs(h_bounce[centre]), 1e-9 * peak[centre])
    np.testing.assert_array_less(np.abs(h_pitch[rate]), 1e-9 * peak[rate])
    # each fills the other's nulls
    assert np.all(np.abs(h_bounce[rate]) > 1e-2 * peak[rate])
    assert np.all(np.abs(h_pitch[centre]) > 1e-3 * peak[centre])


def test_a_car_centre_imu_has_no_pitch_and_lever_arms_add_pitch_acceleration():
    f = np.array([0.8, 1.3, 3.0, 9.0])
    s = 2j * np.pi * f
    h = MODEL.frequency_response(MODEL.theta, s)
    centre, rate = 0, 1
    front, rear = MODEL.channels.index('accel_z:front'), MODEL.channels.index('accel_z:rear')
    # antisymmetric profile (front bogie up, rear down): the body only pitches
    pitch_only = np.einsum('cwf,w->cf', h, [1.0, 1.0, -1.0, -1.0])
    np.testing.assert_allclose(pitch_only[centre], 0.0, atol=1e-12 * np.abs(pitch_only).max())
    assert np.all(np.abs(pitch_only[rate]) > 0)
    # a point at x accelerates as the centre minus x times the pitch acceleration
    for channel, x in ((front, 9.5), (rear, -6.0)):
        np.testing.assert_allclose(h[channel], h[centre] - x * s * h[rate], rtol=1e-10)


def test_decoupled_limits_match_closed_form_frequencies():
    # nearly rigid primary and contact, light damping: the car body on its secondary springs
    theta = theta_with(k_p=1e8, k_h=1e11, c_p=10.0, c_s=10.0)
    modes = {m.description: m for m in MODEL.modes(theta)}
    bounce = np.sqrt(4 * theta[7] / theta[0]) / (2 * np.pi)
    pitch = np.sqrt(theta[7] * L ** 2 / theta[1]) / (2 * np.pi)
    assert modes['car-body bounce'].f_hz == pytest.approx(bounce, rel=1e-2)
    assert modes['car-body pitch'].f_hz == pytest.approx(pitch, rel=1e-2)
    # bogie pitch on its primary springs over wheelsets held by a stiff contact
    theta = theta_with(k_h=1e11, c_p=10.0, c_s=10.0)
    bogie = [m for m in MODEL.modes(theta) if m.description.startswith('bogie pitch')]
    expected = np.sqrt(theta[5] * A ** 2 / theta[3]) / (2 * np.pi)
    assert len(bogie) == 2
    for mode in bogie:
        assert mode.f_hz == pytest.approx(expected, rel=1e-4)
    # wheelset hop on the contact springs under a soft primary
    theta = theta_with(k_p=1e4, c_p=10.0)
    hops = [m for m in MODEL.modes(theta) if m.description.startswith('wheelset hop')]
    assert len(hops) == 4
    for mode in hops:
        assert mode.f_hz == pytest.approx(np.sqrt(2 * theta[9] / theta[4]) / (2 * np.pi),
                                          rel=1e-4)
        assert mode.zeta < 1e-3


def test_shipped_coach_is_the_benchmark_with_modes_in_the_published_ranges():
    coach = load_model(COACH_FILE)
    assert coach.kind == 'coach' and coach.channels == ('accel_z', 'pitch_rate')
    np.testing.assert_array_equal(coach.theta, CoachParams().as_array())
    np.testing.assert_allclose(coach.wheel_offsets_m, [0.0, 2.56, 19.0, 21.56])
    modes = coach.modes()
    assert len(modes) == 10
    by_name = {m.description.split(',')[0]: m.f_hz for m in modes}
    assert 1.0 <= by_name['car-body bounce'] <= 1.5 and 1.0 <= by_name['car-body pitch'] <= 1.5
    assert 5.0 <= by_name['bogie bounce'] <= 12.0 and 5.0 <= by_name['bogie pitch'] <= 12.0
    assert by_name['wheelset hop'] > 100.0


def test_reference_wheelset_sets_the_offsets_and_shifts_the_response_by_its_delay():
    rear = CoachModel(geometry=CoachGeometry(reference_wheelset=3))
    np.testing.assert_allclose(rear.wheel_offsets_m, [-19.0, -16.44, 0.0, 2.56])
    coach = CoachModel()
    f, v = np.array([0.5, 2.0, 7.0]), 20.0
    shift = np.exp(2j * np.pi * f * 19.0 / v)  # the leading wheelset is 19 m ahead
    np.testing.assert_allclose(rear.track_response(rear.theta, f, v),
                               coach.track_response(coach.theta, f, v) * shift, rtol=1e-10)


def write(tmp_path, text):
    path = tmp_path / 'coach.yaml'
    path.write_text(text)
    return path


GOOD = COACH_FILE.read_text()


@pytest.mark.parametrize(('old', 'new', 'message'), [
    ('model: coach', 'model: bus', 'model: expected coach or quarter_car'),
    ('  k_p: 1.2e+6 ', '  k_p: -1.2e+6 ', 'vehicle.k_p: must be a positive finite number'),
    ('  m_c: 32000.0 ', '  m_c: 32.0 ', 'vehicle.m_c: 32 kg is outside the physical range'),
    ('  k_h: 1.0e+9 ', '  k_hh: 1.0e+9 ', 'vehicle: unknown field(s) k_hh'),
    ('  wheelbase_m: 2.56 ', '  wheelbase_m: 25.6 ', 'geometry.wheelbase_m: 25.6 m is outside'),
    ('    x_m: 9.5 ', '    x_m: 95 ', 'imus[0].x_m: expected a number within +-14.25 m'),
    ('reference_wheelset: 1', 'reference_wheelset: 5', 'reference_wheelset: expected 1, 2'),
    ('imus:', 'imu:', 'unknown top-level key(s) imu'),
    ('  - name: above_leading_bogie', '  - name: above leading', 'imus[0].name: expected'),
])
def test_bad_files_give_one_line_errors_naming_file_and_field(tmp_path, old, new, message):
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new))
    with pytest.raises(ConfigError) as info:
        load_model(path)
    text = str(info.value)
    assert text.startswith(f'{path}: ') and message in text and '\n' not in text


def test_geometry_refuses_a_wheelbase_longer_than_the_bogie_spacing():
    with pytest.raises(ConfigError, match='wheelbase_m: 4 m must be shorter'):
        CoachGeometry(bogie_spacing_m=4.0, wheelbase_m=4.0)
    with pytest.raises(ConfigError, match=r"imus\[1\]\.name: 'a' is given twice"):
        CoachGeometry(imus=(ImuPosition('a', 0.0), ImuPosition('a', 1.0)))


def test_listed_null_wavelengths_are_zeros_of_each_channel():
    v = 25.0
    peak = np.abs(MODEL.track_response(MODEL.theta, np.linspace(0.3, 25, 200), v)).max(-1)
    longest = {'accel_z': 2 * L, 'pitch_rate': L, 'accel_z:front': 2 * A, 'accel_z:rear': 2 * A}
    for c, channel in enumerate(MODEL.channels):  # accel_z: the car-centre IMU
        waves = MODEL.null_wavelengths(channel)
        assert waves[0] == longest[channel] and waves[-1] >= 1.0
        h = MODEL.track_response(MODEL.theta, v / waves, v)[c]
        np.testing.assert_array_less(np.abs(h), 1e-8 * peak[c])
    assert 2 * L / 3 in MODEL.null_wavelengths('accel_z')
    assert 2 * L / 3 not in MODEL.null_wavelengths('accel_z:rear')
    with pytest.raises(ValueError, match='not an acceleration channel'):
        MODEL.null_wavelengths('accel_z:roof')


def test_low_frequency_limit_is_the_static_lever_rule():
    # a quasi-static lift of one wheelset by 1 m raises its bogie centre by 1/2, so the car body
    # by 1/4 and pitches it by -+1/(2L): the displacements behind accel / s^2 and rate / s
    s = 2j * np.pi * np.array([1e-6, 1e-4])
    h = MODEL.frequency_response(MODEL.theta, s)
    side = np.array([1.0, 1.0, -1.0, -1.0])  # leading or trailing bogie
    for channel, x in (('accel_z', 0.0), ('accel_z:front', 9.5), ('accel_z:rear', -6.0)):
        static = 0.25 + side * x / (2 * L)
        np.testing.assert_allclose(h[MODEL.channels.index(channel), :, 0] / s[0] ** 2, static,
                                   rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(h[1, :, 0] / s[0], -side / (2 * L), rtol=1e-5)
    # and the damping's first-order correction is still small at 1e-4 Hz
    np.testing.assert_allclose(h[1, :, 1] / s[1], -side / (2 * L), rtol=1e-3)


def test_direct_solve_fallback_equals_the_modal_sum(monkeypatch):
    from railgsa_ros.models import coach

    rng = np.random.default_rng(5)
    theta = MODEL.theta * rng.uniform(0.5, 1.5, (6, 10))
    s = 2j * np.pi * np.logspace(-3, np.log10(500.0), 60)
    modal = MODEL.frequency_response(theta, s)
    monkeypatch.setattr(coach, 'MODAL_COND', 0.0)  # every parameter set "nearly defective"
    solved = MODEL.frequency_response(theta, s)
    peak = np.abs(solved).max(axis=-1, keepdims=True)
    assert np.max(np.abs(modal - solved) / peak) < 1e-9
    assert not np.array_equal(modal, solved)  # two computations, one answer


def test_stiffness_and_damping_matrices_equal_the_textbook_equations():
    # written out by hand from Newton's and Euler's equations of the ten bodies (secondary at
    # x = +-h, h = L/2; wheelsets at +-b about their bogie, b = a/2; nose-down pitch positive)
    k_s, c_s, k_p, c_p, k_h = (MODEL.theta[PARAM_NAMES.index(n)]
                               for n in ('k_s', 'c_s', 'k_p', 'c_p', 'k_h'))
    h, b = L / 2, A / 2

    def textbook(ks, kp, kh):
        k = np.zeros((10, 10))
        k[0, 0] = 4 * ks  # car bounce on four secondary sides
        k[1, 1] = 4 * ks * h ** 2  # car pitch
        for i, x in enumerate((h, -h)):
            zb, tb = 2 + 2 * i, 3 + 2 * i
            k[0, zb] = k[zb, 0] = -2 * ks
            k[1, zb] = k[zb, 1] = 2 * ks * x
            k[zb, zb] = 2 * ks + 4 * kp
            k[tb, tb] = 4 * kp * b ** 2
            for j, arm in enumerate((b, -b)):
                zw = 6 + 2 * i + j
                k[zb, zw] = k[zw, zb] = -2 * kp
                k[tb, zw] = k[zw, tb] = 2 * kp * arm
                k[zw, zw] = 2 * kp + 2 * kh
        return k

    mass, c, k, k_u = MODEL.matrices(MODEL.theta)
    np.testing.assert_allclose(k, textbook(k_s, k_p, k_h), rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(c, textbook(c_s, c_p, 0.0), rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(k_u[6:], 2 * k_h * np.eye(4))
    np.testing.assert_array_equal(k_u[:6], 0.0)
    np.testing.assert_array_equal(mass, MODEL.theta[[0, 1, 2, 3, 2, 3, 4, 4, 4, 4]])
