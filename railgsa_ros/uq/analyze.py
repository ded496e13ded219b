"""One entry point: uncertainty and global sensitivity of a model by Hermite PCE.

``model`` maps parameter values in physical units, shape (N, n), to outputs (N,) or (N, m);
``dists`` gives one :class:`Distribution` per column. Indices have shape (n,) for a scalar
output and (m, n) for m outputs.

Which fit: a quadrature rule projects when it is exact for the integrands of the expansion
(degree 2 * order): pem3 up to order 1, pem5 up to order 2, gauss always. Beyond that PEM5
aliases (order 3: every PEM5 node is a root of He3, so He3(xi_i) and xi1 xi2 xi3 come back 0 and
others alias), so ``fit='auto'`` warns (:class:`AliasingWarning`) and fits by least squares on the
rule's nodes plus scrambled Sobol' points up to twice the number of terms; ``fit='projection'``
refuses with a ConfigError.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import math
import warnings

import numpy as np

from railgsa_ros.errors import ConfigError, InputError
from railgsa_ros.uq.conditional import conditional_design, delta_conditional
from railgsa_ros.uq.delta import delta_indices
from railgsa_ros.uq.distributions import Distribution, isoprobabilistic
from railgsa_ros.uq.germ import resolve, sobol, to_normal
from railgsa_ros.uq.pce import PCE, basis, fit_ols, fit_omp, fit_projection, multi_indices
from railgsa_ros.uq.rules import exact_degree, make_rule

FITS = ('auto', 'projection', 'ols', 'omp')
DELTAS = (True, False, 'surrogate', 'pem5')
OVERSAMPLING = 2  # regression points per PCE term when PEM nodes must be augmented
#: highest total PCE order: order 10 in 5 inputs is already 3003 terms (6006 model runs); 40
#: would not finish
MAX_ORDER = 10
_DELTA_VALUES = 2 ** 24  # surrogate outputs held at once by the delta double loop

Model = Callable[[np.ndarray], np.ndarray]


class AliasingWarning(UserWarning):
    """The rule cannot project the requested order exactly; regression is used instead."""


def evaluate(model: Model, dists: Sequence[Distribution], xi: np.ndarray,
             germ: str = 'hermite') -> tuple[np.ndarray, bool]:
    """Model outputs at germ points as (N, m), and whether the model is scalar."""
    y = np.asarray(model(isoprobabilistic(list(dists), to_normal(xi, germ))), dtype=float)
    if y.ndim not in (1, 2) or y.shape[0] != xi.shape[0]:
        raise InputError(f'model: expected outputs of shape ({xi.shape[0]},) or '
                         f'({xi.shape[0]}, m), got {y.shape}')
    if not np.all(np.isfinite(y)):
        bad = int(np.sum(~np.all(np.isfinite(y.reshape(len(y), -1)), axis=1)))
        raise InputError(f'model: non-finite output at {bad} of {len(y)} points')
    return y.reshape(len(y), -1), y.ndim == 1


@dataclass(frozen=True)
class Result:
    """Moments, quantiles and sensitivity indices of the model output under the input law."""

    pce: PCE
    samples: np.ndarray  # surrogate Monte Carlo outputs, (n_mc,) or (n_mc, m)
    delta: np.ndarray | None
    n_evaluations: int
    rule: str
    order: int
    fit: str
    scalar: bool = field(repr=False)

    def _shape(self, value: np.ndarray) -> np.ndarray:
        return value[0] if self.scalar else value

    @property
    def mean(self) -> np.ndarray:
        """Mean of the output, () or (m,)."""
        return self._shape(self.pce.mean)

    @property
    def std(self) -> np.ndarray:
        """Standard deviation of the output, () or (m,)."""
        return self._shape(np.sqrt(self.pce.variance))

    @property
    def sobol_first(self) -> np.ndarray:
        """First-order Sobol' indices, (n,) or (m, n)."""
        return self._shape(self.pce.sobol_first)

    @property
    def sobol_total(self) -> np.ndarray:
        """Total Sobol' indices, (n,) or (m, n)."""
        return self._shape(self.pce.sobol_total)

    @property
    def sobol_interactions(self) -> dict[tuple[int, ...], np.ndarray]:
        """Sobol' index of every group of inputs (tuple of input positions) -> () or (m,)."""
        return {k: self._shape(v) for k, v in self.pce.sobol_interactions().items()}

    def quantiles(self, q: float | Sequence[float]) -> np.ndarray:
        """Quantiles of the surrogate Monte Carlo sample, shape q.shape (+ (m,))."""
        return np.quantile(self.samples, q, axis=0)


