"""Sampling rules in germ space (standard normal unless stated): each returns (xi (N, n), w (N,)).

Quadrature rules (``pem3``, ``pem5``, ``gauss``) have weights summing to 1 that integrate
polynomials against the standard normal density exactly up to their degree (``EXACTNESS``);
``lstsq`` returns a scrambled Sobol' design with equal weights, meant for regression.

PEM (paper Eq. 19-21): nodes at 0 and +-sqrt(3) on at most one (PEM3) or two (PEM5) axes.
PEM5's axial weight w1 = (4 - n) / 18 vanishes at n = 4 and is negative for n >= 5; nodes of
weight exactly 0 are dropped, so they cost no model run (PEM5 has 2n^2 + 1 nodes, 25 at n = 4;
PEM3's centre weight 1 - n/3 vanishes at n = 3, leaving 6 nodes).
"""

from __future__ import annotations

from itertools import combinations
import math

import numpy as np

from railgsa_ros.errors import ConfigError
from railgsa_ros.uq.germ import check, gauss_1d, sobol

THETA = math.sqrt(3.0)


def _axial(n: int) -> np.ndarray:
    """The 2n nodes +-sqrt(3) e_i, shape (2n, n)."""
    eye = np.eye(n) * THETA
    return np.concatenate([eye, -eye])


def _paired(n: int) -> np.ndarray:
    """The 2n(n - 1) nodes with +-sqrt(3) on two axes, shape (2n(n-1), n)."""
    pairs = np.array(list(combinations(range(n), 2)), dtype=int).reshape(-1, 2)
    signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=float) * THETA
    out = np.zeros((len(pairs), 4, n))
    rows = np.arange(len(pairs))[:, None]
    out[rows, :, pairs[:, :1]] = signs[:, 0]
    out[rows, :, pairs[:, 1:]] = signs[:, 1]
    return out.reshape(-1, n)


def _drop_zero(xi: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove nodes whose weight is exactly zero (no model run is spent on them)."""
    keep = w != 0.0
    return xi[keep], w[keep]


def pem3(n: int) -> tuple[np.ndarray, np.ndarray]:
    """PEM3, exact to degree 3: centre (w0 = 1 - n/3) and 2n axial nodes (w1 = 1/6)."""
    xi = np.concatenate([np.zeros((1, n)), _axial(n)])
    w = np.concatenate([[1.0 - n / 3.0], np.full(2 * n, 1.0 / 6.0)])
    return _drop_zero(xi, w)


def pem5(n: int) -> tuple[np.ndarray, np.ndarray]:
    """PEM5, exact to degree 5: w0 = 1 + (n^2 - 7n)/18, w1 = (4 - n)/18, w2 = 1/36."""
    xi = np.concatenate([np.zeros((1, n)), _axial(n), _paired(n)])
    w = np.concatenate([[1.0 + (n * n - 7.0 * n) / 18.0], np.full(2 * n, (4.0 - n) / 18.0),
                        np.full(2 * n * (n - 1), 1.0 / 36.0)])
    return _drop_zero(xi, w)


def gauss(n: int, points: int, germ: str = 'hermite') -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss rule of the germ: points^n nodes, exact to degree 2 points - 1 per axis."""
    x1, w1 = gauss_1d(points, germ)
    grids = np.meshgrid(*([x1] * n), indexing='ij')
    weights = np.meshgrid(*([w1] * n), indexing='ij')
    return (np.stack([g.ravel() for g in grids], -1),
            np.prod(np.stack([g.ravel() for g in weights], -1), axis=-1))


def lstsq(n: int, size: int, seed: int | None = 0,
          germ: str = 'hermite') -> tuple[np.ndarray, np.ndarray]:
    """Regression design: ``size`` scrambled Sobol' points in germ space, equal weights."""
    return sobol(n, size, seed, germ), np.full(size, 1.0 / size)


EXACTNESS = {'pem3': 3, 'pem5': 5}
RULES = ('pem3', 'pem5', 'gauss', 'lstsq')


def make_rule(name: str, n: int, order: int, size: int | None = None, seed: int | None = 0,
              germ: str = 'hermite') -> tuple[np.ndarray, np.ndarray]:
    """Build rule ``name`` for n inputs and a PCE of total ``order``.

    ``gauss`` uses order + 1 points per axis (exact projection); ``lstsq`` uses ``size`` points
    (default twice the number of PCE terms).
    """
    if n < 1:
        raise ConfigError(f'uncertain parameters: need at least one, got {n}')
    if name in EXACTNESS and check(germ) != 'hermite':
        raise ConfigError(f'rule: {name} is a rule for standard-normal inputs (germ hermite)')
    if name == 'pem3':
        return pem3(n)
    if name == 'pem5':
        return pem5(n)
    if name == 'gauss':
        return gauss(n, order + 1, check(germ))
    if name == 'lstsq':
        terms = math.comb(n + order, n)
        return lstsq(n, size or 2 * terms, seed, check(germ))
    raise ConfigError(f'rule: unknown rule {name!r}; expected one of {", ".join(RULES)}')


def exact_degree(name: str, order: int) -> int | None:
    """Largest total degree the rule integrates exactly (None for regression designs)."""
    if name == 'gauss':
        return 2 * (order + 1) - 1
    return EXACTNESS.get(name)
