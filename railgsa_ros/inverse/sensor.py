"""The group delay of an IMU's digital low-pass filter, to be compensated by the inversion.

A MEMS accelerometer filters and decimates on the chip with a causal filter: the sample stamped
t measured the acceleration around t - tau, tau the filter's group delay (a few ms: 0.1 m of
track at 20 m/s). ``imu.antialias_fir`` is the simulated chip's linear-phase filter; as a causal
filter its group delay is (N - 1) / 2 taps at every frequency. ``group_delay_s`` evaluates it
in a frequency band with ``scipy.signal.group_delay`` (so an IIR or minimum-phase filter given
as (b, a) works too); the pipeline advances the signal by ``sensor_delay_s`` (see
``pipeline.InversionPipeline._response``).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from railgsa_ros.imu import ImuSpec, antialias_fir, imu_spec

FILTER_OVERSAMPLING = 4  # the chip filter is evaluated at this multiple of the output rate
BAND_POINTS = 64  # frequencies averaged over the band


def group_delay_s(b: np.ndarray, a: np.ndarray | float, rate_hz: float,
                  band_hz: tuple[float, float]) -> float:
    """Mean group delay (s) over band_hz (Hz) of the causal filter (b, a) run at rate_hz."""
    f = np.linspace(max(band_hz[0], 1e-6), band_hz[1], BAND_POINTS)
    _, gd = signal.group_delay((b, a), w=f, fs=rate_hz)
    return float(np.mean(gd)) / rate_hz


def sensor_delay_s(spec: ImuSpec | str, band_hz: tuple[float, float] = (0.1, 50.0)) -> float:
    """Group delay (s) of the chip filter of an IMU spec or preset name, over band_hz (Hz: the
    default covers D1-D3 at 10-70 m/s)."""
    spec = imu_spec(spec) if isinstance(spec, str) else spec
    rate = FILTER_OVERSAMPLING * spec.output_rate_hz
    return group_delay_s(antialias_fir(spec, rate), 1.0, rate, band_hz)
