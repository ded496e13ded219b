"""Positions against the simulator's truth: the chainage of every output whatever the order of
the first IMU and odometry messages."""

from __future__ import annotations

import numpy as np
import pytest

from railgsa_ros.bag.run import sample_indices
from railgsa_ros.imu import imu_spec
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.scenario import run_scenario

#: exact stamps (no drift, no jitter, no dropouts): the chainage error is the input stage's
EXACT = imu_spec('adxl355', dropout_fraction=0.0, clock_drift_ppm=0.0, stamp_jitter_s=0.0)
SPEED = 30.0  # m/s: 3 cm per 1 kHz sample


@pytest.fixture(scope='module')
def steady():
    return run_scenario('german-low', SPEED, 6.0, None, EXACT, seed=11)


def replay(run, imu: np.ndarray, odom: np.ndarray, block: int = 100) -> Output:
    """IMU samples ``imu`` and odometry samples ``odom`` (run indices) into an InputStage in
    stamp order, each odometry message after the IMU samples stamped at or before it (the
    IMU's first sample first when both start together)."""
    stage = InputStage(InversionConfig(rate_hz=run.rate_hz))
    t, a = run.stamps_ns, run.accel
    outs, lo = [], 0
    for k in odom.tolist():
        hi = int(np.searchsorted(imu, k, side='right'))
        for s in range(lo, hi, block):
            part = imu[s:min(s + block, hi)]
            outs.append(stage.imu(t[part], a[part]))
        lo = hi
        outs.append(stage.odometry(t[k:k + 1], run.odom_scale * run.speed_mps[k:k + 1]))
    for s in range(lo, imu.size, block):
        outs.append(stage.imu(t[imu[s:s + block]], a[imu[s:s + block]]))
    outs.append(stage.flush())
    return Output.concat(outs)


def start_offset(run, out: Output, first: int) -> np.ndarray:
    """Output chainage less the true distance from the first IMU sample (m), every output."""
    idx = np.searchsorted(run.stamps_ns, out.stamps_ns)
    return out.chainage_m - (run.chainage_m[idx] - run.chainage_m[first])


@pytest.mark.parametrize('imu_from, odom_from', [
    (5, 0),    # odometry starts 5 ms before the IMU
    (0, 0),    # together
    (0, 1),    # odometry 1 ms after the IMU: the 3 cm of issue 22
    (0, 20),   # odometry's first tick lost: 20 ms after the IMU
])
def test_first_sample_chainage_whatever_the_order(steady, imu_from, odom_from):
    n = steady.stamps_ns.size
    ticks = sample_indices(steady.stamps_ns, 50.0)
    odom = np.unique(np.concatenate([[odom_from], ticks[ticks > odom_from]]))
    out = replay(steady, np.arange(imu_from, n), odom)
    assert out.stamps_ns[0] == steady.stamps_ns[imu_from]  # every sample has its output
    assert len(out) == n - imu_from
    offset = start_offset(steady, out, imu_from)
    assert np.all(out.speed_mps == SPEED)  # the first samples too: within odom_timeout_s
    assert np.count_nonzero(out.quality != int(Quality.INVALID)) > 0.3 * len(out)
    assert np.max(np.abs(offset)) < 1e-3  # m: under 1 mm, the whole run


def test_late_odometry_start_is_decided_alike_live_and_offline(steady):
    """Odometry starting 20 ms after the IMU: fed as it arrives (IMU blocks of 7 before each
    odometry message) and as offline reads it (all odometry, then the IMU in one chunk), the
    same speed, chainage and quality at every output."""
    ticks = sample_indices(steady.stamps_ns, 50.0)
    odom = ticks[ticks >= 20]
    imu = np.arange(steady.stamps_ns.size)
    live = replay(steady, imu, odom, block=7)
    stage = InputStage(InversionConfig(rate_hz=steady.rate_hz))
    offline = Output.concat([
        stage.odometry(steady.stamps_ns[odom], steady.speed_mps[odom]),
        stage.imu(steady.stamps_ns, steady.accel), stage.flush()])
    for name in ('stamps_ns', 'chainage_m', 'speed_mps', 'quality'):
        np.testing.assert_array_equal(getattr(live, name), getattr(offline, name))
    np.testing.assert_array_equal(live.u_m, offline.u_m)
