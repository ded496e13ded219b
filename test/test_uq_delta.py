"""Borgonovo delta: linear Gaussian closed form, Ishigami reference, conditional PEM5 design."""

from itertools import product

import numpy as np
import pytest
from scipy import special

from railgsa_ros.uq import Normal, analyze
from railgsa_ros.uq.conditional import conditional_design, distinct_count, paper_count
from railgsa_ros.uq.delta import (
    FOLD,
    _extent,
    _smooth,
    delta_design,
    delta_from_outputs,
    delta_indices,
)

ISHIGAMI_DELTA = np.array([0.263, 0.425, 0.210])  # gsa_notes section 2, semi-analytic


def l1_between_normals(m1, s1, m2, s2):
    """integral |N(m1, s1^2) - N(m2, s2^2)| (s1 != s2): the densities cross at the two roots r
    of a quadratic; between crossings F1 - F2 is monotone, so the integral is its variation."""
    a = 0.5 / s2 ** 2 - 0.5 / s1 ** 2
    b = m1 / s1 ** 2 - m2 / s2 ** 2
    c = m2 ** 2 / (2 * s2 ** 2) - m1 ** 2 / (2 * s1 ** 2) + np.log(s2 / s1)
    disc = np.sqrt(b * b - 4 * a * c)
    r = np.sort([(-b - disc) / (2 * a), (-b + disc) / (2 * a)], axis=0)
    d = special.ndtr((r - m1) / s1) - special.ndtr((r - m2) / s2)
    return np.abs(d[0]) + np.abs(d[1] - d[0]) + np.abs(d[1])


def linear_delta(a, sigma):
    """delta_i of Y = sum a_i X_i, X_i ~ N(mu_i, sigma_i): Y | X_i = mu_i + sigma_i z is normal
    with mean shifted by a_i sigma_i z and variance s^2 - (a_i sigma_i)^2; E over z by
    200-point Gauss-Hermite quadrature."""
    z, w = np.polynomial.hermite_e.hermegauss(200)
    w = w / w.sum()
    s = np.sqrt(np.sum((a * sigma) ** 2))
    return np.array([0.5 * w @ l1_between_normals(0.0, s, ai * z, np.sqrt(s ** 2 - ai ** 2))
                     for ai in a * sigma])


def test_l1_between_normals_against_quadrature():
    y = np.linspace(-30, 30, 600_001)
    f = np.exp(-0.5 * (y / 2) ** 2) / (2 * np.sqrt(2 * np.pi))
    g = np.exp(-0.5 * ((y - 1) / 1.5) ** 2) / (1.5 * np.sqrt(2 * np.pi))
    assert l1_between_normals(0.0, 2.0, 1.0, 1.5) == pytest.approx(
        np.abs(f - g).sum() * (y[1] - y[0]), abs=1e-8)


def test_linear_gaussian_delta_closed_form():
    a, mu, sigma = np.array([1.0, -2.0, 0.5]), np.array([3.0, 1.0, 0.0]), np.array([1.0, 1.0, 2.0])
    truth = linear_delta(a, sigma)
    res = analyze(lambda x: x @ a, [Normal(m, s) for m, s in zip(mu, sigma, strict=True)], order=1,
                  rule='pem3', n_mc=1024)
    np.testing.assert_allclose(res.delta, truth, atol=5e-3)
    assert res.n_evaluations == 6  # PEM3 at n = 3: the centre has weight 0


def test_ishigami_delta_reference():
    def ishigami(xi):
        x = np.pi * (2 * special.ndtr(xi) - 1)
        return np.sin(x[:, 0]) + 7 * np.sin(x[:, 1]) ** 2 + 0.1 * x[:, 2] ** 4 * np.sin(x[:, 0])

    np.testing.assert_allclose(delta_indices(ishigami, 3, n_mc=400_000)[0], ISHIGAMI_DELTA,
                               atol=0.01)


def test_no_influence_gives_zero_and_full_influence_one():
    d = delta_indices(lambda xi: np.stack([xi[:, 0], xi[:, 0] ** 2], -1), 2, n_mc=100_000)
    np.testing.assert_allclose(d[:, 1], 0.0, atol=3e-3)
    assert np.all(d[:, 0] > 0.9)  # a Dirac conditional: the kernel sign blurs the spike


