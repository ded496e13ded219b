"""Exceedance probability P(|u| > limit) of a reconstructed sample from its surrogate.

Per sample, u = c_0 + c[1:] . psi(Z_j) + e with Z_j the band's germ samples (``Design``) and e the
independent Gaussian sensor terms of std s (``uncertainty.terms``). The probability averages, over
the same germ samples the band's quantiles use, the exact normal probability of the sensor term
(Rao-Blackwellised: no sampling noise from e):

    P(|u| > L) = 1/S sum_j [ Phi((-L - m_j) / s) + Phi((m_j - L) / s) ],   m_j = c_0 + c[1:] psi_j

(s = 0: the fraction of samples with |m_j| > L). A candidate defect (a stretch of samples) takes
the largest probability of its samples: the parameter part, which dominates, is one draw for the
whole stretch, so its samples' events nearly coincide.
"""

from __future__ import annotations

import numpy as np
from scipy import special

from railgsa_ros.uncertainty.surrogate import Design

BLOCK = 256  # samples per surrogate block: 2 MB at 1024 germ samples


def exceedance_probability(design: Design, u: np.ndarray, limit_m: np.ndarray | float,
                           sensor_std_m: np.ndarray | float | None = None) -> np.ndarray:
    """P(|u| > limit) (K,) for bank outputs u (P, K) m, limits (K,) or scalar m (NaN: 0) and
    sensor std (K,) or scalar m (None: 0)."""
    coef = design.projector @ np.asarray(u, dtype=float)  # (T, K)
    count = coef.shape[1]
    limit = np.broadcast_to(np.asarray(limit_m, dtype=float), (count,))
    std = np.broadcast_to(np.asarray(0.0 if sensor_std_m is None else sensor_std_m, float),
                          (count,))
    out = np.zeros(count)
    for lo in range(0, count, BLOCK):
        sl = slice(lo, lo + BLOCK)
        m = coef[0, sl, None] + coef[1:, sl].T @ design.germ_basis  # (K', S)
        lim, s = limit[sl, None], std[sl, None]
        with np.errstate(divide='ignore', invalid='ignore'):
            smooth = special.ndtr((-lim - m) / s) + special.ndtr((m - lim) / s)
        sharp = (np.abs(m) > lim).astype(float)
        out[sl] = np.mean(np.where(s > 0, smooth, sharp), axis=1)
    return np.where(np.isfinite(limit) & np.all(np.isfinite(coef), axis=0), out, 0.0)
