"""Multirate band stage: streaming decimation/interpolation against scipy's upfirdn, the
anti-alias design, the choice of R, and the pipeline's frequency response at both rates."""

import itertools

import numpy as np
import pytest
from scipy import signal

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.band import band_edges_hz, bandpass_power
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.multirate import (
    PASS_FACTOR,
    MultirateFir,
    antialias_taps,
    decimation,
)
from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.vehicle import VehicleParams, frequency_response

RATE = 1000.0
F_TOP = band_edges_hz('d1', 70.0)[1]


def _reference(x, taps, r, a):
    """Offline: upfirdn decimation (y[m] = sum a[j] x[m r - j]), causal band FIR per row,
    upfirdn interpolation with gain r, cut to the input length."""
    rows = np.broadcast_to(x, (taps.shape[0], x.shape[-1])) if x.shape[0] == 1 else x
    out = []
    for xi, hi in zip(rows, np.broadcast_to(taps, (rows.shape[0], taps.shape[-1])), strict=True):
        y = signal.upfirdn(a, xi, 1, r)
        out.append(signal.upfirdn(r * a, np.convolve(y, hi)[:y.size], r, 1)[:xi.size])
    return np.array(out)


@pytest.mark.parametrize('dtype, rel', [(np.float64, 1e-12), (np.float32, 1e-6)])
@pytest.mark.parametrize('inputs, filters', [(1, 3), (3, 3), (3, 1)])
def test_streaming_equals_upfirdn_and_any_chunking_is_bit_identical(inputs, filters, dtype, rel):
    """Against float64 upfirdn: float64 to rounding, float32 rate changes to ~10 float32
    epsilons of the peak (far below the 1e-5 design tolerance that selects them)."""
    r = decimation(RATE, F_TOP)
    a = antialias_taps(RATE, r, F_TOP, 1e-5)
    rng = np.random.default_rng(inputs + filters)
    x = rng.standard_normal((inputs, 12000))
    taps = rng.standard_normal((filters, 700))
    whole = MultirateFir(taps, 3, r, a, dtype).process(x)
    ref = _reference(x, taps, r, a)
    assert whole.shape == (3, x.shape[1]) and whole.dtype == np.float64
    assert np.max(np.abs(whole - ref)) < rel * np.max(np.abs(ref))
    fir = MultirateFir(taps, 3, r, a, dtype)
    cuts = np.unique(np.r_[0, rng.integers(0, x.shape[1], 40), np.arange(2300, 2320), 12000])
    parts = np.concatenate([fir.process(x[:, lo:hi]) for lo, hi in itertools.pairwise(cuts)],
                           axis=1)
    assert np.array_equal(parts, whole)


@pytest.mark.parametrize('method, tol, dtype', [
    ('spectral', 1e-5, np.float32), ('spectral', 1e-3, np.float32), ('spectral', 1e-7, np.float64),
    ('feedback', 1e-5, np.float64), ('kalman', 1e-3, np.float64)])
def test_rate_changes_run_in_float32_only_on_the_measured_acceleration(method, tol, dtype):
    cfg = InversionConfig(method=method, fir_tolerance=tol, frame_id='')
    assert InversionPipeline(cfg)._fir.dtype is dtype


def test_antialias_filter_is_flat_in_the_passband_and_rejects_aliases():
    r = decimation(RATE, F_TOP)
    tol = 1e-5
    a = antialias_taps(RATE, r, F_TOP, tol)
    assert a.size % 2 == 1 and np.allclose(a, a[::-1], rtol=0, atol=1e-18)
    f_pass = PASS_FACTOR * F_TOP
    f, h = signal.freqz(a, worN=np.linspace(0, RATE / 2, 20001), fs=RATE)
    # Kaiser ripple ~ tol (kaiserord's estimate is approximate: allow 2x)
    assert np.max(np.abs(np.abs(h[f <= f_pass]) - 1)) < 2 * tol
    assert np.max(np.abs(h[f >= RATE / r - f_pass])) < 2 * tol


def test_decimation_keeps_the_band_inside_the_low_rate():
    r = decimation(RATE, F_TOP)
    assert r == 9  # 70 m/s, 3 m: 23.3 Hz; passband to 35 Hz; fs / R = 111 Hz
    assert RATE / r >= 3 * PASS_FACTOR * F_TOP > RATE / (r + 1)
    assert decimation(100.0, F_TOP) < 2


@pytest.mark.parametrize('multirate', [True, False])
def test_pipeline_response_to_a_sinusoid_is_the_zero_phase_inverse(multirate):
    """Steady state: a = cos(2 pi f t) -> u = Re(|BP(f)|^2 / G(j 2 pi f) e^{j 2 pi f t}) at the
    sample's own stamp (zero phase with the delay removed), up to the FIR tolerance."""
    speed = 40.0
    cfg = InversionConfig(min_design_speed_mps=speed, taper_s=0.0, frame_id='',
                          multirate=multirate)
    lo, hi = band_edges_hz('d1', speed)
    f = np.array([0.5 * lo, lo, 5.0, hi, 2 * hi])
    h = bandpass_power(f, lo, hi, 2) / frequency_response(VehicleParams().as_array(),
                                                           2j * np.pi * f)
    t = np.arange(30000) / RATE
    stamps = np.round(t * 1e9).astype(np.int64)
    peak = np.max(np.abs(h))
    for fi, hi_ in zip(f, h, strict=True):
        pipe = InversionPipeline(cfg)
        out = pipe.push(stamps, cfg.gravity_mps2 + np.cos(2 * np.pi * fi * t), speed)
        assert pipe.decimation == (9 if multirate else 1)
        tk = out.stamps_ns[2 * pipe.delay_samples:] * 1e-9
        want = np.real(hi_ * np.exp(2j * np.pi * fi * tk))
        assert np.max(np.abs(out.u_m[2 * pipe.delay_samples:] - want)) < 5e-5 * peak


def test_speeds_above_max_speed_hold_the_band_design():
    cfg = InversionConfig(min_design_speed_mps=20.0, max_speed_mps=30.0, frame_id='')
    rng = np.random.default_rng(1)
    stamps = np.arange(20000, dtype=np.int64) * 1_000_000
    acc = cfg.gravity_mps2 + rng.standard_normal(stamps.size)
    held = InversionPipeline(cfg).push(stamps, acc, 45.0)
    at_max = InversionPipeline(cfg).push(stamps, acc, 30.0)
    assert np.array_equal(held.u_m, at_max.u_m)
    with pytest.raises(ConfigError, match='max_speed_mps'):
        InversionConfig(min_design_speed_mps=50.0, max_speed_mps=40.0)


def test_slow_sensor_falls_back_to_single_rate():
    cfg = InversionConfig(rate_hz=100.0, min_design_speed_mps=20.0)
    pipe = InversionPipeline(cfg)
    assert pipe.decimation == 1
    assert pipe.delay_samples == InversionPipeline(cfg.with_(multirate=False)).delay_samples
