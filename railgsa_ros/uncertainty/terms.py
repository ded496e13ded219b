"""The band's sensor terms: what the parameter PCE leaves out, one standard deviation per sample.

The parameter band (the PCE over the rule points) assumes the measured acceleration is exact. A
real one is not; each term below is independent of the parameters and of the others, zero-mean
and taken Gaussian, so their variances add (metres of irregularity):

- sensor noise: white accelerometer noise through the inverse and the band at the sample's speed,
  ``inverse.observability`` (sigma_u(v), from the IMU covariance or ``noise_std_mps2``);
- the estimator's own error (a regularised inverse, the coach's LMMSE design): the error std of
  the FIR the nominal pipeline runs, ``pipeline.observability.std_m(v)`` (``inverse/design.py``),
  the posterior of what the sensors could not observe (the nulls) plus their noise through the
  FIR; it replaces the sensor-noise term, which it holds, and with it the band is honest where
  the physics is blind;
- location (the sample's place on the time/chainage axis, from the position fix at the first
  sample on): a time error tau of the stamp shifts the profile, an error du/dt tau, and a
  chainage error xi an error du/dx xi. tau has two independent parts: the residual sensor delay
  N(0, delay_std_s^2), and the IMU clock's rate error (std clock_std_ppm) times the stamp time T
  since the first sample, so std(tau)^2 = delay_std_s^2 + (1e-6 clock_std_ppm T)^2; xi is the
  odometry scale error (std odometry_scale_std) times the distance |c - c_0| from the first
  sample. Std sqrt(du/dt^2 std(tau)^2 + du/dx^2 std(xi)^2) (first order in the shift: valid
  while the shift is far below the shortest band wavelength / 2 pi, about 0.5 m for D1; beyond,
  an over-estimate). du/dt and du/dx are the backward differences of the band mean over the
  stamps and the chainage, T the sum of the forward stamp steps (carried across chunks: the
  same for any chunking; zero across an INVALID sample). No smoothing: the band mean is
  band-passed, its shortest wavelength spans 40 samples at 30 m/s and 400 Hz (15 at 80 m/s), so
  the difference is within 1 % of the derivative and the noise in it is band-limited the same way;
- scale factor: a gain error g ~ N(0, scale_std^2) of the accelerometer scales the profile:
  std scale_std |u|;
- gap filling: the std of the error the model fill of bridged gaps leaves at the sample
  (``Output.gap_std_m``: the fill's posterior covariance through the band FIR,
  ``GapFiller.error_variance``), largest next to a gap and decaying with the distance from it;
- model discrepancy (Kennedy-O'Hagan): the error a reconstruction with the calibrated parameters
  still makes against a surveyed reference beyond all the terms above (unmodelled effects such as
  a sensor noisier than its covariance says), measured by ``railgsa calibrate`` and written
  as ``discrepancy_std_m`` into the uncertainty file: a constant std ``discrepancy_std_m``;
- DEGRADED for another reason (the band design held, noise near the limit): the sample is taken
  to be at least as uncertain as the noisiest VALID one, std max(sigma_u(v), noise_limit_m),
  whichever is larger than the other terms together.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.uncertainty.config import UncertaintyConfig

NoiseStd = Callable[[np.ndarray], np.ndarray]  # speeds (K,) m/s -> sigma_u (K,) m


def bank_terms(config: UncertaintyConfig, pipeline: InversionPipeline,
               noise_std_m: NoiseStd | None) -> SensorTerms:
    """The terms of the band of a bank ``pipeline``: with a regularised inverse (a coach:
    ``pipeline.observability``, the nominal design's) its error std in place of the sensor
    noise ``noise_std_m``, which it holds; else the sensor noise (an exact inverse)."""
    observability = pipeline.observability
    if observability is None:
        return SensorTerms(config, noise_std_m)
    return SensorTerms(config, None, observability.std_m)


class SensorTerms:
    """Streams the per-sample std (m) of the sensor terms (module docstring).

    ``noise_std_m``: sigma_u(v) of the sensor noise (None or config ``sensor_noise`` false: no
    noise term); ``estimator_std_m``: the regularised estimator's error std at the speed (the
    coach: ``observability.std_m``, which holds the noise: then give no ``noise_std_m``; None:
    an exact inverse, no such term; ``bank_terms`` chooses). ``std`` keeps the last emitted
    (stamp, chainage, mean), the first chainage and the stamp time since the first sample for
    the location term.
    """

    def __init__(self, config: UncertaintyConfig, noise_std_m: NoiseStd | None,
                 estimator_std_m: NoiseStd | None = None) -> None:
        self._noise = noise_std_m if config.sensor_noise else None
        self._estimator = estimator_std_m
        self._delay_std_s = config.delay_std_s
        self._clock_rate = 1e-6 * config.clock_std_ppm
        self._odometry_std = config.odometry_scale_std
        self._scale_std = config.scale_std
        self._discrepancy_m = config.discrepancy_std_m
        self._gap_floor_m = config.inversion.noise_limit_m
        self._last: tuple[int, float, float] | None = None  # stamp ns, chainage m, mean m
        self._origin_m = 0.0  # chainage of the first sample (the position fix), m
        self._elapsed_ns = 0  # stamp time of the last sample since the first, ns

    def std(self, stamps_ns: np.ndarray, mean_m: np.ndarray, speed_mps: np.ndarray | None,
            quality: np.ndarray | None, gap_std_m: np.ndarray | None = None,
            chainage_m: np.ndarray | None = None) -> np.ndarray:
        """Std (K,) m of emitted samples: stamps (K,) ns, band mean (K,) m (NaN where
        INVALID), speed (K,) m/s (None or NaN: no noise term), quality (K,) (None: all
        VALID), the gap term (K,) m (None: none) and chainage (K,) m (None: no odometry
        term)."""
        raw = np.asarray(mean_m, dtype=float)
        mean = np.nan_to_num(raw)
        noise, estimator = self._at_speed(self._noise, speed_mps, mean.shape), \
            self._at_speed(self._estimator, speed_mps, mean.shape)
        var = noise ** 2 + estimator ** 2 + (self._scale_std * mean) ** 2 + \
            self._discrepancy_m ** 2
        if mean.size:
            var += self.location_variance(np.asarray(stamps_ns), raw, chainage_m)
        gap = np.zeros(mean.shape) if gap_std_m is None else np.asarray(gap_std_m, float)
        var += gap ** 2
        if quality is not None:  # DEGRADED with no gap term: the floor
            degraded = (np.asarray(quality) == Quality.DEGRADED) & (gap == 0)
            floor = np.maximum(np.maximum(noise, estimator), self._gap_floor_m)
            var = np.where(degraded, np.maximum(var, floor ** 2), var)
        return np.sqrt(var)

    @staticmethod
    def _at_speed(term: NoiseStd | None, speed_mps: np.ndarray | None,
                  shape: tuple[int, ...]) -> np.ndarray:
        """A speed-dependent std (K,) m at the samples' speeds; 0 without the term, the speed
        or where the speed is unknown (NaN: an INVALID sample)."""
        if term is None or speed_mps is None or not shape[0]:
            return np.zeros(shape)
        speed = np.asarray(speed_mps, dtype=float)
        known = np.isfinite(speed)
        return np.where(known, term(np.where(known, speed, 1.0)), 0.0)

    def location_variance(self, stamps_ns: np.ndarray, mean_m: np.ndarray,
                          chainage_m: np.ndarray | None) -> np.ndarray:
        """Variance (K,) m^2 of the location term (module docstring) of samples with stamps
        (K,) ns, band mean (K,) m (NaN where INVALID) and chainage (K,) m (None: no odometry
        part); carries the last sample to the next call."""
        t = stamps_ns.astype(np.int64)
        chain = np.zeros(t.size) if chainage_m is None else np.asarray(chainage_m, float)
        if self._last is None:
            self._last, self._origin_m = (int(t[0]), float(chain[0]), float(mean_m[0])), \
                float(chain[0])
        prev_t, prev_c, prev_u = (np.concatenate([[carried], x[:-1]]) for carried, x in
                                  zip(self._last, (t, chain, mean_m), strict=True))
        steps = t - prev_t
        elapsed_ns = self._elapsed_ns + np.cumsum(np.maximum(steps, 0))
        elapsed_s = elapsed_ns * 1e-9
        du = np.where(np.isfinite(mean_m) & np.isfinite(prev_u), mean_m - prev_u, 0.0)
        rate = np.divide(du, steps * 1e-9, out=np.zeros(t.size), where=steps > 0)
        var = rate ** 2 * (self._delay_std_s ** 2 + (self._clock_rate * elapsed_s) ** 2)
        if self._odometry_std > 0 and chainage_m is not None:
            dc = chain - prev_c
            slope = np.divide(du, dc, out=np.zeros(t.size), where=dc != 0)
            var += (slope * self._odometry_std * (chain - self._origin_m)) ** 2
        self._last = (int(t[-1]), float(chain[-1]), float(mean_m[-1]))
        self._elapsed_ns = int(elapsed_ns[-1])
        return var
