"""The band's sensor terms: what the parameter PCE leaves out, one standard deviation per sample.

The parameter band (the PCE over the rule points) assumes the measured acceleration is exact. A
real one is not; each term below is independent of the parameters and of the others, zero-mean
and taken Gaussian, so their variances add (metres of irregularity):

- sensor noise: white accelerometer noise through the inverse and the band at the sample's speed,
  ``inverse.observability`` (sigma_u(v), from the IMU covariance or ``noise_std_mps2``);
- sensor delay: a residual delay error tau ~ N(0, delay_std_s^2) shifts the profile in time, an
  error du/dt * tau: std |du/dt| delay_std_s, du/dt the backward difference of the band mean
  over the stamps (carried across chunks: the same for any chunking);
- scale factor: a gain error g ~ N(0, scale_std^2) of the accelerometer scales the profile:
  std scale_std |u|;
- gap filling: the std of the error the model fill of bridged gaps leaves at the sample
  (``Output.gap_std_m``: the fill's posterior covariance through the band FIR,
  ``GapFiller.error_variance``), largest next to a gap and decaying with the distance from it;
- model discrepancy (Kennedy-O'Hagan): the error a reconstruction with the calibrated parameters
  still makes against a surveyed reference beyond all the terms above (unmodelled effects such as
  the chainage shift of a drifting sensor clock), measured by ``railgsa calibrate`` and written
  as ``discrepancy_std_m`` into the uncertainty file: a constant std ``discrepancy_std_m``;
- DEGRADED for another reason (the band design held, noise near the limit): the sample is taken
  to be at least as uncertain as the noisiest VALID one, std max(sigma_u(v), noise_limit_m),
  whichever is larger than the other terms together.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from railgsa_ros.inverse.quality import Quality
from railgsa_ros.uncertainty.config import UncertaintyConfig

NoiseStd = Callable[[np.ndarray], np.ndarray]  # speeds (K,) m/s -> sigma_u (K,) m


class SensorTerms:
    """Streams the per-sample std (m) of the sensor terms (module docstring).

    ``noise_std_m``: sigma_u(v) of the sensor noise (None or config ``sensor_noise`` false: no
    noise term). ``std`` keeps the last emitted (stamp, mean) for the delay term's difference.
    """

    def __init__(self, config: UncertaintyConfig, noise_std_m: NoiseStd | None) -> None:
        self._noise = noise_std_m if config.sensor_noise else None
        self._delay_std_s = config.delay_std_s
        self._scale_std = config.scale_std
        self._discrepancy_m = config.discrepancy_std_m
        self._gap_floor_m = config.inversion.noise_limit_m
        self._last: tuple[int, float] | None = None

    def std(self, stamps_ns: np.ndarray, mean_m: np.ndarray, speed_mps: np.ndarray | None,
            quality: np.ndarray | None, gap_std_m: np.ndarray | None = None) -> np.ndarray:
        """Std (K,) m of emitted samples: stamps (K,) ns, band mean (K,) m (NaN where
        INVALID), speed (K,) m/s (None or NaN: no noise term), quality (K,) (None: all
        VALID) and the gap term (K,) m (None: none)."""
        mean = np.nan_to_num(np.asarray(mean_m, dtype=float))
        noise = np.zeros(mean.shape)
        if self._noise is not None and speed_mps is not None and mean.size:
            speed = np.asarray(speed_mps, dtype=float)
            known = np.isfinite(speed)  # unknown speed: an INVALID sample, no noise term
            noise = np.where(known, self._noise(np.where(known, speed, 1.0)), 0.0)
        var = noise ** 2 + (self._scale_std * mean) ** 2 + self._discrepancy_m ** 2
        if self._delay_std_s > 0 and mean.size:
            var += (self._delay_std_s * self._rate(np.asarray(stamps_ns), mean)) ** 2
        gap = np.zeros(mean.shape) if gap_std_m is None else np.asarray(gap_std_m, float)
        var += gap ** 2
        if quality is not None:  # DEGRADED with no gap term: the floor
            degraded = (np.asarray(quality) == Quality.DEGRADED) & (gap == 0)
            floor = np.maximum(noise, self._gap_floor_m)
            var = np.where(degraded, np.maximum(var, floor ** 2), var)
        if mean.size:
            self._last = (int(stamps_ns[-1]), float(mean[-1]))
        return np.sqrt(var)

    def _rate(self, stamps_ns: np.ndarray, mean: np.ndarray) -> np.ndarray:
        """du/dt (K,) m/s by backward difference, the first sample against the carried one."""
        t = stamps_ns.astype(np.int64)
        prev_t = np.concatenate([[self._last[0] if self._last else t[0]], t[:-1]])
        prev_u = np.concatenate([[self._last[1] if self._last else mean[0]], mean[:-1]])
        dt = (t - prev_t) * 1e-9
        return np.divide(mean - prev_u, dt, out=np.zeros(mean.shape), where=dt > 0)

    def reset(self) -> None:
        """Forget the carried sample (a restart of the stream)."""
        self._last = None

