"""Rules: PEM3/PEM5 exactness on every monomial (exact Gaussian moments as truth)."""

from itertools import combinations_with_replacement
import math

import numpy as np
import pytest

from railgsa_ros.errors import ConfigError
from railgsa_ros.uq.rules import gauss, lstsq, make_rule, pem3, pem5


def gaussian_moment(powers: np.ndarray) -> float:
    """E[prod xi_j^k_j] for independent standard normals: prod (k - 1)!! for even k, else 0."""
    if np.any(powers % 2):
        return 0.0
    return float(np.prod([math.prod(range(k - 1, 0, -2)) for k in powers]))


def monomials(n: int, degree: int) -> np.ndarray:
    combos = combinations_with_replacement(range(n), degree)
    return np.array([np.bincount(c, minlength=n) for c in combos]).reshape(-1, n)


def max_error(rule, n: int, degree: int) -> tuple[float, int]:
    xi, w = rule(n)
    powers = monomials(n, degree)
    quad = np.prod(xi[:, None, :] ** powers[None], axis=-1).T @ w
    truth = np.array([gaussian_moment(p) for p in powers])
    return float(np.max(np.abs(quad - truth))), int(np.sum(np.abs(quad - truth) > 1e-9))


@pytest.mark.parametrize('n', range(1, 9))
def test_pem3_exact_to_degree_3(n):
    assert all(max_error(pem3, n, d)[0] < 1e-12 for d in range(4))
    assert len(pem3(n)[0]) == 2 * n + 1 - (n == 3)  # w0 = 1 - n/3 vanishes at n = 3


@pytest.mark.parametrize('n', range(1, 9))
def test_pem5_exact_to_degree_5(n):
    assert all(max_error(pem5, n, d)[0] < 1e-11 for d in range(6))
    xi, w = pem5(n)
    assert len(xi) == 2 * n * n + 1 - 2 * n * (n == 4)  # w1 = (4 - n)/18 vanishes at n = 4
    assert w.sum() == pytest.approx(1.0) and (w.min() < 0) == (n >= 5)


def test_pem5_fails_degree_6_as_measured():
    # gsa_notes section 3: 24 of 28 degree-6 monomials exact; x_i^6 gives 9 (not 15)
    err, wrong = max_error(pem5, 3, 6)
    assert wrong == 4 and err == pytest.approx(6.0)
    assert max_error(pem3, 3, 4)[1] > 0


def test_gauss_exactness_and_lstsq_design():
    xi, w = gauss(2, 4)
    assert len(xi) == 16 and max_error(lambda n: (xi, w), 2, 7)[0] < 1e-11
    assert max_error(lambda n: (xi, w), 2, 8)[0] > 1.0
    pts, wl = lstsq(3, 40, seed=1)
    assert pts.shape == (40, 3) and np.allclose(wl, 1 / 40)
    assert len(make_rule('lstsq', 3, 3)[0]) == 40  # twice the 20 cubic terms


def test_unknown_rule_and_pem_with_legendre_germ():
    with pytest.raises(ConfigError, match='rule'):
        make_rule('pem7', 3, 2)
    with pytest.raises(ConfigError, match='rule'):
        make_rule('pem5', 3, 2, germ='legendre')
