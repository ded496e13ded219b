"""inverse.rate: the IMU rate and lost samples from jittered stamps, against synthetic stamps
whose true rate, jitter and losses are known."""

from __future__ import annotations

import numpy as np
import pytest

from railgsa_ros.inverse.rate import JITTER_TOLERANCE, count_steps

PERIOD_NS = 1e6  # 1 kHz nominal


def _steps(jitter: float, rate_error: float, every: int, seed: int) -> np.ndarray:
    """512 steps (ns) of stamps at (1 + rate_error) periods with a normal error of ``jitter``
    periods each; every ``every``-th sample missing (0: none)."""
    k = np.arange(600)
    if every:
        k = k[k % every != 5]
    t = (k * (1 + rate_error) + np.random.default_rng(seed).normal(0, jitter, k.size)) * PERIOD_NS
    steps = np.rint(np.diff(t))[:512]
    return steps[steps != 0]


@pytest.mark.parametrize('jitter', [0.0, 0.1, 0.15, 0.19])
@pytest.mark.parametrize('rate_error', [0.0, 0.015])
def test_rate_and_lost_samples_are_counted_under_jitter(jitter, rate_error):
    for seed in range(5):
        clean = count_steps(_steps(jitter, rate_error, 0, seed), PERIOD_NS, 3.0)
        true_hz = 1e3 / (1 + rate_error)
        assert abs(clean.rate_hz / true_hz - 1) < 0.01  # the median step: up to 2.3 % off
        assert not clean.lost_significant and not clean.heavy
        assert clean.jitter_s == pytest.approx(jitter * 1e-3, abs=0.025e-3)
        lossy = count_steps(_steps(jitter, rate_error, 10, seed), PERIOD_NS, 3.0)
        assert abs(lossy.rate_hz / true_hz - 1) < 0.01
        assert lossy.lost_significant and abs(lossy.lost - 57) <= 1  # 512 steps over 9 kept


def test_jitter_beyond_the_tolerance_is_heavy_and_the_rate_telescopes():
    for seed in range(5):
        counted = count_steps(_steps(0.3, 0.0, 0, seed), PERIOD_NS, 3.0)
        assert counted.heavy and counted.jitter_s > JITTER_TOLERANCE * 1e-3
        assert abs(counted.rate_hz / 1e3 - 1) < 0.005 and counted.lost == 0
    # another rate is still another rate: 1 kHz stamps against 800 Hz
    other = count_steps(_steps(0.1, 0.0, 0, 0), 1.25e6, 3.0)
    assert abs(other.rate_hz / 1e3 - 1) < 0.01
