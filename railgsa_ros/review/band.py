"""The band's quantiles at the samples a review keeps of them, not at every sample.

The review's stream asks the bank for the PCE mean only (``Driver(quantiles=False)``) and
computes the quantiles (``uncertainty.stream.band_statistics``, the same floats as the full
band) of the samples whose band it uses:

- the two samples around each 0.25 m grid cell centre (``grid.cells_between``; about 2 of 8 at
  30 m/s and 1 kHz), and the last sample of each chunk (the next chunk's first cell may need it);
- the exceedance candidates: samples whose |u| or band edge may pass a limit; a band edge lies
  within mean +- ``deviation_bound`` (every germ sample's deviation is below it), so the others
  cannot pass;

Every other sample's lower/upper is NaN. The grid and the exceedances are those of the band at
every sample (to the last bit of the PCE coefficients' sums); the widest band is the widest of
the samples computed (the review's 0.25 m resolution: an exact widest would need a bound the
band width does not have cheaply; Cauchy-Schwarz admits a third of all samples at 30 m/s and
halves the saving).
"""

from __future__ import annotations

import numpy as np

from railgsa_ros.standards.en13848 import Limits
from railgsa_ros.standards.sampling import cells_between
from railgsa_ros.uncertainty.stream import band_statistics, deviation_bound
from railgsa_ros.uncertainty.surrogate import Design

SAFETY = 1 + 1e-6  # margin on the bound for the rounding of the band's sums


class KeptBand:
    """Lower and upper quantiles (``quantiles``) of the samples a review keeps, chunk by chunk
    (the samples in emission order, INVALID ones left out, as the grid gets them)."""

    def __init__(self, design: Design, quantiles: tuple[float, float], limits: Limits,
                 dx_m: float) -> None:
        self.design = design
        self.quantiles = quantiles
        self.limits = limits
        self.dx_m = float(dx_m)
        self._previous = np.nan  # chainage of the last sample of the previous chunk (m)

    def take(self, chainage_m: np.ndarray, u_m: np.ndarray, speed_mps: np.ndarray,
             mean_m: np.ndarray, bank_u_m: np.ndarray, sensor_std_m: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) (K,) m of samples (K,) (bank outputs (P, K), sensor std (K,), PCE
        mean (K,)), NaN where not needed."""
        c = np.concatenate([[self._previous], chainage_m])
        self._previous = float(chainage_m[-1])
        fills = cells_between(c[:-1], c[1:], self.dx_m)[1] > 0  # pair (k - 1, k)
        need = fills.copy()
        need[:-1] |= fills[1:]
        need[-1] = True
        bound = deviation_bound(self.design, bank_u_m, sensor_std_m) * SAFETY
        with np.errstate(invalid='ignore'):
            reach = np.maximum(np.abs(u_m), np.abs(mean_m) + bound)
            need |= np.any(reach[:, None] > self.limits.at(chainage_m, speed_mps), axis=1)
        lower, upper = np.full(c.size - 1, np.nan), np.full(c.size - 1, np.nan)
        lower[need], _, upper[need] = band_statistics(self.design, self.quantiles,
                                                      bank_u_m[:, need], sensor_std_m[need])
        return lower, upper
