"""Input distributions and their exact isoprobabilistic transforms from a standard normal xi.

x = F^-1(Phi(xi)) and back xi = Phi^-1(F(x)), in the units of the parameter. Both directions
use the lower tail (cdf/ppf) for xi <= 0 and the upper tail (sf/isf) for xi > 0 so that neither
side loses digits to 1 - Phi(xi); the standard normal side goes through log-probabilities
(``log_ndtr``/``ndtri_exp``). The paper's Table 2 has slips (Uniform needs erf(xi / sqrt 2), the
Gamma row is the Wilson-Hilferty approximation): these classes are exact.

Negative-sample policy: a physical parameter that must stay positive is given a ``lower`` bound;
a Normal with a bound is the normal *truncated* there (conditioned on x >= lower), with its exact
truncated transform, so every xi, on any rule or Monte Carlo sample, maps inside the physical
range. Every method (rules, surrogate Monte Carlo, brute force) sees the same distribution.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np
from scipy import special, stats

from railgsa_ros.errors import ConfigError


def _check(name: str, value: Any, positive: bool = False) -> float:
    """A finite float (positive if asked); ConfigError naming ``name`` otherwise."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f'{name}: expected a number, got {value!r}') from None
    if not math.isfinite(out) or (positive and out <= 0):
        kind = 'a positive finite number' if positive else 'a finite number'
        raise ConfigError(f'{name}: must be {kind}, got {value!r}')
    return out


