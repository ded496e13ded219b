"""MEMS accelerometer model against independent truth (PSD, exact decimation, statistics)."""

import itertools
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from railgsa_ros.errors import ConfigError
from railgsa_ros.imu import (
    FRAME_ID,
    PRESETS,
    UG,
    G,
    ImuSpec,
    MemsStream,
    accel_covariance,
    dropout_mask,
    gyro_chain,
    gyro_covariance,
    imu_spec,
    load_imu,
    measure,
)

CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'imu.yaml'


def rest(duration_s, fs_in):
    """Times (s) and zero kinematic acceleration: a sensor at rest."""
    t = np.arange(round(duration_s * fs_in)) / fs_in
    return t, np.zeros_like(t)


def test_ideal_is_exact_decimation_of_a_band_limited_signal():
    fs_in, f_out = 2500.0, 1000.0  # rational ratio 2/5
    spec = imu_spec('ideal', output_rate_hz=f_out)
    t = np.arange(25000) / fs_in
    freqs = np.array([0.7, 2.33, 13.0, 57.3, 180.0, 0.39 * f_out])  # below the 0.4 f_out edge
    amps = np.array([0.3, 1.0, 0.5, 2.0, 0.2, 0.1])
    phases = np.linspace(0.1, 2.0, freqs.size)

    def truth(tt):
        return np.sin(2 * np.pi * freqs * tt[:, None] + phases) @ amps

    out = measure(t, truth(t), spec, seed=1)
    assert out.accel.shape == (10000, 3) and out.valid.all()
    np.testing.assert_allclose(out.t_true_s, np.arange(10000) / f_out, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out.stamps_ns, np.rint(out.t_true_s * 1e9).astype(np.int64))
    inner = slice(100, -100)  # away from the filter's edge transients
    # 80 dB Kaiser design: passband ripple 1e-4 of the amplitude sum
    np.testing.assert_allclose(out.accel[inner, 2], truth(out.t_true_s)[inner] + G,
                               rtol=0, atol=1e-4 * amps.sum())
    np.testing.assert_array_equal(out.accel[:, :2], 0.0)


def test_white_noise_psd_matches_density_and_covariance():
    nd = 100 * UG
    spec = ImuSpec(noise_density=nd, gravity=0.0, output_rate_hz=1000.0, antialias_ratio=0.4)
    t, a = rest(100.0, 4000.0)
    out = measure(t, a, spec, seed=2)
    f, pxx = signal.welch(out.accel, fs=1000.0, nperseg=2048, axis=0)
    band = (f > 5) & (f < 250)  # passband (edge at 0.3 f_out)
    # ~95 Welch segments x 500 bins x 3 axes: the mean PSD estimate is good to well under 1 %
    assert pxx[band].mean() == pytest.approx(nd ** 2, rel=0.03)
    # variance over the output bandwidth (REP 145 covariance diagonal)
    assert out.accel.var(axis=0) == pytest.approx([accel_covariance(spec)] * 3, rel=0.04)
    # the noise bandwidth sits a little below the -6 dB cut-off of 400 Hz
    assert 0.9 * 400.0 < accel_covariance(spec) / nd ** 2 < 400.0


