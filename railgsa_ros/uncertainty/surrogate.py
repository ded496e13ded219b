"""The rule's parameter bank and the linear maps from its P filter outputs to the PCE.

For outputs y (P, ...) of the P rule points, the PCE coefficients are ``projector @ y`` (T, ...):
the quadrature projection Psi^T diag(w) when the rule integrates degree 2 * order exactly (pem5 up
to order 2, pem3 up to 1, gauss always), else the least-squares pseudo-inverse (lstsq designs).
The surrogate on a fixed scrambled Sobol' germ sample Z (S, n) is a fixed linear map of the
coefficients: its deviations from the mean (c_0) are ``c[1:] @ germ_basis`` with ``germ_basis`` =
basis(Z) without the constant column, transposed (T - 1, S). Quantiles per sample cost one
(T - 1) x S product (T - 1 = 9 < P = 19 for pem5) and one sort.

The sensor terms of the band (``uncertainty.terms``) are independent of the parameters and
Gaussian: each germ sample j is paired with a standard-normal value ``noise_germ[j]``, the
quantiles of the 1/2 S, ..., (S - 1/2)/S probabilities in a seeded random order (exact marginal,
independent pairing), so surrogate sample j of a sample with sensor std s is
c_0 + c[1:] . psi_j + s * noise_germ[j]: the band and the exceedance probabilities use the same
samples.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import special

from railgsa_ros.errors import ConfigError
from railgsa_ros.models import VehicleModel, as_model
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uq.distributions import Distribution, isoprobabilistic
from railgsa_ros.uq.germ import resolve, sobol, to_normal
from railgsa_ros.uq.pce import basis, multi_indices
from railgsa_ros.uq.rules import exact_degree, make_rule
from railgsa_ros.vehicle import VehicleParams


@dataclass(frozen=True)
class Design:
    """Rule points xi (P, n) in germ space, their vehicles theta (P, N) (N: the model's
    parameters, 5 for the quarter car), the PCE multi-indices
    alpha (T, n), ``projector`` (T, P), ``germ_basis`` (T - 1, S), the fit used and the germ
    (the config's, or the inputs' default for 'auto')."""

    names: tuple[str, ...]
    dists: tuple[Distribution, ...]
    xi: np.ndarray
    theta: np.ndarray
    alpha: np.ndarray
    projector: np.ndarray
    germ_basis: np.ndarray
    fit: str
    germ: str
    noise_germ: np.ndarray

    @property
    def points(self) -> int:
        """Number of rule points = model evaluations (inverse filters) per sample."""
        return int(self.xi.shape[0])


def _projector(config: UncertaintyConfig, xi: np.ndarray, w: np.ndarray, alpha: np.ndarray,
               germ: str) -> tuple[np.ndarray, str]:
    """(T, P) map from rule-point outputs to PCE coefficients, and 'projection' or 'ols'."""
    psi = basis(xi, alpha, germ)
    exact = exact_degree(config.rule, config.order)
    if exact is not None:
        if 2 * config.order > exact:
            raise ConfigError(f'order: rule {config.rule} projects exactly only up to order '
                              f'{exact // 2} (order {config.order} would alias); use rule '
                              f'gauss or lstsq')
        return psi.T * w, 'projection'
    if np.linalg.matrix_rank(psi) < alpha.shape[0]:
        raise ConfigError(f'rule_size: {xi.shape[0]} points cannot fit {alpha.shape[0]} terms')
    return np.linalg.pinv(psi), 'ols'


def build_design(config: UncertaintyConfig, vehicle: VehicleParams | VehicleModel | np.ndarray
                 | None, dists: Mapping[str, Distribution]) -> Design:
    """Rule points for the uncertain parameters ``dists`` (name -> distribution, names from the
    model's ``param_names``) around the nominal ``vehicle`` (a ``models`` vehicle model, or the
    quarter car's VehicleParams or theta (5,)); the other parameters stay nominal."""
    model = as_model(vehicle)
    names, known = tuple(dists), model.param_names
    bad = [n for n in names if n not in known]
    if not names or bad:
        raise ConfigError(f'uncertain parameters: expected some of {", ".join(known)} (the '
                          f'{model.kind}), got {", ".join(names) or "none"}')
    n = len(names)
    germ = resolve(config.germ, list(dists.values()), config.rule)
    xi, w = make_rule(config.rule, n, config.order, config.rule_size or None, config.seed, germ)
    theta = np.tile(model.theta, (xi.shape[0], 1))
    physical = isoprobabilistic(list(dists.values()), to_normal(xi, germ))
    theta[:, [known.index(name) for name in names]] = physical
    alpha = multi_indices(n, config.order)
    projector, fit = _projector(config, xi, w, alpha, germ)
    z = sobol(n, config.germ_samples, config.seed, germ)
    germ_basis = np.ascontiguousarray(basis(z, alpha, germ)[:, 1:].T)
    return Design(names, tuple(dists.values()), xi, theta, alpha, projector, germ_basis, fit,
                  germ, noise_germ(config.germ_samples, config.seed))


def noise_germ(size: int, seed: int) -> np.ndarray:
    """Standard-normal quantiles at (i + 1/2) / size in a random order fixed by seed: (size,)."""
    rng = np.random.default_rng([seed, 0x5E2503])
    return special.ndtri((rng.permutation(size) + 0.5) / size)
