"""The model interface: load_model chooses; the quarter-car wrapper is vehicle.py bit for bit."""

from pathlib import Path

import numpy as np
import pytest

from railgsa_ros import vehicle
from railgsa_ros.errors import ConfigError
from railgsa_ros.models import as_model, load_model
from railgsa_ros.models.quarter_car import QuarterCarModel

CONFIG = Path(__file__).resolve().parents[1] / 'config'


def test_files_without_a_model_key_stay_the_quarter_car():
    model = load_model(CONFIG / 'vehicle.yaml')
    assert model.kind == 'quarter_car' and model.channels == ('accel_z',)
    np.testing.assert_array_equal(model.theta, vehicle.load_vehicle(CONFIG / 'vehicle.yaml')
                                  .as_array())
    np.testing.assert_array_equal(model.wheel_offsets_m, [0.0])
    same = load_model({'model': 'quarter_car', 'vehicle': vehicle.VehicleParams().as_dict()})
    np.testing.assert_array_equal(same.theta, model.theta)
    assert load_model(CONFIG / 'vehicles' / 'coach.yaml').kind == 'coach'


def test_quarter_car_wrapper_equals_vehicle_py_bit_for_bit():
    model = QuarterCarModel()
    rng = np.random.default_rng(0)
    theta = model.theta * rng.uniform(0.7, 1.3, (4, 5))
    f = np.logspace(-1, 2.3, 300)
    s = 2j * np.pi * f
    expected = vehicle.frequency_response(theta, s)
    h = model.frequency_response(theta, s)
    assert h.shape == (4, 1, 1, f.size)
    assert np.array_equal(h[:, 0, 0], expected)
    assert np.array_equal(model.track_response(theta, f, 17.0)[:, 0], expected)
    a, b, c, d = model.state_space(theta)
    a_ref, b_ref, c_ref, _ = vehicle.state_space(theta)
    for got, ref in ((a, a_ref), (b, b_ref), (c, c_ref)):
        assert np.array_equal(got, ref)
    assert np.array_equal(d, np.zeros((4, 1, 1)))
    modes = model.modes()
    ref_modes = vehicle.modes(vehicle.VehicleParams())
    assert [m.f_hz for m in modes] == [m.natural_frequency_hz for m in ref_modes]
    assert [m.description for m in modes] == ['car-body bounce', 'wheel hop']


def test_as_model_accepts_what_the_entry_points_take():
    params = vehicle.VehicleParams(m_s=9000.0)
    assert as_model(None).theta.tolist() == vehicle.VehicleParams().as_array().tolist()
    assert as_model(params).theta[0] == 9000.0
    assert as_model(params.as_array()).theta[0] == 9000.0
    assert as_model(str(CONFIG / 'vehicles' / 'coach.yaml')).kind == 'coach'
    coach = load_model(CONFIG / 'vehicles' / 'coach.yaml')
    assert as_model(coach) is coach


@pytest.mark.parametrize(('text', 'message'), [
    ('- 1\n', 'expected a mapping with a "vehicle:" section'),
    ('model: quarter_car\n', 'missing top-level "vehicle:" section'),
    ('vehicle: {m_s: 1}\n', 'vehicle: missing field(s) m_us'),
    ('vehicle: {m_s: 9875, m_us: 1100, k_s: 2.13e6, k_us: 1.42e8, c: 1e9}\n',
     'vehicle.c: 1e+09 N*s/m is outside the physical range'),
    ('model: coach\nvehicle: {}\n', 'missing top-level "geometry:" section'),
])
def test_bad_files_give_one_line_errors(tmp_path, text, message):
    path = tmp_path / 'v.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_model(path)
    assert str(info.value).startswith(f'{path}: ') and message in str(info.value)
    assert '\n' not in str(info.value)


def test_track_response_refuses_a_speed_that_is_not_positive():
    with pytest.raises(ConfigError, match='speed'):
        QuarterCarModel().track_response(QuarterCarModel().theta, np.ones(2), 0.0)


def test_quarter_car_entry_points_refuse_a_coach_file_by_name():
    path = CONFIG / 'vehicles' / 'coach.yaml'
    with pytest.raises(ConfigError) as info:
        vehicle.load_vehicle(path)
    assert str(info.value) == (f"{path}: model: 'coach': this entry point takes a quarter car "
                               '(vehicle: m_s, m_us, k_s, k_us, c; docs/vehicles.md)')