def test_bias_scale_and_gravity_appear_exactly():
    spec = ImuSpec(bias=(0.1, -0.2, 0.3), scale_factor=0.01)
    t = np.arange(4000) / 2000.0
    a = 0.5 * np.sin(2 * np.pi * 3.0 * t)
    ref = measure(t, a, imu_spec('ideal'), seed=0).accel
    out = measure(t, a, spec, seed=0).accel
    np.testing.assert_allclose(out, 1.01 * ref + [0.1, -0.2, 0.3], rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(measure(*rest(1.0, 2000.0), spec).accel,
                               np.tile([0.1, -0.2, 1.01 * G + 0.3], (1000, 1)), rtol=1e-14)
    no_g = measure(*rest(1.0, 2000.0), imu_spec('ideal', gravity=0.0)).accel
    np.testing.assert_array_equal(no_g, 0.0)


@pytest.mark.parametrize('name', sorted(PRESETS))
def test_presets_at_rest_read_plus_g_on_z(name):
    spec = PRESETS[name]
    t, a = rest(20.0, 4 * spec.output_rate_hz)
    out = measure(t, a, spec, seed=3)
    z = out.accel[out.valid, 2]
    expected = (1 + spec.scale_factor) * G + spec.bias[2]
    # noise of the mean + bias random walk (std of its time average ~ rw sqrt(T/3)) + LSB
    tol = 5 * (np.sqrt(accel_covariance(spec) / z.size) + spec.bias_rw * np.sqrt(20.0 / 3)) \
        + spec.lsb
    assert z.mean() == pytest.approx(expected, abs=tol)
    assert abs(z.mean() - G) < 0.02 * G  # REP 145: +g on z, imu_link frame (z up)
    assert FRAME_ID == 'imu_link'


def test_bias_random_walk_grows_with_sqrt_time():
    rw = 1e-3
    spec = ImuSpec(bias_rw=rw, gravity=0.0, output_rate_hz=100.0)
    t, a = rest(400.0, 200.0)
    walk = measure(t, a, spec, seed=4).accel  # (40000, 3): increments N(0, rw^2 dt)
    inc = np.diff(walk, axis=0)
    assert inc.std() == pytest.approx(rw * np.sqrt(0.01), rel=0.02)
    assert abs(inc.mean()) < 5 * rw * np.sqrt(0.01) / np.sqrt(inc.size)


def test_clipping_at_range_and_quantisation_step():
    lsb, rng_ = 1e-3, 2 * G
    spec = ImuSpec(lsb=lsb, range_mps2=rng_, gravity=0.0, noise_density=1e-3)
    t = np.arange(20000) / 2000.0
    out = measure(t, 3 * G * np.sin(2 * np.pi * 1.0 * t), spec, seed=5).accel[:, 2]
    full = np.floor(rng_ / lsb) * lsb
    assert out.max() == pytest.approx(full) and out.min() == pytest.approx(-full)
    assert np.mean(np.abs(out) >= full - 1e-12) > 0.1  # saturated over a good part of each cycle
    codes = out / lsb
    np.testing.assert_allclose(codes, np.rint(codes), atol=1e-9)
    assert np.min(np.diff(np.unique(np.rint(codes)))) == 1
    unquantised = measure(t, 3 * G * np.sin(2 * np.pi * t), imu_spec('ideal', gravity=0.0,
                                                                      range_mps2=rng_)).accel
    assert unquantised.max() == rng_ and unquantised.min() == -rng_


def test_clock_drift_and_jitter_statistics():
    spec = ImuSpec(clock_drift_ppm=80.0, stamp_jitter_s=5e-4, output_rate_hz=500.0)
    t, a = rest(60.0, 1000.0)
    out = measure(t, a, spec, seed=6)
    stamps = out.stamps_ns * 1e-9
    slope, icept = np.polyfit(out.t_true_s, stamps, 1)
    # slope error of a least-squares fit: jitter / (std(t) sqrt(n))
    se = 5e-4 / (out.t_true_s.std() * np.sqrt(stamps.size))
    assert slope - 1 == pytest.approx(80e-6, abs=5 * se)
    resid = stamps - (slope * out.t_true_s + icept)
    assert resid.std() == pytest.approx(5e-4, rel=0.05)  # 30000 samples: 0.4 % standard error
    drift_only = measure(t, a, imu_spec('ideal', output_rate_hz=500.0, clock_drift_ppm=-50.0))
    np.testing.assert_array_equal(
        drift_only.stamps_ns, np.rint(np.arange(30000) / 500.0 * (1 - 50e-6) * 1e9))


def test_dropout_fraction_and_burst_length():
    spec = ImuSpec(dropout_fraction=0.05, dropout_burst_s=0.05, output_rate_hz=1000.0)
    valid = dropout_mask(2_000_000, spec, np.random.default_rng(7))
    lost = ~valid
    # about n f / L = 2000 bursts: the lost fraction is good to ~3 %, allow 4 sigma
    assert lost.mean() == pytest.approx(0.05, rel=0.12)
    edges = np.diff(np.concatenate([[0], lost.astype(int), [0]]))
    bursts = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    assert bursts.mean() == pytest.approx(50.0, rel=0.1)  # geometric, std ~ mean
    assert dropout_mask(1000, imu_spec('ideal'), np.random.default_rng(0)).all()


def test_effects_are_seeded_and_independent():
    t, a = rest(5.0, 2000.0)
    noisy = imu_spec('ideal', noise_density=1e-3)
    one = measure(t, a, noisy, seed=8)
    np.testing.assert_array_equal(one.accel, measure(t, a, noisy, seed=8).accel)
    assert not np.array_equal(one.accel, measure(t, a, noisy, seed=9).accel)
    with_drops = measure(t, a, imu_spec('ideal', noise_density=1e-3, dropout_fraction=0.1),
                         seed=8)
    np.testing.assert_array_equal(one.accel, with_drops.accel)
    assert 0 < (~with_drops.valid).sum() < with_drops.valid.size


@pytest.mark.parametrize(('kwargs', 'field'), [
    ({'noise_density': -1.0}, 'noise_density'),
    ({'antialias_ratio': 0.5}, 'antialias_ratio'),
    ({'range_mps2': 0.0}, 'range_mps2'),
    ({'dropout_fraction': 1.0}, 'dropout_fraction'),
    ({'bias': (1.0, 2.0)}, 'bias'),
    ({'gravity': 'abc'}, 'gravity'),
    ({'gravity': float('nan')}, 'gravity'),
    ({'loudness': 3}, 'loudness'),
    ({'gyro': 'yes'}, 'gyro'),
    ({'gyro_noise_density': -1e-4}, 'gyro_noise_density'),
    ({'gyro_range': 0.0}, 'gyro_range'),
    ({'gyro_bias': float('inf')}, 'gyro_bias'),
    ({'chip_cutoff_hz': 500.0}, 'chip_cutoff_hz'),  # not below the 1 kHz ODR's Nyquist
    ({'chip_order': 2.5}, 'chip_order'),
])
def test_invalid_fields_name_the_field(kwargs, field):
    with pytest.raises(ConfigError, match=field):
        imu_spec('adxl355', **kwargs)


def test_chip_filter_noise_psd_and_covariance_and_chunking():
    """With a chip filter (100 Hz, 4 poles) white noise leaves the sensor with the density
    times the Butterworth's |H|^2 = 1 / (1 + (f / fc)^8), and the covariance is its variance;
    the output does not depend on how the input is chunked (the filter keeps its state)."""
    nd = 100 * UG
    spec = ImuSpec(noise_density=nd, gravity=0.0, output_rate_hz=1000.0, chip_cutoff_hz=100.0)
    t, a = rest(100.0, 4000.0)
    out = measure(t, a, spec, seed=2)
    f, pxx = signal.welch(out.accel, fs=1000.0, nperseg=2048, axis=0)
    band = (f > 5) & (f < 200)
    butter = 1 / (1 + (f[band] / 100.0) ** 8)
    assert np.mean(pxx[band] / butter[:, None]) == pytest.approx(nd ** 2, rel=0.03)
    assert out.accel.var(axis=0) == pytest.approx([accel_covariance(spec)] * 3, rel=0.04)
    stream = MemsStream(spec, 4000.0, seed=2)
    cuts = [0, 1, 777, 5000, 123_457, a.shape[0]]
    parts = [stream.process(a[i:j], final=j == a.shape[0]).accel
             for i, j in itertools.pairwise(cuts)]
    np.testing.assert_array_equal(np.concatenate(parts), out.accel)


def test_chip_settings_come_from_the_datasheet_tables():
    """ADXL355: corner ODR / 4; BMI088: the acc_bwp table (normal 145 Hz at 400 Hz ODR, OSR2
    75 Hz, 80 Hz at 200 Hz); an unknown setting is one line naming the valid ones."""
    assert imu_spec('adxl355@4000Hz').chip_cutoff_hz == 1000.0
    assert imu_spec('adxl355@1000Hz').output_rate_hz == 1000.0
    assert imu_spec('bmi088@400Hz').chip_cutoff_hz == 145.0
    assert imu_spec('bmi088@400Hz-osr2').chip_cutoff_hz == 75.0
    assert imu_spec('bmi088@200Hz', noise_density=0.0).chip_cutoff_hz == 80.0
    for bad in ('bmi088@300Hz', 'adxl355@1000Hz-osr2', 'bmi088@400Hz-osr8', 'lsm6@100Hz'):
        with pytest.raises(ConfigError, match='expected'):
            imu_spec(bad)


def test_unknown_preset_and_bad_rate():
    with pytest.raises(ConfigError, match="'mpu6050'"):
        imu_spec('mpu6050')
    t, a = rest(1.0, 1000.0)
    with pytest.raises(ConfigError, match='output_rate_hz'):
        measure(t, a, imu_spec('ideal', output_rate_hz=700.0))  # more than half the input rate
    assert imu_spec('bmi088', noise_density='1e-3').noise_density == 1e-3  # YAML 1.1 strings


def test_load_imu(tmp_path):
    spec = load_imu(CONFIG)
    assert spec.name == 'adxl355' and spec.output_rate_hz == 1000.0
    bad = tmp_path / 'imu.yaml'
    bad.write_text('imu:\n  preset: bmi088\n  lsb: -1.0\n')
    with pytest.raises(ConfigError, match=r'imu\.yaml.*lsb'):
        load_imu(bad)
    bad.write_text('sensor: {}\n')
    with pytest.raises(ConfigError, match=r'imu\.yaml'):
        load_imu(bad)


def test_gyro_noise_bias_and_quantisation_follow_its_own_fields():
    spec = imu_spec('bmi088', gyro_bias_rw=0.0)
    fs = 4 * spec.output_rate_hz
    n = round(20.0 * fs)
    rate = np.column_stack([np.zeros(n), np.full(n, 0.01), np.zeros(n)])  # 0.01 rad/s pitch
    out = MemsStream(gyro_chain(spec), fs, seed=2).process(rate, final=True).accel
    # no gravity; the datasheet-like zero-rate offset on every axis, the rate through the
    # scale factor; white noise at the variance the messages state; values on the LSB grid
    expected = np.array([0.0, 0.01 * (1 + spec.scale_factor), 0.0]) + spec.gyro_bias
    tol = 5 * np.sqrt(gyro_covariance(spec) / out.shape[0] * 50)  # correlated by the filter
    np.testing.assert_allclose(out.mean(axis=0), expected, atol=tol)
    assert out[:, 0].var() == pytest.approx(gyro_covariance(spec), rel=0.1)
    np.testing.assert_allclose(out / spec.gyro_lsb, np.rint(out / spec.gyro_lsb), atol=1e-6)
    assert gyro_covariance(imu_spec('adxl355')) == -1.0  # no gyro: absent (REP 145)
    assert gyro_covariance(imu_spec('ideal')) == 0.0 and imu_spec('ideal').gyro
