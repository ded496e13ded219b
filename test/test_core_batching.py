"""The core's small-batch paths (a live push of 1-8 samples: Python floats instead of numpy
calls) give bit for bit what its vectorised paths give for the same batches: random streams
with gaps (bridged and restarting), NaN rows, absent accelerations, rotated gravity, a wrong
rate, rate jitter, repeated and reordered stamps, wrong frames, speed changes, stops and
reverse running, fed in random batches of 1..500 samples with odometry interleaved as it
arrives."""

from __future__ import annotations

import numpy as np
import pytest

from railgsa_ros.input import held, monitors, noise, odometry, sanitize, stage
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse import pipeline
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output

G = 9.80665
RATE_HZ = 1000.0
ODOM_EVERY = 20  # 50 Hz odometry
#: the modules whose scalar paths take batches up to their SMALL samples
SMALL_PATHS = (stage, held, monitors, noise, odometry, pipeline, sanitize)
FAST = dict(min_design_speed_mps=40.0, fir_tolerance=1e-4, speed_mps=50.0)  # a short FIR


def stream(seed: int, n: int = 8000) -> dict[str, np.ndarray]:
    """IMU stamps (ns), accel (n, 3), covariance (n, 9), frame ids and 50 Hz odometry with
    every kind of input the policy decides on."""
    rng = np.random.default_rng(seed)
    steps = np.full(n, 1_000_000, np.int64) + rng.integers(-20_000, 20_000, n)  # jitter
    steps[1500:2200] = 1_250_000  # 800 Hz for a while: more than one rate block
    steps[rng.integers(100, n, 2)] = 4_000_000  # gaps the filler bridges
    steps[n - 800] = 1_500_000_000  # beyond max_bridge_s: the filters restart
    stamps = 1_764_000_000 * 10**9 + np.cumsum(steps)  # epoch stamps: beyond float precision
    stamps[rng.integers(100, n, 3)] -= 3_000_000  # out of order
    dup = rng.integers(100, n, 3)
    stamps[dup] = stamps[dup - 1]  # repeated
    accel = 0.05 * rng.standard_normal((n, 3))
    accel[:, 2] += G
    accel[3000:3400] = accel[3000:3400][:, [0, 2, 1]] * [1, -1, 1]  # gravity on -y
    accel[rng.integers(0, n, 30), rng.integers(0, 3, 30)] = np.nan
    cov = np.zeros((n, 9))
    cov[:, [0, 4, 8]] = 2.5e-5 * rng.uniform(0.5, 2.0, (n, 1))
    cov[rng.integers(0, n, 20), 0] = -1.0  # acceleration absent
    frames = np.full(n, 'imu_link', dtype=object)
    frames[rng.integers(0, n, 10)] = 'base_link'
    odom_t = stamps[::ODOM_EVERY].copy()
    speed = np.interp(np.arange(odom_t.size), [0, 150, 200, 230, 260, 300, 400],
                      [50.0, 60.0, 0.0, 0.0, -3.0, 45.0, 60.0])
    speed[rng.integers(0, speed.size, 3)] = np.nan
    return {'stamps': stamps, 'accel': accel, 'cov': cov, 'frames': frames,
            'odom_t': np.maximum.accumulate(odom_t), 'odom_v': speed}


def batches(rng: np.random.Generator, n: int) -> list[tuple[int, int]]:
    """Random batch bounds: mostly 1-12 samples (the small paths), some up to 500."""
    sizes = np.where(rng.uniform(size=n) < 0.95, rng.integers(1, 13, n),
                     rng.integers(13, 501, n))
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    bounds = np.concatenate([bounds[bounds < n], [n]])
    return list(zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True))


def feed(policy: InputStage, s: dict, pieces: list[tuple[int, int]] | None) -> Output:
    """Offline (pieces None): all odometry, then the IMU at once. Live: the IMU in ``pieces``,
    each odometry message once an IMU sample at or after its stamp has come."""
    imu = (s['stamps'], s['accel'], s['frames'], s['cov'])
    if pieces is None:
        outs = [policy.odometry(s['odom_t'], s['odom_v']), policy.imu(*imu)]
    else:
        outs, sent = [], 0
        for lo, hi in pieces:
            due = int(np.searchsorted(s['odom_t'], s['stamps'][lo], side='right'))
            if due > sent:
                outs.append(policy.odometry(s['odom_t'][sent:due], s['odom_v'][sent:due]))
                sent = due
            outs.append(policy.imu(*(x[lo:hi] for x in imu)))
        outs.append(policy.odometry(s['odom_t'][sent:], s['odom_v'][sent:]))
    outs.append(policy.flush())
    return Output.concat(outs)


def same(a: Output, b: Output) -> None:
    for name in ('stamps_ns', 'chainage_m', 'u_m', 'quality', 'speed_mps', 'gap_std_m'):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name


CASES = [(1, InputOptions(), 'spectral'),
         (2, InputOptions(use_odom=False, wrong_frame_policy='reject', stuck_s=0.0),
          'feedback')]


@pytest.mark.parametrize('seed, options, method', CASES)
def test_small_batch_paths_give_the_vectorised_result_bit_for_bit(seed, options, method,
                                                                   monkeypatch):
    s = stream(seed)
    cfg = InversionConfig(rate_hz=RATE_HZ, method=method, **FAST)
    pieces = batches(np.random.default_rng(seed), s['stamps'].size)
    fast = InputStage(cfg, options=options)
    got = feed(fast, s, pieces)
    for module in SMALL_PATHS:
        monkeypatch.setattr(module, 'SMALL', 0)  # every batch through the numpy paths
    slow = InputStage(cfg, options=options)
    same(got, feed(slow, s, pieces))
    assert fast.counters == slow.counters and fast.findings == slow.findings
    # the stream reached every decision the small paths make
    for key in ('gravity_invalid', 'rate_invalid', 'nan', 'gap', 'bridged', 'reset'):
        assert slow.counters.get(key, 0) > 0, key
    assert {f.key for f in slow.findings} >= {'gravity', 'rate', 'speed', 'frame'}
    assert np.isfinite(got.u_m).sum() > 1000  # not all INVALID: the band ran


def test_mounting_projection_small_paths_bit_for_bit(monkeypatch):
    """A sensor tilted 10 deg, mounting estimate: the ramps, the unsettled and the settled (slew
    limited) projection, saturated rows kept out of the estimate, in small and vectorised
    batches."""
    from railgsa_ros.input import mounting
    from railgsa_ros.mount_sim import mounted

    monkeypatch.setattr(mounting, 'SETTLE_S', 3.0)
    s = stream(3)
    s['accel'] = mounted(s['accel'], 10.0, -4.0)
    s['accel'][[500, 4100, 6000], 1] = [30.0, 1e300, -25.0]  # beyond the range: not estimated
    cfg = InversionConfig(rate_hz=RATE_HZ, **FAST)
    pieces = batches(np.random.default_rng(3), s['stamps'].size)
    fast = InputStage(cfg)
    got = feed(fast, s, pieces)
    for module in SMALL_PATHS:
        monkeypatch.setattr(module, 'SMALL', 0)
    slow = InputStage(cfg)
    same(got, feed(slow, s, pieces))
    assert fast.counters == slow.counters and fast.findings == slow.findings
    assert slow.mounting.settled and slow.mounting.in_use != mounting.axis_vector('z')
    assert slow.counters['mounting_degraded'] > 0
