"""PCE: PEM5 aliasing facts, exact Sobol' indices of quadratics, Ishigami, vector outputs."""

import math

import numpy as np
import pytest

from railgsa_ros.errors import ConfigError
from railgsa_ros.uq import AliasingWarning, Normal, Uniform, analyze
from railgsa_ros.uq.pce import PCE, basis, fit_projection, multi_indices
from railgsa_ros.uq.rules import pem5

ISHIGAMI_S1 = np.array([0.3139, 0.4424, 0.0])
ISHIGAMI_ST = np.array([0.5576, 0.4424, 0.2437])


def ishigami(x):
    return np.sin(x[:, 0]) + 7 * np.sin(x[:, 1]) ** 2 + 0.1 * x[:, 2] ** 4 * np.sin(x[:, 0])


def test_multi_indices_count_and_grading():
    alpha = multi_indices(4, 3)
    assert alpha.shape == (math.comb(7, 3), 4) and not alpha[0].any()
    assert np.all(np.diff(alpha.sum(axis=1)) >= 0)
    assert len({tuple(a) for a in alpha}) == len(alpha)


def test_basis_is_orthonormal_under_gauss_quadrature():
    from railgsa_ros.uq.rules import gauss
    xi, w = gauss(2, 6)
    psi = basis(xi, multi_indices(2, 5))
    np.testing.assert_allclose(psi.T @ (w[:, None] * psi), np.eye(psi.shape[1]), atol=1e-12)


def test_pem5_gram_matrix_identity_to_order_2_rank_16_at_order_3():
    xi, w = pem5(3)
    for p in (1, 2):
        psi = basis(xi, multi_indices(3, p))
        np.testing.assert_allclose(psi.T @ (w[:, None] * psi), np.eye(psi.shape[1]), atol=1e-13)
    psi = basis(xi, multi_indices(3, 3))
    assert np.linalg.matrix_rank(psi.T @ (w[:, None] * psi)) == 16


def test_pem5_order_3_worked_example_of_gsa_notes():
    def f(x):
        return (1 + x[:, 0] + 0.5 * x[:, 1] * x[:, 2] + 0.3 * x[:, 0] ** 3
                + 0.4 * x[:, 0] * x[:, 1] * x[:, 2] + 0.2 * (x[:, 1] ** 2 - 1) * x[:, 2])

    xi, w = pem5(3)
    alpha = multi_indices(3, 3)
    coef = fit_projection(basis(xi, alpha), w, f(xi)[:, None])[:, 0]
    # coefficients of the unnormalised He basis: c / sqrt(prod alpha_j!)
    norms = np.sqrt(np.prod(np.vectorize(math.factorial)(alpha), axis=1))
    he = dict(zip(map(tuple, alpha), coef / norms, strict=True))
    expected = {(1, 0, 0): 1.9, (0, 1, 1): 0.5, (0, 2, 1): 0.2, (3, 0, 0): 0.0,
                (1, 1, 1): 0.0, (2, 0, 1): -0.1}
    for key, value in expected.items():
        assert he[key] == pytest.approx(value, abs=1e-12)
    pce = PCE(alpha, coef[:, None])
    assert pce.variance[0] == pytest.approx(3.96)  # true 4.64: -14.7 %
    np.testing.assert_allclose(pce.sobol_total[0], [0.917, 0.083, 0.088], atol=1e-3)


@pytest.mark.parametrize('seed', range(5))
def test_sobol_of_random_quadratics_exact_with_pem5(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 7))
    mu, sigma = rng.uniform(-2, 2, n), rng.uniform(0.1, 3, n)
    c0, b, a = rng.normal(), rng.normal(size=n), np.triu(rng.normal(size=(n, n)))

    def model(x):
        z = (x - mu) / sigma
        return c0 + z @ b + np.einsum('ni,ij,nj->n', z, a, z)

    # exact Hermite expansion: z_i^2 = sqrt(2) psi_2 + 1, z_i z_j = psi_1 psi_1
    off = a - np.diag(np.diag(a))
    inter = off ** 2 + off.T ** 2
    main = b ** 2 + 2 * np.diag(a) ** 2
    var = main.sum() + np.sum(off ** 2)
    dists = [Normal(m, s) for m, s in zip(mu, sigma, strict=True)]
    res = analyze(model, dists, order=2, delta=False, n_mc=1024)
    assert res.n_evaluations == len(pem5(n)[0])
    np.testing.assert_allclose(res.sobol_first, main / var, atol=1e-10)
    np.testing.assert_allclose(res.sobol_total, (main + inter.sum(axis=1)) / var, atol=1e-10)
    assert res.mean == pytest.approx(c0 + np.trace(a), abs=1e-10)
    assert res.std ** 2 == pytest.approx(var, rel=1e-10)
    assert sum(res.sobol_interactions.values()) == pytest.approx(1.0)


@pytest.mark.parametrize(('rule', 'order', 'fit', 'size'), [
    ('gauss', 8, 'auto', None), ('lstsq', 8, 'ols', None), ('lstsq', 10, 'omp', 100)])
def test_ishigami_within_0_01(rule, order, fit, size):
    res = analyze(ishigami, [Uniform(-np.pi, np.pi)] * 3, order=order, rule=rule, fit=fit,
                  size=size, delta=False, n_mc=1024, germ='legendre')
    assert np.max(np.abs(res.sobol_first - ISHIGAMI_S1)) < 0.01
    assert np.max(np.abs(res.sobol_total - ISHIGAMI_ST)) < 0.01


def test_pem5_order_3_warns_and_regresses_exactly_on_a_cubic():
    def cubic(x):
        return x[:, 0] ** 3 + x[:, 0] * x[:, 1] * x[:, 2] + x[:, 1] ** 2

    dists = [Normal(0.0, 1.0)] * 3
    with pytest.warns(AliasingWarning, match='21 Sobol'):
        res = analyze(cubic, dists, order=3, delta=False, n_mc=1024)
    assert res.fit == 'ols' and res.n_evaluations == 40
    # exact: var = Var(x^3) + 1 + Var(x^2) = 15 + 1 + 2
    assert res.std ** 2 == pytest.approx(18.0, rel=1e-10)
    np.testing.assert_allclose(res.sobol_total, [16 / 18, 3 / 18, 1 / 18], atol=1e-10)
    with pytest.raises(ConfigError, match='order'):
        analyze(cubic, dists, order=3, fit='projection', delta=False)


def test_vector_outputs_shapes_and_quantiles():
    def model(x):
        t = np.linspace(0, 1, 5)
        return x[:, :1] * t + x[:, 1:2] ** 2

    res = analyze(model, [Normal(0.0, 1.0), Normal(1.0, 0.5)], order=2, delta=True,
                  n_mc=4096, delta_samples=20_000)
    assert res.sobol_first.shape == (5, 2) and res.delta.shape == (5, 2)
    assert res.mean.shape == (5,) and res.samples.shape == (4096, 5)
    assert res.quantiles([0.025, 0.5, 0.975]).shape == (3, 5)
    np.testing.assert_allclose(res.mean, 1.25, atol=1e-12)
    assert res.sobol_first[0, 0] == pytest.approx(0.0, abs=1e-12)
