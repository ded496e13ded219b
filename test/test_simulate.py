"""Forward simulation: steady-state sines, lsim, parameter banks and chunk invariance."""

import itertools

import numpy as np
import pytest
from scipy import signal

from railgsa_ros.simulate import simulate, vehicle_bank
from railgsa_ros.track import paper_profile
from railgsa_ros.vehicle import VehicleParams, feedthrough, frequency_response, state_space

DEFAULT = VehicleParams()
THETA = DEFAULT.as_array()


def lsim_reference(theta, u, dt, x0=None):
    """scipy.signal.lsim of Eq. 2 with both outputs (linear interpolation of the input)."""
    a, b, c_s, c_us = state_space(theta)
    c = np.vstack([c_s, c_us])
    d = np.vstack(feedthrough(theta))
    t = np.arange(u.size) * dt
    _, y, _ = signal.lsim((a, b, c, d), u, t, X0=x0)
    return y[:, 0], y[:, 1]


def test_steady_state_sine_matches_frequency_response():
    # near both modes, the zero at 2.83 Hz, and beyond; all at once as a bank of 7 systems
    freqs = np.array([0.3, 2.33, 2.83, 10.0, 57.3, 120.0, 300.0])
    fs, duration = 40_000.0, 4.0
    t = np.arange(int(fs * duration)) / fs
    u = np.sin(2 * np.pi * freqs[:, None] * t)
    a_s, a_us = simulate(u, 1 / fs, np.tile(THETA, (freqs.size, 1)))
    last = t >= duration - 1.0  # transients decay as exp(-6 t) or faster: e^-18 by then
    basis = np.stack([np.sin(2 * np.pi * freqs[:, None] * t[last]),
                      np.cos(2 * np.pi * freqs[:, None] * t[last])], -1)  # (F, n, 2)
    for out, name in ((a_s, 'sprung'), (a_us, 'unsprung')):
        coef = np.array([np.linalg.lstsq(basis[i], out[i, last], rcond=None)[0]
                         for i in range(freqs.size)])
        measured = coef[:, 0] + 1j * coef[:, 1]  # y = Re(G) sin + Im(G) cos for u = sin
        g = frequency_response(DEFAULT, 2j * np.pi * freqs, name)
        # a first-order hold sees the sine through sinc^2(f dt): 1 - 2e-4 at 300 Hz, 40 kHz
        g = g * np.sinc(freqs / fs) ** 2
        np.testing.assert_allclose(np.abs(measured), np.abs(g), rtol=1e-3)
        np.testing.assert_allclose(np.angle(measured), np.angle(g), atol=1e-3)


def test_agrees_with_lsim_on_a_smooth_input():
    dt = 1e-3
    t = np.arange(15_000) * dt
    u = paper_profile(10.0 * t)  # smooth, starts at rest (u ~ 0)
    a_s, a_us = simulate(u, dt, DEFAULT)
    ref_s, ref_us = lsim_reference(THETA, u, dt)
    np.testing.assert_allclose(a_s, ref_s, rtol=0, atol=1e-10 * np.abs(ref_s).max())
    np.testing.assert_allclose(a_us, ref_us, rtol=0, atol=1e-10 * np.abs(ref_us).max())


def test_initial_state_matches_lsim_free_response():
    dt = 5e-4
    x0 = np.array([0.0, 0.0, 0.01, 0.0])  # car body 10 mm up, released
    u = np.zeros(4000)
    a_s, a_us = simulate(u, dt, DEFAULT, x0=x0[None])
    ref_s, ref_us = lsim_reference(THETA, u, dt, x0)
    np.testing.assert_allclose(a_s, ref_s, rtol=0, atol=1e-10 * np.abs(ref_s).max())
    np.testing.assert_allclose(a_us, ref_us, rtol=0, atol=1e-10 * np.abs(ref_us).max())


def test_parameter_bank_equals_one_by_one():
    rng = np.random.default_rng(1)
    theta = THETA * rng.uniform(0.6, 1.4, (9, 5))
    dt = 5e-4
    u = rng.standard_normal(3000).cumsum() * 1e-5
    u_each = u * rng.uniform(0.5, 2.0, (9, 1))
    shared = simulate(u, dt, theta)
    own = simulate(u_each, dt, theta)
    assert shared[0].shape == (9, 3000)
    for p in range(9):
        one = simulate(u, dt, theta[p])
        mine = simulate(u_each[p], dt, theta[p])
        for k in range(2):
            np.testing.assert_allclose(shared[k][p], one[k], rtol=1e-12,
                                       atol=1e-12 * np.abs(one[k]).max())
            np.testing.assert_allclose(own[k][p], mine[k], rtol=1e-12,
                                       atol=1e-12 * np.abs(mine[k]).max())


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_chunk_invariance_with_random_chunks(seed):
    rng = np.random.default_rng(seed)
    theta = THETA * rng.uniform(0.8, 1.2, (3, 5))
    dt = 5e-4
    u = paper_profile(np.arange(2000) * 0.005 + 60.0)
    whole = vehicle_bank(theta, dt).process(u)
    bank = vehicle_bank(theta, dt)
    sizes = np.concatenate([[1, 1], rng.integers(1, 300, 40)])
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    bounds = [*bounds[bounds < u.size].tolist(), u.size]
    chunked = np.concatenate([bank.process(u[lo:hi]) for lo, hi in itertools.pairwise(bounds)],
                             axis=-1)
    scale = np.abs(whole).max(axis=-1, keepdims=True)  # per system and output
    assert np.max(np.abs(chunked - whole) / scale) < 1e-12
    bank.reset()
    assert np.max(np.abs(bank.process(u) - whole) / scale) < 1e-12
