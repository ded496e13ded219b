"""The independent coach reference (test/reference/) against analytic results and itself by two
code paths: the Newton-Euler ODE against the assembled frequency response, statics against the
statically determinate load paths, energy, and the LMMSE posterior against Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
from reference.coach_ode import (
    MANCHESTER_COACH,
    displacement_response,
    matrices,
    newton_euler,
    profile_response,
    simulate,
    wheelset_offsets,
)
from reference.lmmse import (
    Channel,
    band_power,
    error_spectrum,
    lmmse_estimate,
    posterior_rmse,
    synthetic_record,
    wiener_gains,
)
from scipy import fft

P = MANCHESTER_COACH
ACC = 25e-6 * 9.80665  # ADXL355-like, m/s^2/sqrt(Hz)
GYRO = np.deg2rad(0.014)  # rad/s/sqrt(Hz)
OUTPUTS = (P['l_c'], 0.0, None)  # above the leading bogie, car centre, pitch rate


def ramped_waves(x: np.ndarray) -> np.ndarray:
    """A smooth profile (m): three waves (4-31 m, 0.2-1 mm), faded in over 20-40 m."""
    fade = 0.5 - 0.5 * np.cos(np.pi * np.clip((x - 20.0) / 20.0, 0.0, 1.0))
    waves = (1e-3 * np.sin(2 * np.pi * x / 31.0) + 5e-4 * np.sin(2 * np.pi * x / 9.0 + 1.0)
             + 2e-4 * np.sin(2 * np.pi * x / 4.0 + 2.0))
    return fade * waves


def channels_of(run) -> np.ndarray:
    return np.array([run.pitch_rate() if x is None else run.accel(x) for x in OUTPUTS])


def test_ode_converged_against_halved_tolerances():
    t = np.arange(0.0, 0.8, 1e-3)
    runs = [simulate(P, ramped_waves, 25.0, t, start_m=22.0),  # default tolerances, halved
            simulate(P, ramped_waves, 25.0, t, start_m=22.0, rtol=5e-9, atol=5e-14)]
    a, b = (channels_of(r) for r in runs)
    rel = np.max(np.abs(a - b), axis=1) / np.max(np.abs(b), axis=1)
    assert np.all(rel < 1e-6), rel
    assert np.max(np.abs(b[0])) > 0.01  # the waves reached the car body (m/s^2)


@pytest.mark.parametrize('wavelength', [25.0, 11.0, 4 * P['l_t']])
def test_ode_sine_steady_state_matches_frequency_response(wavelength):
    speed, amp, s0 = 20.0, 1e-3, 40.0
    k = 2 * np.pi / wavelength
    w = k * speed
    phasor = amp * np.exp(1j * k * (s0 - wheelset_offsets(P)))  # rail under each wheelset
    x = displacement_response(P, np.array([w]))[0] @ phasor  # steady state at t = 0
    y0 = np.concatenate([x.imag, (1j * w * x).imag])
    t = np.arange(0.0, 0.6, 1e-3)
    run = simulate(P, lambda s: amp * np.sin(k * s), speed, t, start_m=s0, y0=y0)
    h = profile_response(P, np.array([w]), OUTPUTS, speed)[0]
    expect = np.imag(h[:, None] * amp * np.exp(1j * (k * s0 + w * t)))
    got = channels_of(run)
    if wavelength == 4 * P['l_t']:  # a bogie's two wheelsets cancel: it pitches only
        pitch_acc = np.max(np.abs(run.ddq[3])) * P['l_t']  # bogie ends, m/s^2
        assert np.max(np.abs(run.ddq[2])) < 1e-9 * pitch_acc
        assert np.max(np.abs(got[:2])) < 1e-9 * pitch_acc  # no car-body signal
        assert np.max(np.abs(h[:2])) * amp < 1e-9 * pitch_acc
    else:
        scale = np.max(np.abs(expect), axis=1)
        assert np.all(np.max(np.abs(got - expect), axis=1) < 1e-6 * scale)


def test_variable_speed_moves_every_wheelset_along_the_same_chainage():
    t = np.arange(0.0, 0.5, 1e-3)
    run = simulate(P, ramped_waves, lambda tt: 10.0 + 20.0 * tt, t, start_m=30.0)
    np.testing.assert_allclose(run.chainage, 30.0 + 10.0 * t + 10.0 * t ** 2, rtol=1e-10)
    np.testing.assert_allclose(run.speed, 10.0 + 20.0 * t)
    expect = ramped_waves(run.chainage[None, :] - wheelset_offsets(P)[:, None])
    np.testing.assert_allclose(run.u_w, expect, rtol=1e-12)
    assert wheelset_offsets(P)[-1] == pytest.approx(2 * (P['l_c'] + P['l_t']))


def test_static_lift():
    _, _, K, B = matrices(P)
    acc = newton_euler(P)
    q = np.linalg.solve(K, B @ np.full(4, 1e-3))  # every wheel +1 mm
    np.testing.assert_allclose(q, [1e-3, 0, 1e-3, 0, 1e-3, 0, 1e-3, 1e-3, 1e-3, 1e-3],
                               atol=1e-15)
    assert np.max(np.abs(acc(list(q), [0.0] * 10, [1e-3] * 4))) < 1e-9
    # leading wheelset +1 mm: both stages are statically determinate, so no spring force
    # changes and every body moves rigidly (theta positive nose down)
    d, lc, lt = 1e-3, P['l_c'], P['l_t']
    rigid = [d / 4, -d / (4 * lc), d / 2, -d / (2 * lt), 0, 0, d, 0, 0, 0]
    np.testing.assert_allclose(np.linalg.solve(K, B @ [d, 0, 0, 0]), rigid, atol=1e-15)
    assert np.max(np.abs(acc(rigid, [0.0] * 10, [d, 0, 0, 0]))) < 1e-9


@pytest.mark.parametrize('damped', [False, True])
def test_free_vibration_energy(damped):
    p = P if damped else {**P, 'c_p': 0.0, 'c_s': 0.0}
    M, C, K, _ = matrices(p)
    scale = [1e-3, 1e-4, 1e-3, 1e-4, 1e-3, 1e-4, 1e-6, 1e-6, 1e-6, 1e-6]  # m, rad
    q0 = np.random.default_rng(3).standard_normal(10) * scale
    t = np.arange(0.0, 0.5, 1e-4)
    run = simulate(p, lambda s: 0.0 * s, 20.0, t, y0=np.concatenate([q0, np.zeros(10)]))
    energy = 0.5 * (np.einsum('it,ij,jt->t', run.dq, M, run.dq)
                    + np.einsum('it,ij,jt->t', run.q, K, run.q))
    if damped:  # dE/dt = -dq' C dq
        power = np.einsum('it,ij,jt->t', run.dq, C, run.dq)
        lost = np.concatenate([[0.0], np.cumsum((power[1:] + power[:-1]) / 2 * np.diff(t))])
        np.testing.assert_allclose(energy, energy[0] - lost, rtol=0, atol=1e-4 * energy[0])
        assert energy[-1] < 0.7 * energy[0]
    else:
        assert np.max(np.abs(energy / energy[0] - 1)) < 1e-6


def periodic_record(channels, speed, rate, n, rng):
    """Frequencies, channels and band target of a periodic record drawn from the model."""
    u, y = synthetic_record(P, channels, speed, rate, n, rng)
    f = fft.rfftfreq(n, 1 / rate)
    return f, y, fft.irfft(band_power(f, (3.0 / speed, 25.0 / speed)) * fft.rfft(u), n)


def circular_wiener(channels, speed, f, y):
    w = np.zeros((f.size, len(channels)), complex)
    w[1:] = wiener_gains(P, channels, speed, f[1:])
    return fft.irfft(np.sum(w.T * fft.rfft(y, axis=1), axis=0), y.shape[1])


@pytest.mark.parametrize('channels', [[Channel(P['l_c'], ACC)],
                                      [Channel(0.0, ACC), Channel(None, GYRO)]],
                         ids=['above bogie', 'centre + gyro'])
def test_lmmse_posterior_matches_monte_carlo(channels):
    speed, rate, n = 20.0, 50.0, 2 ** 18  # 105 km of track
    f, y, z = periodic_record(channels, speed, rate, n, np.random.default_rng(7))
    err = circular_wiener(channels, speed, f, y) - z
    e = error_spectrum(P, channels, speed, f[1:])  # two-sided, m^2/Hz
    df = f[1]
    mse = 2 * np.sum(e) * df
    sampling_std = np.sqrt(4 * np.sum(e ** 2) * df * df / (n / rate) / df)  # of the mean of e^2
    assert abs(np.mean(err ** 2) - mse) < 4 * sampling_std
    assert sampling_std < 0.04 * mse  # the check tells a 16 % error in the variance
    assert posterior_rmse(P, channels, speed, rate) == pytest.approx(np.sqrt(mse), rel=0.01)


def test_finite_record_lmmse_is_the_conditional_mean():
    """With a period of the record's own length the covariances are circulant and the
    conjugate-gradient LMMSE must equal the per-frequency Wiener estimate."""
    channels = [Channel(0.0, ACC), Channel(None, GYRO)]
    speed, rate, n = 30.0, 100.0, 4096
    f, y, _ = periodic_record(channels, speed, rate, n, np.random.default_rng(2))
    z_hat, iterations = lmmse_estimate(P, channels, speed, y, rate, period_factor=1,
                                       rtol=1e-11)
    expect = circular_wiener(channels, speed, f, y)
    assert np.max(np.abs(z_hat - expect)) < 1e-6 * np.max(np.abs(expect))
    assert 0 < iterations < 300
