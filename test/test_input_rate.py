"""input.rate: the IMU rate and lost samples from jittered stamps, against synthetic stamps
whose true rate, jitter and losses are known."""

from __future__ import annotations

import numpy as np
import pytest

from railgsa_ros.input.rate import JITTER_TOLERANCE, count_blocks, count_steps

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
        assert abs(counted.rate_hz / 1e3 - 1) < 0.005 and not counted.lost_significant
    # another rate is still another rate: 1 kHz stamps against 800 Hz
    other = count_steps(_steps(0.1, 0.0, 0, 0), 1.25e6, 3.0)
    assert abs(other.rate_hz / 1e3 - 1) < 0.01


JITTERS_MS = [0.0, 0.1, 0.2, 0.22, 0.25]
LOSSES = {'none': lambda k: k >= 0, 'every 50th': lambda k: k % 50 != 25,
          'bursts of 5': lambda k: k % 500 >= 5}


def _lossy_block(jitter_ms: float, loss: str, rate_hz: float, seed: int):
    """512 stamp steps (ns, in stamp order, as the policy re-orders them) of a ``rate_hz``
    stream with stamp jitter of std ``jitter_ms`` and the ``loss`` pattern's samples removed,
    and the truth: samples missing between stamps closer than a gap of 3 nominal periods
    (a burst of 5 at 1 kHz is a 6-period gap, not a loss)."""
    k = np.arange(560)
    k = k[LOSSES[loss](k)]
    t = k * 1e9 / rate_hz + np.random.default_rng(seed).normal(0, jitter_ms * 1e6, k.size)
    order = np.argsort(t, kind='stable')
    steps, dk = np.diff(np.rint(t[order]))[:512], np.diff(k[order])[:512]
    near = np.abs(steps) <= 3 * PERIOD_NS
    return steps, int(dk[near].sum() - near.sum())


@pytest.mark.parametrize('rate_hz', [1000.0, 985.0, 800.0])
@pytest.mark.parametrize('loss', list(LOSSES))
@pytest.mark.parametrize('jitter_ms', JITTERS_MS)
def test_jitter_lost_samples_and_another_rate_are_told_apart(jitter_ms, loss, rate_hz):
    """Over the grid of jitter x loss pattern x true rate (rate_hz 1000): the rate is the
    stream's own within 0.5 % (800 Hz is 800, not 1 kHz with lost samples), the lost samples
    are counted within the rounding of the first and last stamp (two), significant exactly
    where some are lost, and the jitter is measured; beyond 25 % of the period the block is
    heavy (the jitter check's DEGRADED), never miscounted."""
    for seed in range(8):
        steps, truth = _lossy_block(jitter_ms, loss, rate_hz, seed)
        counted = count_steps(steps, PERIOD_NS, 3.0)
        assert abs(counted.rate_hz / rate_hz - 1) < 0.005
        assert abs(counted.lost - truth) <= 2
        assert counted.lost_significant == (truth > 0)
        assert counted.jitter_s == pytest.approx(jitter_ms * 1e-3, abs=0.03e-3)
        share = counted.jitter_s * rate_hz  # of the period; heavy against the median step's
        assert counted.heavy == (share > JITTER_TOLERANCE) or abs(share - JITTER_TOLERANCE) < 0.01


def test_blocks_counted_together_are_counted_as_one_by_one():
    """count_blocks (the policy's batch of full blocks) gives count_steps's results bit for bit,
    over every jitter, loss pattern and rate above (steady rows together, the others alone)."""
    blocks = np.array([_lossy_block(jitter_ms, loss, rate_hz, seed)[0]
                       for jitter_ms in JITTERS_MS for loss in LOSSES
                       for rate_hz in (1000.0, 985.0, 800.0) for seed in range(2)])
    blocks[0, 100] = 0.0  # a repeated stamp and a gap: rows the batch leaves to count_steps
    blocks[1, 200] = 10 * PERIOD_NS
    assert count_blocks(blocks, PERIOD_NS, 3.0) == [count_steps(b, PERIOD_NS, 3.0)
                                                     for b in blocks]
    assert count_blocks(np.zeros((0, 512)), PERIOD_NS, 3.0) == []