class Distribution:
    """A continuous scalar distribution with the exact transform to and from xi ~ N(0, 1)."""

    _frozen: Any  # a frozen scipy.stats distribution

    def from_xi(self, xi: np.ndarray) -> np.ndarray:
        """Physical values x = F^-1(Phi(xi)) for standard-normal xi (any shape)."""
        xi = np.asarray(xi, dtype=float)
        lower = self._frozen.ppf(special.ndtr(np.minimum(xi, 0.0)))
        upper = self._frozen.isf(special.ndtr(-np.maximum(xi, 0.0)))
        return np.where(xi <= 0.0, lower, upper)

    def to_xi(self, x: np.ndarray) -> np.ndarray:
        """Standard-normal xi = Phi^-1(F(x)) for physical values x (any shape)."""
        x = np.asarray(x, dtype=float)
        with np.errstate(divide='ignore'):
            log_cdf, log_sf = self._frozen.logcdf(x), self._frozen.logsf(x)
        low = special.ndtri_exp(np.minimum(log_cdf, math.log(0.5)))
        high = -special.ndtri_exp(np.minimum(log_sf, math.log(0.5)))
        return np.where(log_cdf <= log_sf, low, high)

    def mean(self) -> float:
        """Mean of x."""
        return float(self._frozen.mean())

    def std(self) -> float:
        """Standard deviation of x."""
        return float(self._frozen.std())

    def sample(self, size: int | tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
        """Random draws of x (through xi, so every method shares the same transform)."""
        return self.from_xi(rng.standard_normal(size))


@dataclass(frozen=True)
class Normal(Distribution):
    """Normal(mu, sigma), optionally truncated to [lower, upper] (the negative-sample policy)."""

    mu: float
    sigma: float
    lower: float = -math.inf
    upper: float = math.inf
    _ab: tuple[float, float] = field(init=False, repr=False, compare=False)  # standardised

    def __post_init__(self) -> None:
        object.__setattr__(self, 'mu', _check('mu', self.mu))
        object.__setattr__(self, 'sigma', _check('sigma', self.sigma, positive=True))
        lo, hi = float(self.lower), float(self.upper)
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise ConfigError(f'lower/upper: need lower < upper, got {self.lower!r}, '
                              f'{self.upper!r}')
        a, b = (lo - self.mu) / self.sigma, (hi - self.mu) / self.sigma
        if max(special.ndtr(b) - special.ndtr(a), special.ndtr(-a) - special.ndtr(-b)) < 1e-12:
            raise ConfigError(f'lower/upper: [{lo}, {hi}] holds no probability of '
                              f'Normal({self.mu}, {self.sigma})')
        object.__setattr__(self, '_ab', (a, b))
        # scipy's frozen truncnorm is used for moments only: its ppf/isf lose digits in the
        # tails (measured: x < lower by 5e-10 at xi = -30, xi error 1e-2 at xi = 8), so the
        # transform below is written in log-probabilities instead.
        frozen = stats.norm(self.mu, self.sigma) if math.isinf(a) and math.isinf(b) else \
            stats.truncnorm(a, b, loc=self.mu, scale=self.sigma)
        object.__setattr__(self, '_frozen', frozen)

    def _log_masses(self) -> tuple[float, float, float]:
        """(log Phi(a), log Phi(-b), log of the mass between the standardised bounds)."""
        a, b = self._ab
        log_pa, log_qb = float(special.log_ndtr(a)), float(special.log_ndtr(-b))
        return log_pa, log_qb, float(_log_diff(special.log_ndtr(b), log_pa))

    def from_xi(self, xi: np.ndarray) -> np.ndarray:
        """Physical values in [lower, upper]: exact truncated-normal quantile of Phi(xi)."""
        xi = np.asarray(xi, dtype=float)
        log_pa, log_qb, log_mass = self._log_masses()
        low = special.ndtri_exp(np.logaddexp(log_pa, special.log_ndtr(np.minimum(xi, 0.0))
                                             + log_mass))
        high = -special.ndtri_exp(np.logaddexp(log_qb, special.log_ndtr(-np.maximum(xi, 0.0))
                                               + log_mass))
        x = self.mu + self.sigma * np.where(xi <= 0.0, low, high)
        return np.clip(x, self.lower, self.upper)

    def to_xi(self, x: np.ndarray) -> np.ndarray:
        """Standard-normal xi of x (x is clipped to [lower, upper] first)."""
        z = (np.clip(np.asarray(x, dtype=float), self.lower, self.upper) - self.mu) / self.sigma
        log_pa, log_qb, log_mass = self._log_masses()
        with np.errstate(divide='ignore'):
            log_cdf = _log_diff(special.log_ndtr(z), log_pa) - log_mass
            log_sf = _log_diff(special.log_ndtr(-z), log_qb) - log_mass
        low = special.ndtri_exp(np.minimum(log_cdf, math.log(0.5)))
        high = -special.ndtri_exp(np.minimum(log_sf, math.log(0.5)))
        return np.where(log_cdf <= log_sf, low, high)


def _log_diff(log_a: np.ndarray | float, log_b: np.ndarray | float) -> np.ndarray:
    """log(exp(log_a) - exp(log_b)) for log_a >= log_b, without overflow (-inf when equal)."""
    with np.errstate(divide='ignore', invalid='ignore'):
        return log_a + np.log1p(-np.exp(np.asarray(log_b) - log_a))


@dataclass(frozen=True)
class Uniform(Distribution):
    """Uniform on [a, b]."""

    a: float
    b: float

    def __post_init__(self) -> None:
        a, b = _check('a', self.a), _check('b', self.b)
        if not a < b:
            raise ConfigError(f'a/b: need a < b, got {a}, {b}')
        object.__setattr__(self, '_frozen', stats.uniform(a, b - a))


@dataclass(frozen=True)
class LogNormal(Distribution):
    """LogNormal: ln x ~ Normal(mu, sigma) (mu, sigma are the parameters of ln x)."""

    mu: float
    sigma: float

    def __post_init__(self) -> None:
        mu, sigma = _check('mu', self.mu), _check('sigma', self.sigma, positive=True)
        object.__setattr__(self, '_frozen', stats.lognorm(s=sigma, scale=math.exp(mu)))


@dataclass(frozen=True)
class Gamma(Distribution):
    """Gamma(shape k, scale theta): mean k * theta."""

    shape: float
    scale: float

    def __post_init__(self) -> None:
        k = _check('shape', self.shape, positive=True)
        theta = _check('scale', self.scale, positive=True)
        object.__setattr__(self, '_frozen', stats.gamma(k, scale=theta))


@dataclass(frozen=True)
class Exponential(Distribution):
    """Exponential(rate lambda): mean 1 / lambda."""

    rate: float

    def __post_init__(self) -> None:
        rate = _check('rate', self.rate, positive=True)
        object.__setattr__(self, '_frozen', stats.expon(scale=1.0 / rate))


@dataclass(frozen=True, eq=False)
class Empirical(Distribution):
    """The distribution of observed samples, with a continuous piecewise-linear CDF.

    The CDF interpolates the Hazen plotting positions (i - 1/2) / N of the sorted distinct values
    (ties share their mean position) and is flat outside [min, max]: the support is bounded by
    the data, so no extrapolation is invented.
    """

    samples: np.ndarray = field(repr=False)
    _values: np.ndarray = field(init=False, repr=False)  # distinct sorted values
    _positions: np.ndarray = field(init=False, repr=False)  # their plotting positions

    def __post_init__(self) -> None:
        data = np.asarray(self.samples, dtype=float).ravel()
        if data.size < 2 or not np.all(np.isfinite(data)):
            raise ConfigError('samples: need at least 2 finite values')
        values, counts = np.unique(data, return_counts=True)
        if values.size < 2:
            raise ConfigError('samples: need at least 2 distinct values')
        positions = (np.cumsum(counts) - 0.5 * counts) / data.size
        object.__setattr__(self, '_values', values)
        object.__setattr__(self, '_positions', positions)
        object.__setattr__(self, '_frozen', None)

    def from_xi(self, xi: np.ndarray) -> np.ndarray:
        """Physical values: the piecewise-linear quantile function at Phi(xi)."""
        return np.interp(special.ndtr(np.asarray(xi, dtype=float)), self._positions,
                         self._values)

    def to_xi(self, x: np.ndarray) -> np.ndarray:
        """Standard-normal xi of x (clipped to the data's plotting-position range)."""
        return special.ndtri(np.interp(np.asarray(x, dtype=float), self._values,
                                       self._positions))

    def mean(self) -> float:
        """Mean of the sample."""
        return float(np.mean(self.samples))

    def std(self) -> float:
        """Standard deviation of the sample."""
        return float(np.std(self.samples))


def isoprobabilistic(dists: list[Distribution], xi: np.ndarray) -> np.ndarray:
    """Map standard-normal xi (N, n) to physical values (N, n), one distribution per column."""
    xi = np.asarray(xi, dtype=float)
    if xi.shape[-1] != len(dists):
        raise ValueError(f'xi has {xi.shape[-1]} columns for {len(dists)} distributions')
    return np.stack([d.from_xi(xi[..., i]) for i, d in enumerate(dists)], axis=-1)
