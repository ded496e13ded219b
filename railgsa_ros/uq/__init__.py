"""Uncertainty quantification and global sensitivity by Hermite polynomial chaos (issue 4).

``analyze(model, dists)`` fits the expansion on a PEM/Gauss/regression design and returns mean,
std, quantiles, Sobol' and Borgonovo indices; ``validate`` checks it against brute force.
"""

from railgsa_ros.uq.analyze import AliasingWarning, Result, analyze
from railgsa_ros.uq.distributions import (
    Distribution,
    Empirical,
    Exponential,
    Gamma,
    LogNormal,
    Normal,
    Uniform,
)
from railgsa_ros.uq.validate import Validation, monte_carlo_indices, validate

__all__ = ['AliasingWarning', 'Distribution', 'Empirical', 'Exponential', 'Gamma', 'LogNormal',
           'Normal', 'Result', 'Uniform', 'Validation', 'analyze', 'monte_carlo_indices',
           'validate']
