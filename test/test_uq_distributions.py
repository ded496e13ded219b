"""Distributions: exact transforms against closed forms, Monte Carlo and round trips."""

import math

import numpy as np
import pytest
from scipy import special, stats

from railgsa_ros.errors import ConfigError
from railgsa_ros.uq.distributions import (
    Empirical,
    Exponential,
    Gamma,
    LogNormal,
    Normal,
    Uniform,
    isoprobabilistic,
)

XI = np.linspace(-5.0, 5.0, 41)
CASES = [
    (Normal(2.0, 0.5), stats.norm(2.0, 0.5)),
    (Normal(2.13e6, 7.1e5, lower=0.0), stats.truncnorm(-3.0, np.inf, 2.13e6, 7.1e5)),
    (Uniform(-math.pi, math.pi), stats.uniform(-math.pi, 2 * math.pi)),
    (LogNormal(0.3, 0.4), stats.lognorm(0.4, scale=math.exp(0.3))),
    (Gamma(2.5, 3.0), stats.gamma(2.5, scale=3.0)),
    (Exponential(2.0), stats.expon(scale=0.5)),
]


def test_closed_forms():
    # Table 2 corrected: Uniform with erf(xi / sqrt 2), Exponential via the upper tail.
    u = Uniform(1.0, 4.0).from_xi(XI)
    np.testing.assert_allclose(u, 1.0 + 3.0 * (0.5 + 0.5 * special.erf(XI / math.sqrt(2))),
                               rtol=1e-14)
    tail = np.where(XI <= 0, -np.log1p(-special.ndtr(XI)), -np.log(special.ndtr(-XI)))
    np.testing.assert_allclose(Exponential(2.0).from_xi(XI), tail / 2.0, rtol=1e-12)
    np.testing.assert_allclose(LogNormal(0.3, 0.4).from_xi(XI), np.exp(0.3 + 0.4 * XI),
                               rtol=1e-13)
    np.testing.assert_allclose(Normal(2.0, 0.5).from_xi(XI), 2.0 + 0.5 * XI, rtol=0, atol=1e-14)


def test_gamma_row_of_table_2_is_wilson_hilferty_only():
    shape, scale = 9.0, 2.0
    approx = shape * scale * (XI * math.sqrt(1 / (9 * shape)) + 1 - 1 / (9 * shape)) ** 3
    exact = Gamma(shape, scale).from_xi(XI)
    inner = np.abs(XI) <= 3
    assert np.max(np.abs(approx - exact)[inner] / exact[inner]) < 2e-2  # close ...
    assert np.max(np.abs(approx - exact) / exact) > 1e-3  # ... but not exact


@pytest.mark.parametrize(('dist', 'ref'), CASES)
def test_transform_matches_cdf_and_monte_carlo(dist, ref):
    x = dist.from_xi(XI)
    np.testing.assert_allclose(ref.cdf(x), special.ndtr(XI), rtol=1e-9, atol=1e-12)
    draws = dist.sample(20_000, np.random.default_rng(1))
    assert stats.kstest(draws, ref.cdf).pvalue > 1e-3
    assert abs(dist.mean() - ref.mean()) <= 1e-9 * abs(ref.mean())


@pytest.mark.parametrize(('dist', 'ref'), CASES)
def test_round_trip_into_the_tails(dist, ref):
    # float spacing of x next to a finite bound limits that side (x - bound loses digits)
    low = -5.0 if isinstance(dist, Uniform) else -6.0 if dist._frozen.support()[0] == 0 else -8.0
    high = 5.0 if isinstance(dist, Uniform) else 8.0
    xi = np.linspace(low, high, 101)
    np.testing.assert_allclose(dist.to_xi(dist.from_xi(xi)), xi, atol=1e-6)


def test_truncated_normal_stays_physical():
    dist = Normal(2.13e6, 7.1e5, lower=0.0)
    x = dist.from_xi(np.linspace(-40, 40, 2001))
    assert np.all(x >= 0.0) and np.all(np.diff(x) >= 0)
    # conditioned on x >= 0: the mean moves by sigma phi(3) / (1 - Phi(-3))
    shift = 7.1e5 * stats.norm.pdf(3.0) / stats.norm.sf(-3.0)
    assert dist.mean() == pytest.approx(2.13e6 + shift, rel=1e-12)


def test_empirical_follows_its_data():
    data = np.random.default_rng(2).gamma(3.0, size=5000)
    dist = Empirical(data)
    x = dist.from_xi(np.random.default_rng(3).standard_normal(20_000))
    assert stats.ks_2samp(x, data).pvalue > 1e-3
    assert x.min() >= data.min() and x.max() <= data.max()
    inner = np.linspace(-2, 2, 9)
    np.testing.assert_allclose(dist.to_xi(dist.from_xi(inner)), inner, atol=1e-9)


def test_isoprobabilistic_maps_columns():
    dists = [Normal(1.0, 2.0), Exponential(1.0)]
    xi = np.array([[0.0, 0.0], [1.0, -1.0]])
    x = isoprobabilistic(dists, xi)
    np.testing.assert_allclose(x[:, 0], [1.0, 3.0])
    np.testing.assert_allclose(x[:, 1], -np.log(special.ndtr(-xi[:, 1])))


@pytest.mark.parametrize(('factory', 'field'), [
    (lambda: Normal(1.0, -1.0), 'sigma'), (lambda: Normal('x', 1.0), 'mu'),
    (lambda: Uniform(2.0, 1.0), 'a/b'), (lambda: Gamma(0.0, 1.0), 'shape'),
    (lambda: Exponential(float('nan')), 'rate'), (lambda: Empirical([1.0]), 'samples'),
    (lambda: Normal(0.0, 1.0, lower=50.0), 'lower'),
])
def test_bad_parameters_name_the_field(factory, field):
    with pytest.raises(ConfigError, match=field):
        factory()
