"""InputStage: live-style feeding equals offline feeding at variable speed with stops, quality
states against the simulation's truth, and the plausibility findings."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from railgsa_ros.imu import imu_spec
from railgsa_ros.input.findings import ERROR, OK, WARN
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.samples import pieces
from railgsa_ros.scenario import run_scenario
from railgsa_ros.speed_profile import parse_speed_profile

ODOM_EVERY = 20  # odometry at 50 Hz next to a 1 kHz IMU
NO_DROPOUTS = imu_spec('adxl355', dropout_fraction=0.0)  # the tests make their own gaps


def _covariance(run, n=None) -> np.ndarray:
    cov = np.zeros((run.stamps_ns.size if n is None else n, 9))
    cov[:, [0, 4, 8]] = run.accel_covariance
    return cov


@pytest.fixture(scope='module')
def stop_and_go():
    """Accelerate 0 -> 25 m/s, cruise, brake to a standstill, stand, restart: 80 s at 1 kHz."""
    profile = np.array([0.0, 8, 16, 25, 25, 25, 24, 12, 0, 0, 0, 0, 6, 14, 20, 20])
    return run_scenario('german-low', profile, 80.0, None, 'adxl355', seed=3)


def offline(run, policy: InputStage, odom=True) -> Output:
    """Offline feeding: all odometry first, then the IMU in chunks of 65536, then flush."""
    outs = []
    if odom:
        outs.append(policy.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY]))
    cov = _covariance(run)
    for sl in pieces(run.stamps_ns.size):
        outs.append(policy.imu(run.stamps_ns[sl], run.accel[sl], None, cov[sl]))
    outs.append(policy.flush())
    return Output.concat(outs)


def live(run, policy: InputStage, seed: int, max_lag_s: float = 0.3) -> Output:
    """Live feeding: IMU batches of 1..500 samples as they arrive (at their last stamp),
    odometry messages one at a time arriving with a random lag of 0..max_lag_s."""
    rng = np.random.default_rng(seed)
    bounds = np.cumsum(rng.integers(1, 501, size=run.stamps_ns.size))
    bounds = np.concatenate([[0], bounds[bounds < run.stamps_ns.size], [run.stamps_ns.size]])
    events = [(int(run.stamps_ns[hi - 1]), 1, lo, hi)
              for lo, hi in itertools.pairwise(bounds)]
    odom_t, odom_v = run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY]
    lag = rng.uniform(0, max_lag_s * 1e9, odom_t.size).astype(np.int64)
    arrival = np.maximum.accumulate(odom_t + lag)  # one odometry topic: in stamp order
    events += [(int(a), 0, i, i + 1) for i, a in enumerate(arrival)]
    events.sort()
    cov = _covariance(run)
    outs = []
    for _, kind, lo, hi in events:
        if kind == 0:
            outs.append(policy.odometry(odom_t[lo:hi], odom_v[lo:hi]))
        else:
            outs.append(policy.imu(run.stamps_ns[lo:hi], run.accel[lo:hi], None, cov[lo:hi]))
    outs.append(policy.flush())
    return Output.concat(outs)


def assert_identical(a: Output, b: Output) -> None:
    for name in ('stamps_ns', 'chainage_m', 'u_m', 'quality', 'speed_mps'):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name


def test_live_feeding_equals_offline_bit_for_bit_at_variable_speed_with_stops(stop_and_go):
    run = stop_and_go
    cfg = InversionConfig(rate_hz=run.rate_hz)
    ref = offline(run, InputStage(cfg))
    for seed in (1, 2):
        assert_identical(live(run, InputStage(cfg), seed), ref)
    # every accepted IMU sample has exactly one output, in order
    np.testing.assert_array_equal(ref.stamps_ns, run.stamps_ns)
    # and the speed of each output is the odometry held at its stamp (independent lookup)
    odom_t, odom_v = run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY]
    held = odom_v[np.searchsorted(odom_t, run.stamps_ns, side='right') - 1]
    np.testing.assert_array_equal(ref.speed_mps, held)


def test_standstill_and_low_speed_are_invalid_nan_and_cruise_is_valid(stop_and_go):
    run = stop_and_go
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    out = offline(run, policy)
    q, v = out.quality, out.speed_mps
    assert np.all(q[v < policy.noise.v_invalid] == Quality.INVALID)
    assert np.all(np.isnan(out.u_m[q == Quality.INVALID]))
    assert np.all(np.isfinite(out.u_m[q != Quality.INVALID]))
    standing = run.speed_mps == 0
    assert standing.sum() > 5000 and np.all(q[standing] == Quality.INVALID)
    # below min_design_speed_mps the band design is held: at best DEGRADED
    assert np.all(q[(v >= policy.noise.v_invalid) & (v < 10.0)] >= Quality.DEGRADED)
    # the cruise at 25 m/s is VALID; accelerating and braking at ~1.5 m/s^2 is DEGRADED
    # (the speed across the band window is off its design by more than 5 %)
    cruise = np.abs(v - 25.0) < 0.01
    assert cruise.sum() > 10000 and np.sum(q[cruise] == Quality.VALID) > 0.8 * cruise.sum()
    ramp = (v > 12.0) & (v < 22.0) & (np.arange(v.size) < np.flatnonzero(cruise)[0])
    assert ramp.sum() > 2000 and np.all(q[ramp] >= Quality.DEGRADED)
    counts = policy.counters
    assert counts['speed_change'] > ramp.sum()
    assert counts['valid'] + counts['degraded'] + counts['invalid'] == run.stamps_ns.size


def test_no_odometry_means_unknown_speed_invalid_and_a_finding():
    run = run_scenario('german-low', 20.0, 20.0, None, 'adxl355', seed=1)
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    out = offline(run, policy, odom=False)
    assert len(out) == run.stamps_ns.size
    assert np.all(out.quality == Quality.INVALID) and np.all(np.isnan(out.u_m))
    assert policy.counters['speed_unknown'] == run.stamps_ns.size
    assert policy.status.level == WARN and 'odom' in policy.status.message
    # the fallback speed only when asked for
    fixed = InputStage(InversionConfig(rate_hz=run.rate_hz, speed_mps=20.0),
                        options=InputOptions(use_odom=False))
    out = offline(run, fixed, odom=False)
    assert np.sum(out.quality == Quality.VALID) > 0


def test_nan_odometry_keeps_every_imu_sample():
    # no sensor dropouts: a bridged gap would degrade what follows (not this test's subject)
    run = run_scenario('german-low', 20.0, 20.0, None,
                       imu_spec('adxl355', dropout_fraction=0.0), seed=2)
    speed = run.speed_mps.copy()
    speed[::ODOM_EVERY][::3] = np.nan  # a third of the odometry messages are NaN
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    outs = [policy.odometry(run.stamps_ns[::ODOM_EVERY], speed[::ODOM_EVERY])]
    outs.append(policy.imu(run.stamps_ns, run.accel, None, _covariance(run)))
    outs.append(policy.flush())
    out = Output.concat(outs)
    np.testing.assert_array_equal(out.stamps_ns, run.stamps_ns)
    assert policy.counters['odom_nan'] == len(speed[::ODOM_EVERY][::3])
    assert np.sum(out.quality == Quality.VALID) > 0
    assert {f.key: f.level for f in policy.findings}['odometry'] == WARN


def test_negative_speed_is_reverse_running_with_decreasing_chainage():
    run = run_scenario('german-low', 20.0, 20.0, None,
                       imu_spec('adxl355', dropout_fraction=0.0), seed=2)
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    policy.odometry(run.stamps_ns[::ODOM_EVERY], -run.speed_mps[::ODOM_EVERY])
    out = Output.concat([policy.imu(run.stamps_ns, run.accel, None, _covariance(run)),
                         policy.flush()])
    assert np.all(np.diff(out.chainage_m) < 0)
    assert policy.counters['reverse'] == run.stamps_ns.size
    assert np.sum(out.quality == Quality.VALID) > 0
    assert 'reverse' in policy.status.message


def test_gravity_on_minus_y_is_a_finding_naming_the_axis_and_invalid_outputs():
    run = run_scenario('german-low', 20.0, 20.0, None, 'adxl355', seed=4)
    accel = np.zeros_like(run.accel)
    accel[:, 0], accel[:, 1], accel[:, 2] = run.accel[:, 0], -run.accel[:, 2], run.accel[:, 1]
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    policy.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY])
    out = Output.concat([policy.imu(run.stamps_ns, accel, None, _covariance(run)),
                         policy.flush()])
    assert np.all(out.quality == Quality.INVALID) and np.all(np.isnan(out.u_m))
    finding = {f.key: f for f in policy.findings}['gravity']
    assert finding.level == ERROR and "accel_axis to '-y'" in finding.message
    # configured right, the same data is fine
    fixed = InputStage(InversionConfig(rate_hz=run.rate_hz, accel_axis='-y'))
    fixed.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY])
    out = Output.concat([fixed.imu(run.stamps_ns, accel, None, _covariance(run)),
                         fixed.flush()])
    assert np.sum(out.quality == Quality.VALID) > 0
    assert {f.key: f.level for f in fixed.findings}['gravity'] == OK


def test_rate_hz_disagreeing_with_the_data_is_an_error_finding_and_invalid():
    run = run_scenario('german-low', 20.0, 20.0, None, 'adxl355', seed=5)
    policy = InputStage(InversionConfig(rate_hz=800.0))
    policy.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY])
    out = Output.concat([policy.imu(run.stamps_ns, run.accel, None, _covariance(run)),
                         policy.flush()])
    finding = {f.key: f for f in policy.findings}['rate']
    assert finding.level == ERROR and 'set rate_hz to 10' in finding.message
    # INVALID from the end of the first block of steps on
    assert np.all(out.quality[600:] == Quality.INVALID)


def test_every_sample_rejected_for_its_frame_is_status_error():
    run = run_scenario('german-low', 20.0, 3.0, None, 'adxl355', seed=6)
    frames = np.full(run.stamps_ns.size, 'bad_frame')
    strict = InputStage(InversionConfig(rate_hz=run.rate_hz),
                         options=InputOptions(wrong_frame_policy='reject'))
    strict.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY])
    out = Output.concat([strict.imu(run.stamps_ns, run.accel, frames), strict.flush()])
    assert len(out) == 0
    assert strict.status.level == ERROR and 'wrong_frame' in strict.status.message
    # the default accepts a driver's own frame with a warning
    lenient = InputStage(InversionConfig(rate_hz=run.rate_hz))
    lenient.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY])
    out = Output.concat([lenient.imu(run.stamps_ns, run.accel, frames), lenient.flush()])
    assert len(out) == run.stamps_ns.size
    finding = {f.key: f for f in lenient.findings}['frame']
    assert finding.level == WARN and "'bad_frame'" in finding.message


def test_warm_up_after_a_dropout_reset_is_invalid_and_the_valid_rest_is_accurate():
    """A 0.2 s dropout with the reset policy: outputs whose band window reaches into the
    restart are INVALID; VALID outputs match the same run without the dropout."""
    run = run_scenario('german-low', 20.0, 40.0, None, NO_DROPOUTS, seed=7)
    keep = np.ones(run.stamps_ns.size, bool)
    keep[20000:20200] = False
    cfg = InversionConfig(rate_hz=run.rate_hz, gap_policy='reset')

    def invert(mask):
        policy = InputStage(cfg)
        policy.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY])
        out = Output.concat([policy.imu(run.stamps_ns[mask], run.accel[mask], None,
                                        _covariance(run, int(mask.sum()))), policy.flush()])
        return out, policy

    out, policy = invert(keep)
    ref, _ = invert(np.ones(run.stamps_ns.size, bool))
    assert policy.counters['reset'] == 1
    d = int(policy.pipeline.window_half_width(np.array([20.0]))[0])  # the band window
    warm = d + round(cfg.taper_s * cfg.rate_hz)
    after = np.flatnonzero(out.stamps_ns > run.stamps_ns[20199])
    assert np.all(out.quality[after[:warm]] == Quality.INVALID)
    before = np.flatnonzero(out.stamps_ns < run.stamps_ns[20000])
    assert np.all(out.quality[before[-d:]] == Quality.INVALID)  # the tail before the reset
    valid = out.quality == Quality.VALID
    idx = np.searchsorted(ref.stamps_ns, out.stamps_ns[valid])
    err = out.u_m[valid] - ref.u_m[idx]
    assert np.max(np.abs(err)) < 0.05e-3, np.max(np.abs(err))  # 1.9 mm before the policy


def test_bridged_stretch_degrades_its_window():
    run = run_scenario('german-low', 20.0, 40.0, None, NO_DROPOUTS, seed=8)
    keep = np.ones(run.stamps_ns.size, bool)
    keep[20000:20100] = False  # 0.1 s: bridged with the default policy
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    policy.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY])
    out = Output.concat([policy.imu(run.stamps_ns[keep], run.accel[keep], None,
                                    _covariance(run, int(keep.sum()))), policy.flush()])
    assert policy.counters['bridged'] > 0
    d = int(policy.pipeline.window_half_width(np.array([20.0]))[0])
    t_gap = run.stamps_ns[[19999, 20100]]
    reach = d * 1e6 - 2e6  # D periods of 1 ms, less the stamp jitter
    near = (out.stamps_ns > t_gap[0] - reach) & (out.stamps_ns < t_gap[1] + reach)
    assert np.all(out.quality[near] >= Quality.DEGRADED)
    far = (out.stamps_ns < t_gap[0] - (d + 2) * 1e6) & (out.quality != Quality.INVALID)
    assert far.sum() > 1000 and np.all(out.quality[far] == Quality.VALID)


def _noise_only(policy: InputStage, rate_hz: float, sigma: float, seconds: float) -> Output:
    """Gravity plus white noise of std ``sigma`` on z, at a fixed speed: the reconstruction is
    pure propagated sensor noise."""
    n = int(seconds * rate_hz)
    accel = np.zeros((n, 3))
    accel[:, 2] = 9.80665 + sigma * np.random.default_rng(11).standard_normal(n)
    stamps = 10**18 + np.arange(n, dtype=np.int64) * round(1e9 / rate_hz)
    return Output.concat([policy.imu(stamps, accel), policy.flush()])


def test_low_speed_threshold_matches_a_noise_only_monte_carlo():
    """sigma_u(v) of the noise floor (the integral over 1/G and the band) against the std of
    the reconstruction of 900 s of pure sensor noise through the pipeline (band designed at the
    speed itself: min_design_speed_mps 2 m/s), and the INVALID speed it derives."""
    rate, sigma, limit = 200.0, 0.02, 1e-3

    def policy(speed):
        cfg = InversionConfig(rate_hz=rate, speed_mps=speed, min_design_speed_mps=2.0,
                              max_speed_mps=10.0, noise_limit_m=limit)
        return InputStage(cfg, options=InputOptions(use_odom=False, stuck_s=0.0),
                           noise_variance=sigma ** 2)

    v_invalid = policy(5.0).noise.v_invalid
    assert 2.0 < v_invalid < 3.0  # where sigma_u(v) = 1 mm for this sensor
    for speed in (1.1 * v_invalid, 3.0, 5.0):
        p = policy(speed)
        out = _noise_only(p, rate, sigma, 900.0)
        kept = out.quality != Quality.INVALID
        assert kept.sum() > 800 * rate
        measured = np.std(out.u_m[kept])
        predicted = float(p.noise.sigma_m(np.array([speed]))[0])
        # 900 s of noise in a band 0.1-1.7 Hz wide: about 500 independent values, 3 % error
        assert measured == pytest.approx(predicted, rel=0.08), speed
    # at 1.1 v_invalid the measured noise is just below the limit; below v_invalid: INVALID
    slow = _noise_only(policy(0.95 * v_invalid), rate, sigma, 300.0)
    assert np.all(slow.quality == Quality.INVALID) and np.all(np.isnan(slow.u_m))


def test_band_follows_the_policy_at_variable_speed(stop_and_go):
    """uncertainty_node's streaming code through its own policy over the bank: the same
    stamps and qualities as the nominal policy, NaN where INVALID, widened where DEGRADED."""
    from railgsa_ros.uncertainty import UncertaintyConfig, offline_bands

    run = stop_and_go
    cfg = InversionConfig(rate_hz=run.rate_hz)
    ref = offline(run, InputStage(cfg))
    band = offline_bands(run.stamps_ns, run.accel,
                         (run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY]),
                         covariance=_covariance(run),
                         config=UncertaintyConfig(inversion=cfg, rule='pem3', order=1,
                                                  germ_samples=256))
    np.testing.assert_array_equal(band.stamps_ns, ref.stamps_ns)
    np.testing.assert_array_equal(band.quality, ref.quality)
    invalid = band.quality == Quality.INVALID
    for values in (band.lower_m, band.mean_m, band.upper_m):
        assert np.all(np.isnan(values[invalid])) and np.all(np.isfinite(values[~invalid]))
    degraded = band.quality == Quality.DEGRADED
    assert degraded.sum() > 1000
    # the DEGRADED floor: a sensor std of at least noise_limit_m, about 1.96 of it each side
    # (the 2.5/97.5 % quantiles of 256 germ samples: 1.87 at the least here)
    half = (band.upper_m - band.lower_m)[degraded] / 2
    assert np.all(half >= 1.8 * cfg.noise_limit_m)


@pytest.mark.parametrize('axis', ['z', '-y'])
def test_noise_is_the_median_of_the_first_reported_variances_skipping_absent_and_unknown(axis):
    """The noise rule against an independent computation: the median of the configured axis'
    variance over the first NOISE_SAMPLES samples; REP 145 covariance[0] == -1 (acceleration
    absent: the sample is rejected as nan) and all-zero covariances (unknown) are skipped;
    later samples do not count; with none reported, noise_std_mps2^2."""
    from railgsa_ros.input.noise import NOISE_SAMPLES

    run = run_scenario('german-low', 20.0, 1.0, None, 'adxl355', seed=6)
    n = 300
    stamps, accel = run.stamps_ns[:n], run.accel[:n].copy()
    if axis == '-y':
        accel[:, 1], accel[:, 2] = -run.accel[:n, 2], run.accel[:n, 1]
    rng = np.random.default_rng(11)
    cov = np.zeros((n, 9))
    cov[:, [0, 4, 8]] = rng.uniform(1e-6, 1e-3, (n, 3))
    kind = rng.choice(['known', 'absent', 'zero'], n, p=[0.5, 0.25, 0.25])
    cov[kind == 'absent', 0] = -1.0
    cov[kind == 'zero'] = 0.0
    col = {'z': 8, '-y': 4}[axis]
    head = slice(0, NOISE_SAMPLES)
    known = [cov[i, col] for i in range(NOISE_SAMPLES) if kind[i] == 'known']
    expected = sorted(known)[len(known) // 2] if len(known) % 2 else \
        (sorted(known)[len(known) // 2 - 1] + sorted(known)[len(known) // 2]) / 2
    assert 0 < len(known) < NOISE_SAMPLES and expected != np.median(cov[:, col])
    options = InputOptions(use_odom=False)
    cfg = InversionConfig(rate_hz=run.rate_hz, accel_axis=axis, speed_mps=20.0)
    policy = InputStage(cfg, options=options)
    for lo in range(0, n, 37):  # batching does not matter
        policy.imu(stamps[lo:lo + 37], accel[lo:lo + 37], None, cov[lo:lo + 37])
    assert policy.noise_variance == pytest.approx(expected, rel=1e-12)
    assert f'median of {len(known)}' in policy.noise_source
    policy.flush()  # the last reorder_window_s of samples wait for their stamp order
    assert policy.counters.get('nan', 0) == int(np.sum(kind == 'absent'))  # absent: rejected
    # none reported in the head (absent or all zero): the configured noise_std_mps2
    silent = cov.copy()
    silent[head] = 0.0
    silent[head][kind[head] == 'absent', 0] = -1.0
    fallback = InputStage(cfg, options=options)
    fallback.imu(stamps, accel, None, silent)
    assert fallback.noise_variance == pytest.approx(cfg.noise_std_mps2 ** 2, rel=1e-12)
    assert 'noise_std_mps2' in fallback.noise_source


def test_samples_lost_between_close_stamps_are_counted_and_degrade_not_valid():
    """Every tenth IMU sample missing (what BEST_EFFORT loss looks like: two-period steps,
    shorter than a gap): the record would close up around them, so the policy counts them as
    lost, keeps the rate right, and publishes nothing VALID after the first block; the same run
    without the loss stays VALID with no loss counted."""
    run = run_scenario('german-low', 20.0, 8.0, None, 'adxl355', seed=5)
    keep = np.arange(run.stamps_ns.size) % 10 != 5
    results = {}
    for name, mask in (('lossy', keep), ('clean', np.ones_like(keep))):
        policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
        policy.odometry(run.stamps_ns[::ODOM_EVERY], run.speed_mps[::ODOM_EVERY])
        out = Output.concat([policy.imu(run.stamps_ns[mask], run.accel[mask], None,
                                        _covariance(run)[mask]), policy.flush()])
        results[name] = (out, policy.counters, {f.key: f for f in policy.findings}['rate'])
    out, counters, finding = results['lossy']
    blocks = keep.sum() // 512
    assert abs(counters['lost'] - (blocks - 0) * 512 / 9) < 0.1 * blocks * 512 / 9 + 5
    assert finding.level == WARN and 'lost' in finding.message
    measured = float(finding.message.split('measured IMU rate ')[1].split(' Hz')[0])
    assert abs(measured / run.rate_hz - 1) < 0.005  # the sensor's rate, not 900 Hz
    assert counters.get('rate_invalid', 0) == 0
    assert not np.any(out.quality[600:] == Quality.VALID)
    out, counters, finding = results['clean']
    assert counters.get('lost', 0) == 0 and finding.level == OK
    assert np.sum(out.quality[600:] == Quality.VALID) > 1000


@pytest.mark.parametrize('rate_hz, loss', [(1000.0, 'every 50th'), (1000.0, 'bursts of 5'),
                                            (800.0, 'every 50th')])
def test_jittered_stamps_with_lost_samples_are_counted_not_another_rate(rate_hz, loss):
    """0.22 ms of host-stamp jitter (22 % of the period) with samples removed, rate_hz 1000:
    every 50th lost is counted as lost (DEGRADED, the 'lost' WARN: not INVALID with "set
    rate_hz", as the phase-locked loop did); bursts of 5 are gaps (6 periods), not losses;
    800 Hz data is 800 Hz (ERROR "set rate_hz to 800"), not 1 kHz with lost samples."""
    n, g = 2700, 9.80665  # 5 rate blocks
    rng = np.random.default_rng(7)
    k = np.arange(n)
    keep = k % 50 != 25 if loss == 'every 50th' else k % 500 >= 5
    stamps = 10**18 + np.rint(k / rate_hz * 1e9 + rng.normal(0, 0.22e6, n)).astype(np.int64)
    accel = 0.02 * rng.standard_normal((n, 3)) + [0.0, 0.0, g]
    policy = InputStage(InversionConfig(rate_hz=1000.0))
    odom = np.arange(stamps[0], stamps[-1] + 10**9, 20 * 10**6)
    policy.odometry(odom, np.full(odom.size, 20.0))
    out = Output.concat([policy.imu(stamps[keep], accel[keep], None, None), policy.flush()])
    counters, finding = policy.counters, {f.key: f for f in policy.findings}['rate']
    measured = float(finding.message.split('measured IMU rate ')[1].split(' Hz')[0])
    assert abs(measured / rate_hz - 1) < 0.005
    if rate_hz != 1000.0:
        assert finding.level == ERROR and f'set rate_hz to {measured:.6g}' in finding.message
        assert counters['rate_invalid'] == keep.sum() - 513  # all after the first block
        assert np.all(out.quality == Quality.INVALID)
        return
    assert counters.get('rate_invalid', 0) == 0
    blocks_end = np.sort(stamps[keep])[5 * 512]  # the last sample the rate blocks saw
    truth = int(np.count_nonzero(~keep & (stamps <= blocks_end)))
    if loss == 'every 50th':
        assert abs(counters['lost'] - truth) <= 2 * 5 and finding.level == WARN
        assert 'lost' in finding.message
    else:
        assert counters.get('lost', 0) == 0 and counters['gap'] == 5 and finding.level == OK


def _valid_error(run, policy: InputStage) -> tuple[np.ndarray, Output]:
    """Error (m) of the VALID outputs against the truth band-passed on distance at their true
    chainage (100 m left out at each end), and the output."""
    out = offline(run, policy)
    idx = np.searchsorted(run.stamps_ns, out.stamps_ns)  # no dropouts: every stamp is a sample
    dx = 0.25
    x = np.arange(run.chainage_m[0], run.chainage_m[-1], dx)
    truth = band_distance(np.interp(x, run.chainage_m, run.truth_u_m), dx)
    c = run.chainage_m[idx]
    keep = (out.quality == Quality.VALID) & (c > x[0] + 100) & (c < x[-1] - 100)
    return out.u_m[keep] - np.interp(c[keep], x, truth), out


@pytest.mark.parametrize('accel', [1.2, 2.0])
def test_valid_outputs_under_braking_are_as_accurate_as_at_constant_speed(accel):
    """Braking 28 -> 14 m/s between two cruises: the time-domain band maps wavelengths by its
    design speed, so outputs whose band window sees the speed change by more than
    window_speed_tolerance are DEGRADED (counted, 'acceleration' finding); the VALID ones stay
    within twice the error of a constant-speed run over the same track (before: 0.3 mm
    errors published as VALID at 2 m/s^2)."""
    prof = parse_speed_profile(f'cruise:28:8s,brake:28-14:{14 / accel:.4g}s,cruise:14:8s')
    run = run_scenario('german-low', prof, prof.duration_s, None, NO_DROPOUTS, seed=2)
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    err, out = _valid_error(run, policy)
    steady = run_scenario('german-low', 21.0, prof.duration_s, None, NO_DROPOUTS, seed=2)
    ref_policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    ref, _ = _valid_error(steady, ref_policy)
    assert err.size > 2000 and ref.size > 10000
    rms, ref_rms = np.sqrt(np.mean(err ** 2)), np.sqrt(np.mean(ref ** 2))
    assert rms < 2.0 * ref_rms, (rms, ref_rms)
    assert np.max(np.abs(err)) < 3.0 * np.max(np.abs(ref))
    ramp = (out.speed_mps > 15.0) & (out.speed_mps < 27.0)
    assert ramp.sum() > 4000 and np.all(out.quality[ramp] == Quality.DEGRADED)
    assert policy.counters['speed_change'] > ramp.sum()
    finding = {f.key: f for f in policy.findings}['acceleration']
    assert 'more than 5%' in finding.message  # WARN while such outputs come, then OK
    # at constant speed nothing is raised and there is no such finding
    assert ref_policy.counters.get('speed_change', 0) == 0
    assert 'acceleration' not in {f.key for f in ref_policy.findings}


def _jittered(jitter_s: float) -> tuple[Output, InputStage, np.ndarray]:
    """20 m/s for 20 s with host-stamp jitter of std ``jitter_s``: (output, policy, error of
    the VALID outputs against the truth on distance)."""
    run = run_scenario('german-low', 20.0, 20.0, None,
                       imu_spec('adxl355', dropout_fraction=0.0, stamp_jitter_s=jitter_s),
                       seed=10)  # the median step made 1536 outputs INVALID on this one
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz))
    err, out = _valid_error(run, policy)
    return out, policy, err


def test_harmless_stamp_jitter_keeps_the_outputs_valid_and_accurate():
    """0.2 ms of stamp jitter at 1 kHz (a host-stamped driver) is 4 mm of chainage at 20 m/s:
    the rate check counts per stamp, so no output is INVALID or DEGRADED for it (the median
    step made up to 8 % of them INVALID), and the VALID ones are as accurate as without
    jitter."""
    ref, _, ref_err = _jittered(0.0)
    out, policy, err = _jittered(2e-4)
    counters = policy.counters
    assert counters.get('rate_invalid', 0) == 0 and counters.get('jitter', 0) == 0
    assert counters.get('lost', 0) == 0
    # the same outputs VALID but for the few samples whose stamps came out of order
    rejected = counters.get('out_of_order', 0)
    assert rejected < 20 and not np.any(out.quality == Quality.DEGRADED)
    assert abs(counters['valid'] - np.sum(ref.quality == Quality.VALID)) <= rejected
    assert {f.key: f.level for f in policy.findings}['rate'] == OK
    assert 'jitter' not in {f.key for f in policy.findings}
    assert abs(err.size - ref_err.size) <= rejected and err.size > 5000
    # measured 1.3x on this run: its 2 stamps out of order are rejected, i.e. lost
    assert np.sqrt(np.mean(err ** 2)) < 1.5 * np.sqrt(np.mean(ref_err ** 2))


def test_stamp_jitter_that_reorders_stamps_is_a_counted_warning_and_degraded():
    """0.35 ms at 1 kHz: stamps reorder (put back in stamp order by the re-order window, but
    their times stay wrong): every output after the first rate block is at best DEGRADED,
    counted as jitter, with a WARN naming the jitter; the rate itself is still judged right
    (not INVALID)."""
    out, policy, _ = _jittered(3.5e-4)
    counters = policy.counters
    assert counters['reordered'] > 0 and counters['jitter'] > 0
    assert counters.get('out_of_order', 0) == counters.get('late', 0) == 0
    assert counters.get('rate_invalid', 0) == 0
    finding = {f.key: f for f in policy.findings}['jitter']
    assert finding.level == WARN and 'IMU stamp jitter 0.3' in finding.message
    assert not np.any(out.quality[600:] == Quality.VALID)
    assert np.sum(out.quality == Quality.DEGRADED) > 5000


@pytest.mark.parametrize(('chunk', 'spike'), [(2, 1e30), (500, 1e4)])
def test_one_saturated_sample_costs_its_own_output_only(chunk, spike):
    """A corrupt sample far beyond the range is rejected as saturated and does not enter the
    gravity mean (it made the vertical axis miss gravity, every output INVALID, for up to a
    minute): every other output keeps its quality."""
    run = run_scenario('german-low', 20.0, 10.0, None, 'adxl355', seed=5)
    cov = _covariance(run)

    def feed(accel: np.ndarray) -> tuple[Output, InputStage]:
        policy = InputStage(InversionConfig(speed_mps=20.0), options=InputOptions(
            use_odom=False))
        outs = [policy.imu(run.stamps_ns[i:i + chunk], accel[i:i + chunk], None,
                           cov[i:i + chunk]) for i in range(0, run.stamps_ns.size, chunk)]
        return Output.concat([*outs, policy.flush()]), policy

    accel = run.accel.copy()
    accel[5_000, 2] = spike
    clean, _ = feed(run.accel)
    out, policy = feed(accel)
    assert policy.counters['saturated'] == 1
    assert policy.counters.get('gravity_invalid', 0) == 0
    kept = clean.stamps_ns != run.stamps_ns[5_000]
    assert np.array_equal(out.stamps_ns, clean.stamps_ns[kept])
    assert np.array_equal(out.quality, clean.quality[kept])


def test_a_time_reset_keeps_the_speed_known_whatever_the_jump():
    """Stamps of IMU and odometry jump back by 5 s at once (a bag played again, a clock set):
    the new stream's samples wait for its odometry as any do (they were released at once,
    the newest stamp of the old stream making them look a timeout old: 4960 samples without a
    speed, INVALID, the chainage held over 100 m)."""
    run = run_scenario('german-low', 20.0, 12.0, None, 'adxl355', seed=6)
    cut, back = 6_000, 5 * 10**9
    imu_t = run.stamps_ns.copy()
    imu_t[cut:] -= back
    odom_i = np.arange(0, imu_t.size, ODOM_EVERY)
    odom_t = imu_t[odom_i]
    policy = InputStage(InversionConfig(), options=InputOptions())
    cov = _covariance(run)
    outs = []
    for i in range(0, imu_t.size, 2):  # arrival order; odometry arrives with its IMU sample
        if i % ODOM_EVERY == 0:
            outs.append(policy.odometry(odom_t[i // ODOM_EVERY:i // ODOM_EVERY + 1],
                                        run.speed_mps[i:i + 1]))
        outs.append(policy.imu(imu_t[i:i + 2], run.accel[i:i + 2], None, cov[i:i + 2]))
    out = Output.concat([*outs, policy.flush()])
    assert policy.counters['time_reset'] == 1
    # around the jump only: the old stream's samples in the re-order window and after its last
    # odometry (the new stream's odometry replaced it), the new one's before its first
    assert policy.counters.get('speed_unknown', 0) <= 50 + 2 * ODOM_EVERY + 40
    assert out.chainage_m[-1] == pytest.approx(20.0 * 12.0, abs=1.0)


@pytest.mark.parametrize('chunk', [2, 4096])
def test_an_odometry_outage_is_flagged_and_its_distance_recovered(chunk):
    """No odometry for 3 s while the train brakes: the samples without a speed are INVALID and
    hold the chainage (as before), and the first one with a speed again moves it on by the
    distance at a speed linear across the outage (the held chainage lost it for good: 40 m
    of every later position)."""
    run = run_scenario('german-low', np.array([25.0, 22, 15, 10]), 16.0, None, 'adxl355',
                       seed=7)
    odom_i = np.arange(0, run.stamps_ns.size, ODOM_EVERY)
    outage = (run.stamps_ns[odom_i] > run.stamps_ns[6_000]) & (
        run.stamps_ns[odom_i] < run.stamps_ns[9_000])
    odom_i = odom_i[~outage]
    policy = InputStage(InversionConfig(), options=InputOptions())
    cov = _covariance(run)
    outs, k = [], 0
    for lo in range(0, run.stamps_ns.size, chunk):  # odometry up to the chunk's end first
        hi = min(lo + chunk, run.stamps_ns.size)
        upto = np.searchsorted(odom_i, hi)
        outs.append(policy.odometry(run.stamps_ns[odom_i[k:upto]], run.speed_mps[odom_i[k:upto]]))
        k = upto
        outs.append(policy.imu(run.stamps_ns[lo:hi], run.accel[lo:hi], None, cov[lo:hi]))
    out = Output.concat([*outs, policy.flush()])
    assert policy.counters['speed_unknown'] > 1000  # the outage past odom_timeout_s
    truth = np.concatenate([[0.0], np.cumsum(0.5 * (run.speed_mps[1:] + run.speed_mps[:-1])
                                             * np.diff(run.stamps_ns) * 1e-9)])
    at = np.searchsorted(run.stamps_ns, out.stamps_ns)
    after = out.stamps_ns > run.stamps_ns[10_000]
    covered = truth[9_000] - truth[6_000]  # about 55 m: the held chainage lost most of them
    assert np.abs(out.chainage_m[after] - truth[at[after]]).max() < 0.05 * covered


def test_zero_stamps_are_malformed_as_in_the_nodes_intake():
    """A zero header stamp among real ones (what bag readers pass on, and a node's intake
    drops as malformed) is counted and left out: it was a time reset and a 54-year gap, the
    chainage jumping by 1.7e10 m."""
    run = run_scenario('german-low', 20.0, 20.0, None, 'adxl355', seed=8)
    stamps = run.stamps_ns.copy()
    stamps[[5000, 12_000]] = 0
    odom_t = run.stamps_ns[::ODOM_EVERY].copy()
    odom_t[300] = 0
    policy = InputStage(InversionConfig(), options=InputOptions())
    out = Output.concat([policy.odometry(odom_t, run.speed_mps[::ODOM_EVERY]),
                         *(policy.imu(stamps[i:i + 500], run.accel[i:i + 500])
                           for i in range(0, stamps.size, 500)), policy.flush()])
    counts = policy.counters
    assert counts['malformed'] == 2 and counts['odom_malformed'] == 1
    assert counts.get('time_reset', 0) == 0 and len(out) == stamps.size - 2
    assert out.chainage_m[-1] == pytest.approx(20.0 * 20.0, abs=0.1)


def test_an_option_change_the_filters_do_not_see_keeps_them_running():
    """stuck_s, reorder_window_s or speed_mps (speed from odometry) changed mid-run: the
    options apply to the running filters, whose outputs are those of a run without the change
    (a rebuild flushed them: 5,024 more INVALID outputs, 100 m of track, per change)."""
    run = run_scenario('german-low', 20.0, 20.0, None, 'adxl355', seed=9)
    cov = _covariance(run)

    def feed(change: bool) -> tuple[Output, InputStage]:
        policy = InputStage(InversionConfig(), options=InputOptions())
        outs = []
        for i in range(0, run.stamps_ns.size, 500):
            if i % ODOM_EVERY == 0:
                sl = slice(i, i + 500, ODOM_EVERY)
                outs.append(policy.odometry(run.stamps_ns[sl], run.speed_mps[sl]))
            if change and i == 10_000:
                outs.append(policy.rebuild(InversionConfig(speed_mps=33.0), options=InputOptions(
                    stuck_s=0.6, reorder_window_s=0.08)))
            outs.append(policy.imu(run.stamps_ns[i:i + 500], run.accel[i:i + 500], None,
                                   cov[i:i + 500]))
        return Output.concat([*outs, policy.flush()]), policy

    (plain, _), (changed, policy) = feed(False), feed(True)
    assert policy.counters['reconfigure'] == 1 and policy.counters.get('rebuild', 0) == 0
    assert policy.options.stuck_s == 0.6 and policy.config.speed_mps == 33.0
    assert_identical(changed, plain)


def test_an_odometry_sign_glitch_is_implausible_not_reverse_running():
    """One second of -20 m/s from an odometry reading +20 m/s (a sign glitch: 2000 m/s^2 at
    50 Hz) is counted and ignored like NaN odometry: the speed holds, no reverse running (it
    was VALID reverse running and put every later position 40 m short)."""
    run = run_scenario('german-low', 20.0, 12.0, None, 'adxl355', seed=10)
    odom_t, odom_v = run.stamps_ns[::ODOM_EVERY], np.array(run.speed_mps[::ODOM_EVERY])
    glitch = (odom_t >= run.stamps_ns[6_000]) & (odom_t < run.stamps_ns[6_900])
    odom_v[glitch] *= -1.0
    policy = InputStage(InversionConfig(), options=InputOptions())
    out = Output.concat([policy.odometry(odom_t, odom_v),
                         *(policy.imu(run.stamps_ns[i:i + 500], run.accel[i:i + 500])
                           for i in range(0, run.stamps_ns.size, 500)), policy.flush()])
    assert policy.counters['odom_implausible'] == glitch.sum()
    assert policy.counters.get('reverse', 0) == 0 and policy.counters.get('speed_unknown', 0) == 0
    assert out.chainage_m[-1] == pytest.approx(20.0 * 12.0, abs=0.1)
    assert {f.level for f in policy.findings if f.key == 'odometry'} == {WARN}