def _design(rule: str, n: int, order: int, fit: str, size: int | None, seed: int | None,
            germ: str) -> tuple[np.ndarray, np.ndarray, str]:
    """Design points, weights and the fit actually used."""
    xi, w = make_rule(rule, n, order, size, seed, germ)
    exact = exact_degree(rule, order)
    projectable = exact is not None and 2 * order <= exact
    terms = math.comb(n + order, n)
    if fit == 'projection' and not projectable:
        raise ConfigError(f'order: rule {rule} cannot project order {order} exactly (it is '
                          f'exact to degree {exact}, order {order} needs {2 * order}); use '
                          f'fit auto/ols/omp or rule gauss')
    if fit in ('auto', 'projection') and projectable:
        return xi, w, 'projection'
    fit = 'ols' if fit in ('auto', 'projection') else fit
    if rule != 'lstsq' and xi.shape[0] < OVERSAMPLING * terms:
        if not projectable:
            warnings.warn(f'rule {rule} with {xi.shape[0]} points cannot project order {order} '
                          f'exactly; fitting by {fit} on its points plus '
                          f'{OVERSAMPLING * terms - xi.shape[0]} Sobol\' points',
                          AliasingWarning, stacklevel=3)
        extra = sobol(n, OVERSAMPLING * terms - xi.shape[0], seed, germ)
        xi = np.concatenate([xi, extra])
    return xi, np.full(len(xi), 1.0 / len(xi)), fit


def check_seed(seed: int | None) -> None:
    """ConfigError unless ``seed`` is None or an integer >= 0 (numpy's seeds)."""
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise ConfigError(f'seed: expected an integer >= 0, got {seed!r}')


def analyze(model: Model, dists: Sequence[Distribution], order: int = 3, rule: str = 'pem5',
            delta: bool | str = True, n_mc: int = 100_000, seed: int | None = 0,
            fit: str = 'auto', size: int | None = None, delta_samples: int = 400_000,
            germ: str | None = None) -> Result:
    """Fit a PCE of total ``order`` to ``model`` and derive every statistic from it.

    Regression fits (ols, omp) on a quadrature rule add scrambled Sobol' points up to twice
    the number of terms.

    rule: pem3 | pem5 | gauss | lstsq (``size`` points); fit: auto | projection | ols | omp;
    delta: True or 'surrogate' (double-loop Monte Carlo on the surrogate, ``delta_samples``
    surrogate runs per input), 'pem5' (the paper's conditional-PEM5 design, extra model runs),
    False (skip). ``n_mc`` surrogate samples feed ``samples`` and ``quantiles``. germ: hermite
    (the paper; PEM rules) or legendre (uniform inputs, gauss/lstsq rules); None or 'auto':
    the Wiener-Askey germ of ``dists`` (``germ.default_germ``: legendre when every input is
    uniform and the rule is not PEM, else hermite).
    """
    germ = resolve(germ, dists, rule)
    if fit not in FITS:
        raise ConfigError(f'fit: unknown fit {fit!r}; expected one of {", ".join(FITS)}')
    if delta not in DELTAS:
        raise ConfigError(f'delta: expected True, False, "surrogate" or "pem5", got {delta!r}')
    if isinstance(order, bool) or not isinstance(order, int) or not 1 <= order <= MAX_ORDER:
        raise ConfigError(f'order: expected an integer in [1, {MAX_ORDER}], got {order!r}')
    check_seed(seed)
    if delta == 'pem5' and germ != 'hermite':
        raise ConfigError('delta: the conditional PEM5 design needs germ hermite')
    n = len(dists)
    xi, w, used = _design(rule, n, order, fit, size, seed, germ)
    cond = conditional_design(n) if delta == 'pem5' else None
    runs = xi if cond is None else np.concatenate([xi, cond.points])
    unique, inverse = np.unique(runs, axis=0, return_inverse=True)
    y_unique, scalar = evaluate(model, dists, unique, germ)
    y = y_unique[inverse.ravel()]
    alpha = multi_indices(n, order)
    psi = basis(xi, alpha, germ)
    y_fit = y[:len(xi)]
    if used == 'projection':
        coef = fit_projection(psi, w, y_fit)
    elif used == 'omp':
        coef = fit_omp(psi, y_fit)
    else:
        coef = fit_ols(psi, y_fit)
    pce = PCE(alpha, coef, germ)
    samples = pce(sobol(n, n_mc, seed, germ))
    if delta in (True, 'surrogate'):
        # outputs in chunks: the double loop holds n * delta_samples values per output
        step = max(1, _DELTA_VALUES // (n * delta_samples))
        d = np.concatenate([delta_indices(PCE(alpha, coef[:, j:j + step], germ), n,
                                          delta_samples, seed=seed, germ=germ)
                            for j in range(0, coef.shape[1], step)])
    elif cond is not None:
        d = delta_conditional(cond, y[len(xi):], pce, seed=seed)
    else:
        d = None
    if scalar:
        samples = samples[:, 0]
        d = None if d is None else d[0]
    return Result(pce, samples, d, len(unique), rule, order, used, scalar)
