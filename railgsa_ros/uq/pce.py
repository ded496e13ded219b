"""Polynomial chaos of total order p in n inputs: orthonormal probabilists' Hermite (or Legendre).

Psi_alpha(xi) = prod_j He_{alpha_j}(xi_j) / sqrt(alpha_j!), orthonormal under N(0, I). The
coefficients come from projection on a quadrature rule, ordinary least squares or a sparse
orthogonal matching pursuit with corrected leave-one-out error; moments and Sobol' indices are
sums of squared coefficients. Outputs are an array axis: coef has shape (P, m).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations_with_replacement
import math

import numpy as np

from railgsa_ros.uq.germ import vander as germ_vander

_CHUNK = 16384  # rows per basis evaluation: bounds memory at N * P * n floats per chunk


def multi_indices(n: int, order: int) -> np.ndarray:
    """All alpha in N^n with |alpha| <= order, graded by total degree; shape (P, n), row 0 = 0."""
    rows = [np.zeros((1, n), dtype=int)]
    for degree in range(1, order + 1):
        combos = np.array(list(combinations_with_replacement(range(n), degree)), dtype=int)
        rows.append((combos[:, :, None] == np.arange(n)).sum(axis=1))
    return np.concatenate(rows)


def basis(xi: np.ndarray, alpha: np.ndarray, germ: str = 'hermite') -> np.ndarray:
    """Orthonormal basis at germ points xi (N, n) for multi-indices alpha (P, n): (N, P)."""
    xi = np.atleast_2d(np.asarray(xi, dtype=float))
    order = int(alpha.max(initial=0))
    vander = germ_vander(xi, order, germ)  # (N, n, order + 1)
    cols = np.arange(alpha.shape[1])
    return np.prod(vander[:, cols, alpha], axis=-1)


def fit_projection(psi: np.ndarray, weights: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Coefficients by quadrature projection: c = sum_k w_k y_k Psi(xi_k); shape (P, m)."""
    return psi.T @ (weights[:, None] * y)


def fit_ols(psi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Coefficients by ordinary least squares; shape (P, m)."""
    return np.linalg.lstsq(psi, y, rcond=None)[0]


def _corrected_loo(q: np.ndarray, r_inv: np.ndarray, resid: np.ndarray,
                   y_var: np.ndarray) -> float:
    """Corrected leave-one-out error (Blatman & Sudret 2011), summed over outputs.

    q: thin-QR factor (N, k) of the active columns, r_inv: inverse of R, resid (N, m).
    """
    n_rows, k = q.shape
    h = np.sum(q * q, axis=1)
    if np.any(h > 1.0 - 1e-10) or k >= n_rows:
        return math.inf
    loo = np.mean((resid / (1.0 - h)[:, None]) ** 2, axis=0) / y_var
    trace = n_rows * np.sum(r_inv * r_inv)  # tr((Psi^T Psi / N)^-1)
    return float(np.sum(loo) * n_rows / (n_rows - k) * (1.0 + trace / n_rows))


def fit_omp(psi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sparse coefficients by simultaneous orthogonal matching pursuit (one support for all
    outputs), keeping the support of least corrected leave-one-out error; shape (P, m).

    Greedy selection is sequential by nature: the loop runs over selected terms, not samples.
    """
    n_rows, n_terms = psi.shape
    y_var = np.maximum(np.var(y, axis=0), np.finfo(float).tiny)
    col_norm = np.linalg.norm(psi, axis=0)
    col_norm[col_norm == 0] = np.inf
    active = [0]
    best = (math.inf, np.zeros((n_terms, y.shape[1])))
    for _ in range(min(n_terms, n_rows - 2)):
        q, r = np.linalg.qr(psi[:, active])
        coef_active = np.linalg.solve(r, q.T @ y)
        resid = y - psi[:, active] @ coef_active
        err = _corrected_loo(q, np.linalg.inv(r), resid, y_var)
        if err < best[0]:
            coef = np.zeros((n_terms, y.shape[1]))
            coef[active] = coef_active
            best = (err, coef)
        score = np.sum((psi.T @ resid) ** 2, axis=1) / col_norm ** 2
        score[active] = -1.0
        if len(active) == n_terms or score.max() <= 0.0:
            break
        active.append(int(np.argmax(score)))
    return best[1]


@dataclass(frozen=True)
class PCE:
    """A fitted expansion: multi-indices alpha (P, n), coefficients coef (P, m), its germ."""

    alpha: np.ndarray
    coef: np.ndarray
    germ: str = 'hermite'

    def __call__(self, xi: np.ndarray) -> np.ndarray:
        """Surrogate values at xi (N, n): shape (N, m), evaluated in chunks of rows."""
        xi = np.atleast_2d(xi)
        out = np.empty((xi.shape[0], self.coef.shape[1]))
        for start in range(0, xi.shape[0], _CHUNK):
            stop = start + _CHUNK
            out[start:stop] = basis(xi[start:stop], self.alpha, self.germ) @ self.coef
        return out

    @property
    def mean(self) -> np.ndarray:
        """Mean of each output, shape (m,)."""
        return self.coef[0].copy()

    @property
    def variance(self) -> np.ndarray:
        """Variance of each output, shape (m,)."""
        return np.sum(self.coef[1:] ** 2, axis=0)

    def _share(self, mask: np.ndarray) -> np.ndarray:
        """Variance share of the terms selected by mask (P, k): shape (m, k); 0 if V = 0."""
        part = (self.coef ** 2).T @ mask.astype(float)
        var = self.variance[:, None]
        return np.divide(part, var, out=np.zeros_like(part), where=var > 0)

    @property
    def sobol_first(self) -> np.ndarray:
        """First-order indices S_i, shape (m, n): terms in input i alone."""
        alone = (self.alpha > 0) & ((self.alpha > 0).sum(axis=1) == 1)[:, None]
        return self._share(alone)

    @property
    def sobol_total(self) -> np.ndarray:
        """Total indices S_Ti, shape (m, n): every term involving input i."""
        return self._share(self.alpha > 0)

    def sobol_interactions(self) -> dict[tuple[int, ...], np.ndarray]:
        """Closed-subset-free (ANOVA) indices S_u for every subset u that has terms: u -> (m,)."""
        support = self.alpha > 0
        keys, inverse = np.unique(support[1:], axis=0, return_inverse=True)
        groups = np.zeros((self.alpha.shape[0], len(keys)), dtype=bool)
        groups[np.arange(1, self.alpha.shape[0]), inverse.ravel()] = True
        shares = self._share(groups)
        return {tuple(int(i) for i in np.flatnonzero(k)): shares[:, j]
                for j, k in enumerate(keys)}
