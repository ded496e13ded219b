"""Band design (EN 13848 bands as zero-phase FIR) and the partitioned streaming convolution."""

import itertools

import numpy as np
import pytest
from scipy import signal

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.band import (
    band_edges_hz,
    bandpass_power,
    design_grid,
    fir_taps,
    half_length,
    truncation_error,
)
from railgsa_ros.inverse.convolve import PartitionedFir


def test_band_edges_follow_speed():
    assert band_edges_hz('d1', 20.0) == pytest.approx((20 / 25, 20 / 3))
    assert band_edges_hz('d2', 35.0) == pytest.approx((0.5, 1.4))
    assert band_edges_hz('d3', 35.0) == pytest.approx((35 / 200, 0.5))
    assert band_edges_hz('2:70', 14.0) == pytest.approx((0.2, 7.0))
    assert band_edges_hz('wide', 20.0) == pytest.approx((0.1, 20.0))
    for bad in ('d4', '70:2', '0:5', 'a:b', '1:2:3'):
        with pytest.raises(ConfigError, match='band'):
            band_edges_hz(bad, 20.0)


@pytest.mark.parametrize('order', [1, 2, 4])
def test_bandpass_power_is_squared_analog_butterworth(order):
    lo, hi = 0.8, 6.5
    b, a = signal.butter(order, [2 * np.pi * lo, 2 * np.pi * hi], 'bandpass', analog=True)
    f = np.geomspace(0.01, 100.0, 400)
    _, h = signal.freqs(b, a, worN=2 * np.pi * f)
    assert np.allclose(bandpass_power(f, lo, hi, order), np.abs(h) ** 2, rtol=1e-9, atol=1e-15)
    assert bandpass_power(np.array([lo, hi]), lo, hi, order) == pytest.approx([0.5, 0.5])
    assert bandpass_power(np.array([0.0]), lo, hi, order)[0] == 0.0


@pytest.mark.parametrize('tol', [1e-4, 1e-6])
def test_fir_truncation_error_follows_tolerance(tol):
    lo, hi = band_edges_hz('d1', 15.0)
    f = design_grid(1000.0, lo)
    response = bandpass_power(f, lo, hi, 2)
    d = half_length(response, tol)
    taps = fir_taps(response, d)
    assert taps.shape == (2 * d + 1,)
    assert np.allclose(taps, taps[::-1], atol=1e-18)  # real response: linear phase
    err = truncation_error(taps, response)
    assert tol / 10 < err < 3 * tol
    # a shorter filter is measurably worse
    assert truncation_error(fir_taps(response, d // 2), response) > 10 * err


def test_fir_length_scales_inversely_with_speed():
    d = {}
    for v in (10.0, 40.0):
        lo, hi = band_edges_hz('d1', v)
        d[v] = half_length(bandpass_power(design_grid(1000.0, lo), lo, hi, 2), 1e-5)
    assert d[10.0] / d[40.0] == pytest.approx(4.0, rel=0.02)


def _reference(x, taps):
    return np.stack([np.convolve(xi, hi)[:x.shape[1]] for xi, hi in
                     zip(x, np.broadcast_to(taps, (x.shape[0], taps.shape[1])), strict=True)])


@pytest.mark.parametrize('length, shared', [(7, True), (33, False), (300, True), (5000, False)])
def test_partitioned_fir_matches_convolution_for_any_chunking(length, shared):
    rng = np.random.default_rng(length)
    x = rng.standard_normal((2, 9000))
    taps = rng.standard_normal((1 if shared else 2, length))
    ref = _reference(x, taps)
    whole = PartitionedFir(taps, 2).process(x)
    assert np.max(np.abs(whole - ref)) < 1e-12 * np.max(np.abs(ref))
    fir = PartitionedFir(taps, 2)
    cuts = np.unique(np.r_[0, rng.integers(0, x.shape[1], 30), np.arange(2040, 2060), 9000])
    parts = np.concatenate([fir.process(x[:, a:b]) for a, b in
                            itertools.pairwise(cuts)], axis=1)
    assert np.array_equal(parts, whole)  # bit-identical


def test_set_taps_at_switch_period_swaps_every_tap_at_once():
    rng = np.random.default_rng(3)
    old, new = rng.standard_normal((2, 1, 5000))
    x = rng.standard_normal(12000)
    fir = PartitionedFir(old, 1)
    n_sw = 2 * fir.switch_period
    first = fir.process(x[:n_sw])
    fir.set_taps(new)
    second = fir.process(x[n_sw:])
    assert np.allclose(first[0], np.convolve(x, old[0])[:n_sw], atol=1e-11)
    assert np.allclose(second[0], np.convolve(x, new[0])[n_sw:12000], atol=1e-11)


@pytest.mark.parametrize('speed, expected', [(8.0, 'invalid'), (18.0, 'degraded'),
                                             (30.0, 'valid')])
def test_d3_at_low_speed_is_flagged_by_the_noise_floor(speed, expected):
    """D3 (70-200 m) on the ADXL355 noise: the policy's noise floor (sigma_u through 1/G and
    the band, noise_limit_m 0.1 mm) makes every output INVALID below ~14 m/s, DEGRADED below
    ~22 m/s; the threshold is checked against the integral itself."""
    from railgsa_ros.imu import accel_covariance, imu_spec
    from railgsa_ros.input.options import InputOptions
    from railgsa_ros.input.stage import InputStage
    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.inverse.observability import band_noise_std
    from railgsa_ros.vehicle import VehicleParams

    var = accel_covariance(imu_spec('adxl355'))
    cfg = InversionConfig(band='d3', speed_mps=speed)
    sigma = band_noise_std(VehicleParams().as_array(), 'd3', 2, 1000.0, var, [speed])[0]
    assert (sigma > cfg.noise_limit_m) == (expected == 'invalid')
    policy = InputStage(cfg, options=InputOptions(use_odom=False), noise_variance=var)
    assert (speed < policy.noise.v_invalid) == (expected == 'invalid')
    assert (policy.noise.v_invalid <= speed < policy.noise.v_degraded) == (expected == 'degraded')
    assert 12.0 < policy.noise.v_invalid < 16.0 and 19.0 < policy.noise.v_degraded < 25.0


def test_the_noise_floor_table_is_shared_only_by_the_same_vehicle_and_sensor():
    """The policies of one run share one sigma_u table (a cache on vehicle, band, order, rate
    and variance); another vehicle or sensor gets its own, equal to the integral itself."""
    from railgsa_ros.inverse.observability import SPEED_GRID, NoiseFloor, band_noise_std
    from railgsa_ros.vehicle import VehicleParams

    theta, var = VehicleParams().as_array(), 3e-4
    first = NoiseFloor(theta, 'd1', 2, 1000.0, var)
    assert NoiseFloor(theta.copy(), 'd1', 2, 1000.0, var)._sigma is first._sigma
    for other, other_var in ((theta * np.array([1.2, 1, 1, 1, 1]), var), (theta, 2 * var)):
        floor = NoiseFloor(other, 'd1', 2, 1000.0, other_var)
        np.testing.assert_allclose(floor.sigma_m(SPEED_GRID),
                                   band_noise_std(other, 'd1', 2, 1000.0, other_var, SPEED_GRID),
                                   rtol=1e-12)
        assert not np.allclose(floor.sigma_m(SPEED_GRID), first.sigma_m(SPEED_GRID))
    with pytest.raises(ValueError):
        first._sigma[0] = 0.0  # shared: read-only
