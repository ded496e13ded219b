"""Ground truth for mounting tests: car-body horizontal motion and a rotated sensor.

The simulator's car body moves vertically only; a tilted sensor mixes the horizontal axes into
its up axis, so the tests and ``benchmarks/bench_mounting.py`` add what a real car body has:
longitudinal acceleration dv/dt (traction, braking), lateral cant deficiency in curves
(quasi-static, held for tens of seconds) and lateral/longitudinal vibration (band-limited
noise). The sensor rotation uses scipy's ``Rotation`` (not the core's own
``input.mounting.rotation``), an independent truth.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfilt
from scipy.spatial.transform import Rotation


def horizontal_motion(t_s: np.ndarray, speed_mps: np.ndarray, seed: int = 0, *,
                      curve: tuple[float, float, float] | None = (10.0, 30.0, 0.6),
                      lateral_rms: float = 0.15, longitudinal_rms: float = 0.05,
                      band_hz: tuple[float, float] = (0.5, 8.0)) -> np.ndarray:
    """Car-body (x forward, y left) specific force (T, 2), m/s^2, at the times t_s (s, uniform):
    x = dv/dt + vibration, y = cant deficiency + vibration; ``curve`` = (start s, duration s,
    deficiency m/s^2) with 5 s transitions (None: straight); vibration: white noise through a
    4th-order Butterworth band-pass ``band_hz`` scaled to the given RMS (m/s^2)."""
    rng = np.random.default_rng(seed)
    fs = 1.0 / float(np.median(np.diff(t_s)))
    sos = butter(4, band_hz, 'bandpass', fs=fs, output='sos')

    def vibration(rms: float) -> np.ndarray:
        v = sosfilt(sos, rng.standard_normal(t_s.size))
        return rms * v / np.std(v)

    x = np.gradient(np.asarray(speed_mps, float), t_s) + vibration(longitudinal_rms)
    y = vibration(lateral_rms)
    if curve is not None:
        start, length, deficiency = curve
        y += deficiency * np.interp(t_s, [start, start + 5, start + length - 5, start + length],
                                    [0.0, 1.0, 1.0, 0.0])
    return np.stack([x, y], axis=1)


def mounted(accel_body: np.ndarray, roll_deg: float, pitch_deg: float) -> np.ndarray:
    """What a sensor rotated by roll (about x) then pitch (about y) relative to the car body
    reads (T, 3): R^T a with R = Rotation.from_euler('xy', [roll, pitch])."""
    r = Rotation.from_euler('xy', [roll_deg, pitch_deg], degrees=True)
    return r.inv().apply(accel_body)
