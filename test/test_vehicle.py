"""Quarter-vehicle model: modes, zeros, frequency response and configuration validation."""

from pathlib import Path

import numpy as np
import pytest
from scipy import linalg

from railgsa_ros.errors import ConfigError
from railgsa_ros.vehicle import (
    PARAM_NAMES,
    VehicleParams,
    feedthrough,
    frequency_response,
    load_vehicle,
    modes,
    poles,
    state_space,
    tf_polynomials,
    zeros_sprung,
)

CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'vehicle.yaml'
DEFAULT = VehicleParams()


def direct_response(theta, omega, row):
    """C (j w I - A)^-1 B by a linear solve for each frequency (independent of the tf code)."""
    a, b, c_s, c_us = state_space(theta)
    c, d = (c_s, c_us)[row], feedthrough(theta)[row]
    x = np.linalg.solve(1j * omega[:, None, None] * np.eye(4) - a, b)
    return (c @ x + d)[:, 0, 0]


def test_modes_match_the_paper_values():
    bounce, hop = modes(DEFAULT)
    # rail_domain.md section 2: 2.33 Hz (zeta 0.41) and 57.3 Hz (zeta 0.15)
    assert bounce.natural_frequency_hz == pytest.approx(2.33, abs=0.005)
    assert hop.natural_frequency_hz == pytest.approx(57.3, abs=0.05)
    assert bounce.damping_ratio == pytest.approx(0.41, abs=0.005)
    assert hop.damping_ratio == pytest.approx(0.15, abs=0.005)
    # poles are the roots of the hand-derived denominator and of det(sI - A)
    p = np.sort_complex(poles(DEFAULT))
    _, _, den = tf_polynomials(DEFAULT)
    np.testing.assert_allclose(np.sort_complex(np.roots(den)), p, rtol=1e-9)
    np.testing.assert_allclose(den, np.poly(state_space(DEFAULT)[0]), rtol=1e-9)


def test_zeros_double_at_origin_and_at_minus_ks_over_c():
    z = zeros_sprung(DEFAULT)
    np.testing.assert_array_equal(z[:2], 0.0)
    assert z[2] == pytest.approx(-2.13e6 / 1.2e5)  # -17.75 rad/s (2.83 Hz)
    a, b, c_s, _ = state_space(DEFAULT)
    # transmission zeros: finite generalised eigenvalues of the Rosenbrock system matrix
    rosen = np.block([[a, b], [c_s, np.zeros((1, 1))]])
    ev = linalg.eigvals(rosen, np.diag([1.0, 1.0, 1.0, 1.0, 0.0]))
    zz = np.sort(ev[np.isfinite(ev)].real)
    assert zz.size == 3 and zz[0] == pytest.approx(-17.75, rel=1e-9)
    np.testing.assert_allclose(zz[1:], 0.0, atol=1e-6)
    # double zero: the car body follows the track at low frequency, |G_s(j w)| -> w^2
    w = np.array([1e-3, 1e-2])
    np.testing.assert_allclose(np.abs(frequency_response(DEFAULT, 1j * w)), w ** 2, rtol=1e-3)
    assert abs(frequency_response(DEFAULT, -17.75 + 0j)) < 1e-12


@pytest.mark.parametrize(('f_hz', 'gain'), [(0.1, 0.40), (1.0, 47.0), (10.0, 843.0),
                                            (58.0, 1.4e4), (1000.0, 250.0)])
def test_sprung_gain_matches_rail_domain_table(f_hz, gain):
    # rail_domain.md section 2, |a_s / z_r| in (m/s^2)/m, given to 2-3 significant digits
    value = abs(frequency_response(DEFAULT, 2j * np.pi * f_hz))
    assert value == pytest.approx(gain, rel=0.03)


def test_frequency_response_equals_state_space_solve_for_parameter_banks():
    rng = np.random.default_rng(0)
    theta = DEFAULT.as_array() * rng.uniform(0.7, 1.3, (6, 5))
    omega = np.logspace(-2, 4, 40)
    for row, output in enumerate(('sprung', 'unsprung')):
        g = frequency_response(theta, 1j * omega, output)
        assert g.shape == (6, 40)
        for p in range(6):
            # the solve cancels ~8 digits where |G_s| ~ w^2 << 1 (w = 0.01 rad/s)
            np.testing.assert_allclose(g[p], direct_response(theta[p], omega, row), rtol=1e-6)
    np.testing.assert_allclose(poles(theta)[3], poles(theta[3]))


def test_config_file_equals_defaults():
    assert load_vehicle(CONFIG) == DEFAULT
    assert DEFAULT.as_dict() == dict(zip(PARAM_NAMES, DEFAULT.as_array(), strict=True))


@pytest.mark.parametrize(('body', 'match'), [
    ('m_s: -9875.0', 'm_s'),
    ('k_s: 0.0', 'k_s'),
    ('c: .nan', 'c'),
    ('k_us: abc', 'k_us'),
    ('m_us: true', 'm_us'),
    ('mass: 1.0', 'mass'),
])
def test_invalid_values_name_the_field(tmp_path, body, match):
    text = CONFIG.read_text()
    key = body.split(':')[0]
    lines = [ln for ln in text.splitlines() if not ln.strip().startswith(f'{key}:')]
    path = tmp_path / 'v.yaml'
    path.write_text('\n'.join(lines) + f'\n  {body}\n')
    with pytest.raises(ConfigError, match=match):
        load_vehicle(path)


def test_missing_field_and_file_errors(tmp_path):
    path = tmp_path / 'v.yaml'
    path.write_text('vehicle:\n  m_s: 9875.0\n  m_us: 1100.0\n')
    with pytest.raises(ConfigError, match=r'v\.yaml.*missing.*k_s'):
        load_vehicle(path)
    path.write_text('vehicle: [1, 2\n')
    with pytest.raises(ConfigError, match=r'v\.yaml.*invalid YAML'):
        load_vehicle(path)
    path.write_text('other: 1\n')
    with pytest.raises(ConfigError, match=r'v\.yaml.*vehicle'):
        load_vehicle(path)
    with pytest.raises(ConfigError, match=r'nope\.yaml'):
        load_vehicle(tmp_path / 'nope.yaml')
    path.write_bytes(b'\xff\xfe\x00vehicle')
    with pytest.raises(ConfigError, match=r'v\.yaml'):
        load_vehicle(path)


def test_yaml11_numeric_strings_are_accepted(tmp_path):
    path = tmp_path / 'v.yaml'
    path.write_text('vehicle: {m_s: 9875, m_us: 1100, k_s: 2.13e6, k_us: 1.42e8, c: 1.2e5}\n')
    assert load_vehicle(path) == DEFAULT
