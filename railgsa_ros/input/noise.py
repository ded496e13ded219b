"""The noise decision: the accelerometer noise, its floor in the band, and the speed grades.

The noise is the median of the configured axis' reported variance over the first NOISE_SAMPLES
IMU samples (absent or unknown ones skipped), else ``noise_std_mps2``^2, or a variance given
up front; it designs the Kalman method and the sensor noise floor
(``inverse.observability.NoiseFloor``), whose speed limits grade each sample: INVALID without a
speed or below the speed where the noise fills ``noise_limit_m``, DEGRADED below the one where
it fills half of it and outside [min_design_speed_mps, max_speed_mps]. A coach's floor is its
pipeline's ``observability.std_m``, the error std of the band output; it is not graded against
``noise_limit_m``: that error is mostly the band's part that no car-body signal observes at any
speed (twice the wheelbase: 0.1-0.12 mm for the shipped coach in D1, with an MEMS gyro and
accelerometer), not noise, and would make every output INVALID. The coach's pipeline grades
its outputs itself (DEGRADED where the unobserved fraction is large or outside the design
speeds); the stage adds INVALID without a speed or at standstill.
The gyro variance (a coach's pitch rate) is the median of the first NOISE_SAMPLES messages'
reported angular_velocity_covariance[4] (None without: ``gyro_noise_std_rads``).
"""

from __future__ import annotations

import numpy as np

from railgsa_ros.input.findings import OK, Findings
from railgsa_ros.input.sanitize import SMALL
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.design import Observability
from railgsa_ros.inverse.observability import STANDSTILL_MPS, NoiseFloor
from railgsa_ros.inverse.quality import Quality

NOISE_SAMPLES = 64  #: IMU samples whose reported variances decide the noise
AXES = 'xyz'
_VALID, _DEGRADED, _INVALID = int(Quality.VALID), int(Quality.DEGRADED), int(Quality.INVALID)


class Noise:
    """The noise decision (``variance`` (m/s^2)^2 and its ``source`` once decided; given up
    front when ``variance`` is not None) and its ``floor`` with the speed limits ``v_invalid``
    and ``v_degraded`` (m/s) once designed."""

    def __init__(self, variance: float | None = None) -> None:
        self.given = variance is not None
        self.variance = variance
        self.source = 'given' if variance is not None else ''
        self.floor: NoiseFloor | CoachFloor | None = None
        self.v_invalid = self.v_degraded = np.nan
        self._reported: list[float] = []  # variances of the first NOISE_SAMPLES samples
        self._gyro: list[float] = []  # gyro (y axis) variances of the first NOISE_SAMPLES

    @property
    def gyro_variance(self) -> float | None:
        """Median reported pitch-rate variance (rad/s)^2, None when none was reported."""
        return float(np.median(self._gyro)) if self._gyro else None

    def note_gyro(self, cov: np.ndarray, absent: np.ndarray, received: int) -> None:
        """Keep the y axis' reported variances (REP 145 angular_velocity_covariance (T, 9) of
        the samples after the first ``received``) of the first NOISE_SAMPLES samples."""
        room = NOISE_SAMPLES - received
        if room > 0:
            var = cov[:room, 4]
            self._gyro.extend(var[~absent[:room] & np.isfinite(var) & (var > 0)].tolist())

    def note(self, config: InversionConfig, cov: np.ndarray, absent: np.ndarray,
             received: int) -> None:
        """Keep the configured axis' variances of the first NOISE_SAMPLES samples (REP 145
        covariances (T, 9) of the samples after the first ``received``)."""
        room = NOISE_SAMPLES - received
        if room <= 0 or self.given:
            return
        col = 4 * AXES.index(config.accel_axis[-1])
        head = cov[:room]
        var = head[:, col]
        known = ~absent[:room] & np.any(head != 0, axis=1) & np.isfinite(var) & (var > 0)
        self._reported.extend(var[known].tolist())

    def decide(self, config: InversionConfig) -> None:
        """Decide the noise from the variances noted so far, else noise_std_mps2 (a
        variance given up front stays)."""
        if self.given:
            return
        if self._reported:
            self.variance = float(np.median(self._reported))
            self.source = f'median of {len(self._reported)} IMU-reported variances'
        else:
            self.variance = config.noise_std_mps2 ** 2
            self.source = 'noise_std_mps2: the IMU reports no covariance'

    def design(self, config: InversionConfig, theta: np.ndarray, findings: Findings,
               observability: Observability | None = None) -> None:
        """The noise floor of the nominal vehicle ``theta`` (5,) in the band (a coach's:
        its pipeline's ``observability``), its speed limits and the 'noise' finding."""
        variance = self.variance
        assert variance is not None  # called once the noise is decided
        if observability is not None:
            self.floor = CoachFloor(observability)
            self.v_invalid = self.v_degraded = STANDSTILL_MPS
            low, high = config.min_design_speed_mps, config.max_speed_mps
            error_mm = 1e3 * observability.std_m(np.array([low, high]))
            findings.set('noise', OK, (
                f'sensor noise {np.sqrt(variance):.3g} m/s^2 ({self.source}): the coach\'s '
                f'band error is {error_mm[0]:.3g} mm at {low:g} m/s, {error_mm[1]:.3g} mm at '
                f'{high:g} m/s'))
            return
        self.floor = NoiseFloor(theta, config.band, config.band_order, config.rate_hz, variance)
        self.v_invalid = self.floor.speed_for(config.noise_limit_m)
        self.v_degraded = max(self.floor.speed_for(config.noise_limit_m / 2), self.v_invalid)
        findings.set('noise', OK, (
            f'sensor noise {np.sqrt(variance):.3g} m/s^2 ({self.source}): the '
            f'band is unobservable below {self.v_invalid:.3g} m/s, degraded below '
            f'{max(self.v_degraded, config.min_design_speed_mps):.3g} m/s'))

    def sigma_m(self, speeds_mps: np.ndarray) -> np.ndarray:
        """Sensor noise propagated into the band, sigma_u (m), at the given speeds (m/s)."""
        if self.floor is None:
            return np.full(np.shape(speeds_mps), np.nan)
        return self.floor.sigma_m(speeds_mps)

    def speed_quality(self, config: InversionConfig, speed: np.ndarray, known: np.ndarray
                      ) -> np.ndarray:
        """Quality codes (N,) of samples at these speeds (m/s; ``known`` False: no speed)."""
        v_deg, v_min, v_max = self.v_degraded, config.min_design_speed_mps, config.max_speed_mps
        if speed.size <= SMALL:  # the same comparisons per sample
            return np.array([max(_INVALID if not k or v < self.v_invalid else _VALID,
                                 _DEGRADED if v < v_deg or v < v_min or v > v_max else _VALID)
                             for v, k in zip(np.abs(speed).tolist(), known.tolist(),
                                             strict=True)], np.uint8)
        v = np.abs(speed)
        q = np.where(~known | (v < self.v_invalid), _INVALID, _VALID)
        slow = (v < v_deg) | (v < v_min) | (v > v_max)
        return np.maximum(q, np.where(slow, _DEGRADED, _VALID)).astype(np.uint8)


class CoachFloor:
    """A coach's floor: the error std (m) of its band output (``Observability.std_m``)."""

    def __init__(self, observability: Observability) -> None:
        self.observability = observability

    def sigma_m(self, speeds_mps: np.ndarray) -> np.ndarray:
        """Error std (m) of the band output at |speed| (m/s; held at the table's ends)."""
        return self.observability.std_m(speeds_mps)
