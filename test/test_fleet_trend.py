"""Defect trends: weighted least squares and the projected limit date, against Monte Carlo."""

import numpy as np
import pytest

from railgsa_ros.fleet.defects import match
from railgsa_ros.fleet.trend import crossing, fit_trend

T = np.array([0.0, 25.0, 61.0, 90.0, 118.0, 150.0])  # days
SIGMA = np.array([1.0, 2.0, 1.0, 1.5, 1.0, 3.0]) * 1e-4  # m
A, B = 5e-3, 2e-5  # depth at t = 0 (m) and rate (m/day)
LIMIT = 8e-3  # reached at t = 150 days


def test_fit_matches_weighted_polyfit():
    rng = np.random.default_rng(0)
    d = A + B * T + SIGMA * rng.standard_normal(T.size)
    trend = fit_trend(T, d, SIGMA)
    slope, intercept = np.polyfit(T, d, 1, w=1 / SIGMA)
    assert trend.rate_m_per_day == pytest.approx(slope, rel=1e-10)
    assert trend.at(0.0)[0] == pytest.approx(intercept, rel=1e-10)
    assert fit_trend(np.array([3.0, 3.0]), np.array([1e-3, 2e-3]), np.array([1e-4, 1e-4])) is None


def test_rate_error_and_date_interval_cover_the_truth():
    """The stated SE matches the spread of the fitted rates over 4000 noisy series, and the 95 %
    date interval holds the true crossing date in about 95 % of them."""
    rng = np.random.default_rng(1)
    rates, ses, covered, ordered = [], [], 0, 0
    n = 4000
    truth_date = (LIMIT - A) / B
    for _ in range(n):
        d = A + B * T + SIGMA * rng.standard_normal(T.size)
        trend = fit_trend(T, d, SIGMA)
        rates.append(trend.rate_m_per_day)
        ses.append(trend.rate_se)
        central, early, late = crossing(trend, LIMIT, T[-1] - 60)
        covered += early <= truth_date <= late
        ordered += early <= central <= late
    rates, ses = np.array(rates), np.array(ses)
    # the Birge ratio only inflates: the SE is at least the true spread, by less than 25 %
    assert np.std(rates) <= np.mean(ses) < 1.25 * np.std(rates)
    assert np.mean(np.abs(rates - B) < 1.96 * ses) > 0.94
    assert ordered == n
    assert 0.93 < covered / n <= 1.0


def test_crossing_edge_cases():
    d = A + B * T
    trend = fit_trend(T, d, SIGMA)
    central, early, late = crossing(trend, LIMIT, T[-1])
    assert central == pytest.approx(150.0, abs=1e-6) and early <= 150.0 <= late
    shrinking = crossing(fit_trend(T, A - 1e-6 * T, SIGMA), LIMIT, T[-1])
    assert shrinking[0] == np.inf and shrinking[2] == np.inf  # the upper edge may still get there
    past = crossing(trend, 5.5e-3, T[-1])  # already beyond: now
    assert past[0] == pytest.approx(T[-1])


def test_match_groups_by_position_and_sign():
    ids = match(np.array([100.0, 250.0, 100.8, 99.5, 250.3, 100.2]),
                np.array([-1, -1, -1, -1, -1, 1]))
    assert list(ids) == [0, 1, 0, 0, 1, 2]
