"""Kalman inversion (Appendix A.3): shaping filter vs the German spectrum, filter, smoother."""

import itertools

import numpy as np
import pytest
from scipy import integrate, linalg

from railgsa_ros.inverse.kalman import KalmanInverse, augmented_model, shaping_coefficients
from railgsa_ros.simulate import simulate
from railgsa_ros.track import GERMAN_AV, german_psd, make_profile
from railgsa_ros.vehicle import VehicleParams

NOMINAL = VehicleParams().as_array()


@pytest.mark.parametrize('speed', [10.0, 40.0])
def test_shaping_filter_spectrum_is_the_german_spectrum_in_time(speed):
    a, b, g = shaping_coefficients(speed, GERMAN_AV['low'])
    w = np.geomspace(1e-3, 1e3, 50)
    s_time = g ** 2 / (np.pi * (w ** 2 + a ** 2) * (w ** 2 + b ** 2))  # one-sided, m^2/(rad/s)
    assert np.allclose(s_time, german_psd(w / speed, 'low') / speed, rtol=1e-12)


def test_discrete_model_variance_matches_spectrum_integral():
    speed, dt = 20.0, 1e-3
    phi, q, _ = augmented_model(NOMINAL, speed, GERMAN_AV['low'], 0.0, dt)
    shaping = slice(4, 6)
    cov = linalg.solve_discrete_lyapunov(phi[0][shaping, shaping], q[0][shaping, shaping])
    var_u, _ = integrate.quad(german_psd, 0, np.inf, limit=200)
    assert cov[0, 0] == pytest.approx(var_u, rel=1e-6)


def _record(speed, seconds, noise, seed=0):
    dt = 1e-3
    x, u = make_profile('german-low', speed * seconds + 50, 0.01, seed=seed)
    t = np.arange(0, seconds, dt)
    truth = np.interp(speed * t, x, u)
    a_s, _ = simulate(truth, dt, NOMINAL)
    rng = np.random.default_rng(seed)
    return truth, a_s + noise * rng.standard_normal(t.size)


def test_filter_is_stable_and_chunk_invariant():
    _, y = _record(20.0, 4.0, 5e-3)
    kf = KalmanInverse(NOMINAL, GERMAN_AV['low'], 1e-6, 2.5e-5, 1e-3, 20.0, 0.02, 10.0, 70.0)
    assert kf.design.spectral_radius < 1.0
    whole = kf.process(y)
    kf.reset()
    cuts = np.unique(np.r_[0, np.random.default_rng(1).integers(0, y.size, 25), y.size])
    parts = np.concatenate([kf.process(y[a:b]) for a, b in itertools.pairwise(cuts)],
                           axis=1)
    assert np.max(np.abs(parts - whole)) <= 1e-10 * np.max(np.abs(whole))


def test_smoother_beats_filter_and_tracks_truth():
    truth, y = _record(20.0, 12.0, 5e-3)
    kf = KalmanInverse(NOMINAL, GERMAN_AV['low'], 1e-6, 2.5e-5, 1e-3, 20.0, 0.02, 10.0, 70.0)
    filt, smooth = kf.process(y)[0], kf.smooth(y)[0]
    mid = slice(3000, 9000)  # scored away from the ends, after removing the unobservable trend
    def detrend(z):
        return (z - np.polyval(np.polyfit(np.arange(z.size), z, 2), np.arange(z.size)))
    e_filt = np.std(detrend(filt[mid] - truth[mid]))
    e_smooth = np.std(detrend(smooth[mid] - truth[mid]))
    assert e_smooth < 0.5 * e_filt
    assert e_smooth < 0.2 * np.std(detrend(truth[mid]))


def test_set_speed_redesigns_only_beyond_tolerance():
    kf = KalmanInverse(NOMINAL, GERMAN_AV['low'], 1e-6, 2.5e-5, 1e-3, 20.0, 0.05, 10.0, 70.0)
    assert not kf.set_speed(20.5)
    assert kf.set_speed(25.0)
    assert kf.design.speed == 25.0
    assert kf.set_speed(3.0) and kf.design.speed == 10.0  # held at the minimum speed
