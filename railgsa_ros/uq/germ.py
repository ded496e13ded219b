"""The germ of the expansion: standard-normal (Hermite chaos) or uniform on [-1, 1] (Legendre).

Hermite is the paper's choice and the only germ the PEM rules exist for. A uniform input seen
through a normal germ is a saturating function of xi whose Hermite coefficients decay slowly
(measured on Ishigami's sin(x): 1.3 % of the amplitude left beyond order 30), so uniform inputs
are better served by the Legendre germ (the Wiener-Askey match), with Gauss or regression rules.
Every distribution maps from either germ through the probability u: xi = Phi^-1(u).

``default_germ`` (germ ``'auto'``, the default) follows the inputs: Legendre when every input is
uniform and the rule is not a PEM rule, else Hermite. Mixed inputs get Hermite: one germ serves
every axis here, a normal input through a uniform germ is Phi^-1 of it (unbounded at the ends:
worse than the bounded uniform through a normal germ), and the PEM rules exist only for it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any
import warnings

import numpy as np
from numpy.polynomial import hermite_e, legendre
from scipy import special
from scipy.stats import qmc

from railgsa_ros.errors import ConfigError
from railgsa_ros.uq.distributions import Uniform

GERMS = ('hermite', 'legendre')
AUTO = 'auto'
PEM_RULES = ('pem3', 'pem5')


def check(germ: str) -> str:
    """Return germ if known, else ConfigError naming the field."""
    if germ not in GERMS:
        raise ConfigError(f'germ: unknown germ {germ!r}; expected one of {", ".join(GERMS)}')
    return germ


def default_germ(dists: Sequence[Any], rule: str = 'gauss') -> str:
    """The Wiener-Askey germ of the inputs (module docstring): legendre for all-uniform inputs
    on a Gauss or regression rule, else hermite."""
    uniform = bool(dists) and all(isinstance(d, Uniform) for d in dists)
    return 'legendre' if uniform and rule not in PEM_RULES else 'hermite'


def resolve(germ: str | None, dists: Sequence[Any], rule: str = 'gauss') -> str:
    """``germ`` checked, or the default germ of ``dists`` when None or 'auto'."""
    return default_germ(dists, rule) if germ in (None, AUTO) else check(germ)


def from_unit(u: np.ndarray, germ: str) -> np.ndarray:
    """Germ values with probability u in (0, 1)."""
    return special.ndtri(u) if germ == 'hermite' else 2.0 * np.asarray(u) - 1.0


def to_normal(z: np.ndarray, germ: str) -> np.ndarray:
    """Standard-normal xi with the same probability as the germ value z."""
    return np.asarray(z, dtype=float) if germ == 'hermite' else special.ndtri(0.5 * (z + 1.0))


def vander(z: np.ndarray, order: int, germ: str) -> np.ndarray:
    """Orthonormal 1-D polynomials of degree 0..order at z (...): shape (..., order + 1)."""
    k = np.arange(order + 1)
    if germ == 'hermite':
        return hermite_e.hermevander(z, order) / np.sqrt(special.factorial(k))
    return legendre.legvander(z, order) * np.sqrt(2.0 * k + 1.0)


def gauss_1d(points: int, germ: str) -> tuple[np.ndarray, np.ndarray]:
    """Gauss nodes and probability weights (summing to 1) for the germ's density."""
    x, w = hermite_e.hermegauss(points) if germ == 'hermite' else legendre.leggauss(points)
    return x, w / w.sum()


def sobol(n: int, size: int, seed: int | np.random.Generator | None, germ: str) -> np.ndarray:
    """A scrambled Sobol' design of ``size`` points in germ space, shape (size, n)."""
    sampler = qmc.Sobol(d=n, scramble=True, seed=seed)
    with warnings.catch_warnings():
        # Sizes that are not powers of 2 lose the balance property but stay low-discrepancy;
        # regression designs need the exact size, so scipy's advisory warning is silenced.
        warnings.filterwarnings('ignore', message='.*balance properties.*')
        u = sampler.random(size)
    return from_unit(u, germ)
