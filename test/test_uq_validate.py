"""Brute-force Monte Carlo (Saltelli/Jansen, given-data delta) against analytic truth and PCE."""

from pathlib import Path
import sys

import numpy as np
import pytest

from railgsa_ros.uq import Normal, monte_carlo_indices, validate
from railgsa_ros.uq.delta import delta_given_data

sys.path.insert(0, str(Path(__file__).parent))
from test_uq_delta import linear_delta


def test_saltelli_jansen_on_linear_gaussian():
    a = np.array([1.0, 2.0, 0.5])
    mc = monte_carlo_indices(lambda x: x @ a, [Normal(0.0, 1.0)] * 3, n_base=4096)
    exact = a ** 2 / np.sum(a ** 2)
    assert mc.n_evaluations == 5 * 4096
    np.testing.assert_allclose(mc.sobol_first, exact, atol=0.01)
    np.testing.assert_allclose(mc.sobol_total, exact, atol=0.01)
    np.testing.assert_allclose(mc.delta, linear_delta(a, np.ones(3)), atol=0.03)


def test_given_data_delta_independent_input_is_zero():
    rng = np.random.default_rng(4)
    x = rng.standard_normal((16384, 2))
    d = delta_given_data(x, x[:, 0] + 0.3 * x[:, 0] ** 2)
    # a singular copula (y a function of x0 alone) is smeared over the rank grid: below 1
    assert d[0, 1] == pytest.approx(0.0, abs=5e-3) and d[0, 0] > 0.7


def test_validate_reports_errors_and_cost_ratio():
    def model(x):
        return x[:, 0] + x[:, 1] ** 2 + 0.5 * x[:, 0] * x[:, 2]

    check = validate(model, [Normal(0.0, 1.0)] * 3, n_base=4096, order=2, n_mc=4096,
                     delta_samples=50_000)
    assert check.result.n_evaluations == 19
    assert check.cost_ratio == pytest.approx(5 * 4096 / 19)
    assert check.errors['sobol_first'] < 0.02 and check.errors['sobol_total'] < 0.02
    assert check.errors['std_rel'] < 0.02 and check.errors['delta'] < 0.04
