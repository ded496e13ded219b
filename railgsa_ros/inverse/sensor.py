"""The group delay of an IMU's digital low-pass filter, to be compensated by the inversion.

A MEMS accelerometer filters and decimates on the chip with a causal filter: the sample stamped
t measured the acceleration around t - tau, tau the filter's group delay (a few ms: 0.1 m of
track at 20 m/s). A preset at a datasheet setting (``adxl355@1000Hz``, ``bmi088@400Hz``:
``datasheets``) models the chip's filter as ``imu.chip_filter``, a Butterworth at the
datasheet's -3 dB cut-off, and the simulator runs that filter: the preset's delay and the
simulated bag's come from the same datasheet figure, not from each other. The delay-free models
(``adxl355``, ``bmi088``, ``ideal``) have none. ``group_delay_s`` evaluates a filter's delay in
a frequency band with ``scipy.signal.group_delay``; the pipeline advances the signal by
``sensor_delay_s`` (see ``pipeline.InversionPipeline._response``).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from railgsa_ros.imu import ImuSpec, chip_filter, imu_spec

RATE_PER_CUTOFF = 100  # the chip filter is evaluated at this multiple of its cut-off: the
# datasheet's analog figure (the simulator's rate, 2 kHz and more, is within 2 % of it)
BAND_POINTS = 64  # frequencies averaged over the band
LOW_BAND_HZ = (0.1, 25.0)  # D1 at up to 300 km/h (83 m/s / 3 m = 28 Hz), D2 and D3 below


def group_delay_s(b: np.ndarray, a: np.ndarray | float, rate_hz: float,
                  band_hz: tuple[float, float]) -> float:
    """Mean group delay (s) over band_hz (Hz) of the causal filter (b, a) run at rate_hz."""
    f = np.linspace(max(band_hz[0], 1e-6), band_hz[1], BAND_POINTS)
    _, gd = signal.group_delay((b, a), w=f, fs=rate_hz)
    return float(np.mean(gd)) / rate_hz


def sensor_delay_s(spec: ImuSpec | str, band_hz: tuple[float, float] = LOW_BAND_HZ) -> float:
    """Group delay (s) of the chip filter of an IMU spec or preset name (a datasheet setting
    ``chip@ODRHz[-mode]`` included) over band_hz (Hz), at most a quarter of its cut-off; 0
    for a spec without one."""
    spec = imu_spec(spec) if isinstance(spec, str) else spec
    rate = RATE_PER_CUTOFF * spec.chip_cutoff_hz
    sos = chip_filter(spec, rate) if rate else None
    if sos is None:
        return 0.0
    b, a = signal.sos2tf(sos)
    low = (band_hz[0], min(band_hz[1], spec.chip_cutoff_hz / 4))
    return group_delay_s(b, a, rate, low)
