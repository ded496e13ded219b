"""Brute-force Monte Carlo check of :func:`analyze`: the same indices from model runs only.

Sobol' indices by the Saltelli (2010) first-order and Jansen total-effect estimators on a
scrambled Sobol' pair of matrices A, B (N (n + 2) model runs); delta from the given data
(the 2N runs of A and B) by the copula form of the same cross-fitted L1 estimator
(:func:`delta.delta_given_data`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from railgsa_ros.errors import ConfigError
from railgsa_ros.uq.analyze import Model, Result, analyze, check_seed, evaluate
from railgsa_ros.uq.delta import delta_given_data
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.uq.germ import sobol


@dataclass(frozen=True)
class MonteCarloIndices:
    """Brute-force estimates; shapes as in Result ((n,) or (m, n))."""

    mean: np.ndarray
    std: np.ndarray
    sobol_first: np.ndarray
    sobol_total: np.ndarray
    delta: np.ndarray
    n_evaluations: int


@dataclass(frozen=True)
class Validation:
    """Brute force, the PCE result, their largest absolute differences and the cost ratio."""

    monte_carlo: MonteCarloIndices
    result: Result
    errors: dict[str, float]
    cost_ratio: float  # brute-force runs / PCE runs


def monte_carlo_indices(model: Model, dists: Sequence[Distribution], n_base: int = 4096,
                        seed: int | None = 0) -> MonteCarloIndices:
    """Saltelli/Jansen Sobol' indices and given-data delta with n_base (n + 2) model runs."""
    n = len(dists)
    ab = sobol(2 * n, n_base, seed, 'hermite')
    a, b = ab[:, :n], ab[:, n:]
    mixed = np.broadcast_to(a, (n, n_base, n)).copy()
    mixed[np.arange(n), :, np.arange(n)] = b.T
    y, scalar = evaluate(model, dists, np.concatenate([a, b, mixed.reshape(-1, n)]))
    mean = np.mean(y[:2 * n_base], axis=0)
    y = y - mean  # centred: the first-order estimator's noise grows with mean^2 / variance
    y_a, y_b = y[:n_base], y[n_base:2 * n_base]
    y_ab = y[2 * n_base:].reshape(n, n_base, -1)
    var = np.var(np.concatenate([y_a, y_b]), axis=0)
    safe = np.where(var > 0, var, 1.0)
    first = np.mean(y_b * (y_ab - y_a), axis=1).T / safe[:, None]
    total = 0.5 * np.mean((y_a - y_ab) ** 2, axis=1).T / safe[:, None]
    delta = delta_given_data(np.concatenate([a, b]), np.concatenate([y_a, y_b]), seed=seed)
    std = np.sqrt(var)

    def shape(v: np.ndarray) -> np.ndarray:
        return v[0] if scalar else v

    return MonteCarloIndices(shape(mean), shape(std), shape(first), shape(total), shape(delta),
                             len(y))


def validate(model: Model, dists: Sequence[Distribution], n_base: int = 4096,
             seed: int | None = 0, result: Result | None = None,
             **analyze_kwargs: Any) -> Validation:
    """Compare ``analyze`` (run here unless ``result`` is given) with brute force
    (``n_base`` >= 2, ConfigError otherwise)."""
    if isinstance(n_base, bool) or not isinstance(n_base, int) or n_base < 2:
        raise ConfigError(f'validate: expected a number of base samples >= 2, got {n_base!r}')
    check_seed(seed)
    result = result or analyze(model, dists, seed=seed, **analyze_kwargs)
    mc = monte_carlo_indices(model, dists, n_base, seed)
    errors = {name: float(np.max(np.abs(np.asarray(getattr(result, name))
                                        - getattr(mc, name))))
              for name in ('sobol_first', 'sobol_total')}
    scale = np.maximum(np.abs(mc.std), np.finfo(float).tiny)
    errors['mean_rel_std'] = float(np.max(np.abs(result.mean - mc.mean) / scale))
    errors['std_rel'] = float(np.max(np.abs(result.std - mc.std) / scale))
    if result.delta is not None:
        errors['delta'] = float(np.max(np.abs(result.delta - mc.delta)))
    return Validation(mc, result, errors, mc.n_evaluations / result.n_evaluations)
