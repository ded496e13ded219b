"""Feedback inversion (Eq. 5-7): stability against exact arithmetic, paper mode, refusals."""

from fractions import Fraction
import itertools

import numpy as np
import pytest

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.feedback import FeedbackInverse, require_stable, stability
from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.simulate import simulate
from railgsa_ros.track import paper_profile
from railgsa_ros.vehicle import VehicleParams, tf_polynomials

NOMINAL = VehicleParams().as_array()


def exact_hurwitz(theta: np.ndarray, gain: float) -> tuple[Fraction, Fraction]:
    """H2, H3 of den + K num_s evaluated in exact rational arithmetic from the raw parameters."""
    m_s, m_us, k_s, k_us, c = (Fraction(float(x)) for x in theta)
    k = Fraction(gain)
    scale = m_s * m_us
    a3 = (c * (m_s + m_us) + k * k_us * c) / scale
    a2 = (k_s * (m_s + m_us) + k_us * m_s + k * k_us * k_s) / scale
    a1, a0 = c * k_us / scale, k_s * k_us / scale
    return a3 * a2 - a1, a1 * (a3 * a2 - a1) - a3 ** 2 * a0


@pytest.mark.parametrize('gain', [1.0, 1000.0, 1e6])
def test_hurwitz_determinants_match_exact_arithmetic(gain):
    rng = np.random.default_rng(1)
    bank = NOMINAL * rng.uniform(0.5, 1.5, (4, 5))
    report = stability(bank, gain)
    assert report.stable
    for theta, (_, h2, h3) in zip(bank, report.hurwitz, strict=True):
        e2, e3 = exact_hurwitz(theta, gain)
        assert h2 == pytest.approx(float(e2), rel=1e-12)
        assert h3 == pytest.approx(float(e3), rel=1e-9)


def test_slow_pair_matches_newton_refined_root():
    report = stability(NOMINAL, 1000.0)
    num, _, den = tf_polynomials(NOMINAL)
    poly = den + 1000.0 * num  # Newton on the closed-loop polynomial (Horner, complex128)
    s = 1j * 2 * np.pi * report.slow_hz[0]
    for _ in range(20):
        s -= np.polyval(poly, s) / np.polyval(np.polyder(poly), s)
    assert abs(s.imag) / (2 * np.pi) == pytest.approx(report.slow_hz[0], rel=1e-9)
    assert s.real == pytest.approx(report.slow_real[0], rel=1e-4)
    assert report.slow_hz[0] == pytest.approx(1 / (2 * np.pi * np.sqrt(1000.0)), rel=0.01)
    assert report.margin == pytest.approx(-report.slow_real[0])
    assert report.eigenvalues.shape == (1, 4)


@pytest.mark.parametrize('gain', [0.0, -5.0, float('nan'), float('inf'), 'abc'])
def test_invalid_gain_refused(gain):
    with pytest.raises(ConfigError, match='gain'):
        InversionConfig(gain=gain)
    with pytest.raises(ConfigError, match='gain'):
        require_stable(NOMINAL, gain)


def test_unstable_parameter_set_refused():
    bad = NOMINAL.copy()
    bad[4] = -bad[4]  # negative damping: open and closed loop unstable
    with pytest.raises(ConfigError, match='unstable'):
        FeedbackInverse(np.stack([NOMINAL, bad]), 1000.0, 1e-3)


@pytest.mark.parametrize('method, why', [('analytical', 'D = 0'),
                                         ('flatness', 'relative degree 1')])
def test_analytical_and_flatness_explain_why_not(method, why):
    with pytest.raises(ConfigError, match=why):
        InversionConfig(method=method)


def test_paper_mode_reconstructs_paper_profile():
    dt = 1e-3
    t = np.arange(0.0, 14.0, dt)
    u = paper_profile(10.0 * t)
    a_s, _ = simulate(u, dt, NOMINAL)
    cfg = InversionConfig(method='feedback', band='none', taper_s=0.0, frame_id='')
    pipe = InversionPipeline(cfg, NOMINAL)
    stamps = np.round(t * 1e9).astype(np.int64)
    out = pipe.push(stamps, a_s + cfg.gravity_mps2, 10.0)
    assert np.array_equal(out.stamps_ns, stamps)  # no band: no delay
    err = np.max(np.abs(out.u_m - u)) / np.max(np.abs(u))
    assert err <= 1e-3
    assert out.chainage_m[-1] == pytest.approx(10.0 * t[-1])


def test_feedback_chunk_invariance():
    rng = np.random.default_rng(2)
    y = rng.standard_normal(3000) * 0.1
    bank = NOMINAL * rng.uniform(0.8, 1.2, (3, 5))
    whole = FeedbackInverse(bank, 1000.0, 1e-3).process(y)
    inv = FeedbackInverse(bank, 1000.0, 1e-3)
    cuts = np.unique(np.r_[0, rng.integers(0, y.size, 40), np.arange(100, 110), y.size])
    parts = np.concatenate([inv.process(y[a:b]) for a, b in itertools.pairwise(cuts)],
                           axis=1)
    # Eq. 7 forms u = K (y - C x): the 1e-5 cancellation limits agreement to ~1e-11 relative
    assert np.max(np.abs(parts - whole)) <= 1e-9 * np.max(np.abs(whole))