@pytest.mark.parametrize('n', range(2, 7))
def test_conditional_design_counts(n):
    design = conditional_design(n)
    grid = np.array(list(product([-1, 0, 1], repeat=n)))
    at_most_three = grid[np.count_nonzero(grid, axis=1) <= 3]
    assert len(design.points) == len(at_most_three) == distinct_count(n)
    assert (paper_count(n) == distinct_count(n)) == (n <= 3)
    assert paper_count(3) == 27


def test_conditional_pem5_delta_on_linear_gaussian():
    a = np.array([1.0, 2.0, 0.5])
    res = analyze(lambda x: x @ a, [Normal(0.0, 1.0)] * 3, order=2, delta='pem5', n_mc=65_536)
    assert res.n_evaluations == 27
    # three fixed values per input are a coarse quadrature of E[s]: a few hundredths
    np.testing.assert_allclose(res.delta, linear_delta(a, np.ones(3)), atol=0.04)


def test_smoothing_pads_each_row_by_what_its_bandwidth_needs():
    """_smooth pads each row by at least TAIL_BANDWIDTHS bandwidths (1 to 300 bins: every
    padding step): against the same Gaussian transfer function on a grid padded by 15 bins,
    where nothing wraps around. Kernels of 2 bins and wider agree to rounding; below, the
    transfer function cut at the grid's Nyquist frequency (at 1 bin: exp(-pi^2 / 2) = 0.7 %
    there) leaves a slowly decaying tail that wraps (measured: 2.5e-6 of the peak at 1 bin,
    2e-7 with the former padding of 1024 bins, which left 1e-3 at 300 bins). Row by row the
    same floats as in a batch (the deferred window records rely on it)."""
    rng = np.random.default_rng(3)
    bins, size = 1024, 16 * 1024
    diff = rng.standard_normal((2, 40, bins)) * (rng.random((2, 40, bins)) < 0.2)
    h = np.geomspace(1.0, 300.0, 80).reshape(2, 40)
    got = _smooth(diff, h)
    spec = np.fft.rfft(diff, n=size) * np.exp(-2 * (np.pi * np.fft.rfftfreq(size)
                                                    * h[..., None]) ** 2)
    ref = np.fft.irfft(spec, n=size)[..., :bins]
    err = np.abs(got - ref).max(axis=-1) / np.abs(ref).max(axis=-1)
    assert np.all(err[h >= 2] < 1e-12) and np.all(err < 1e-5)
    for k in (0, 7, 39):
        np.testing.assert_array_equal(_smooth(diff[1, k:k + 1], h[1, k:k + 1]), got[1, k:k + 1])


def test_delta_design_is_what_delta_indices_evaluates():
    """delta_from_outputs on the outputs at delta_design's points is delta_indices, bit for bit
    (the uncertainty windows evaluate their surrogates there through a cached basis)."""
    def func(xi):
        return np.stack([xi[:, 0] + 0.3 * xi[:, 1] ** 2, np.sin(xi[:, 2]) * xi[:, 0]], -1)

    design = delta_design(3, 4096, seed=5)
    y_cond = func(design.cond.reshape(-1, 3)).reshape(*design.cond.shape[:3], -1)
    np.testing.assert_array_equal(delta_from_outputs(func(design.ref), y_cond),
                                  delta_indices(func, 3, 4096, seed=5))


@pytest.mark.parametrize('rows', [1, FOLD - 1, FOLD, FOLD + 1, 3 * FOLD + 5])
def test_extent_is_the_columns_min_and_max(rows):
    """The folded reduction against min/max over the leading axes: rows below, at and beyond
    multiples of FOLD, a NaN propagated as np.min and np.max do."""
    y = np.random.default_rng(rows).standard_normal((rows, 2, 3))
    y[-1, 0, 1] = np.nan
    lo, hi = _extent(y)
    np.testing.assert_array_equal(lo, y.min(axis=(0, 1)))
    np.testing.assert_array_equal(hi, y.max(axis=(0, 1)))
