"""The vehicle-model interface (``VehicleModel``, ``ModeInfo``) and the delayed sum over the
wheelsets that every model's track response uses (docs/vehicles.md)."""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np

from railgsa_ros.errors import ConfigError


class ModeInfo(NamedTuple):
    """One vibration mode: natural frequency (Hz), damping ratio (-) and what moves."""

    f_hz: float
    zeta: float
    description: str


class VehicleModel(Protocol):
    """What the inversion, band, sensitivities and calibration need of a vehicle."""

    kind: str
    param_names: tuple[str, ...]
    theta: np.ndarray
    units: dict[str, str]
    docs: dict[str, str]
    bounds: dict[str, tuple[float, float]]
    channels: tuple[str, ...]
    wheel_offsets_m: np.ndarray

    def frequency_response(self, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(..., C, W, F) complex at complex frequencies s (F,) rad/s, theta (..., n)."""
        ...

    def track_response(self, theta: np.ndarray, f_hz: np.ndarray,
                       speed_mps: float) -> np.ndarray:
        """(..., C, F): the wheelsets' responses summed with their delays d_w / v."""
        ...

    def state_space(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray]:
        """(A, B, C, D), shapes (..., N, N), (..., N, W), (..., C, N), (..., C, W)."""
        ...

    def modes(self, theta: np.ndarray | None = None) -> list[ModeInfo]:
        """The vibration modes of one parameter set (default: the nominal), by frequency."""
        ...


def delayed_sum(h: np.ndarray, offsets_m: np.ndarray, f_hz: np.ndarray,
                speed_mps: float) -> np.ndarray:
    """sum_w h[..., c, w, f] exp(-2j pi f d_w / v): (..., C, W, F) -> (..., C, F).

    One wheelset at offset 0 returns h[..., 0, :] itself (no multiplication: bit for bit).
    """
    if not (np.isfinite(speed_mps) and speed_mps > 0):
        raise ConfigError(f'speed: must be a positive finite number (m/s), got {speed_mps!r}')
    offsets_m = np.asarray(offsets_m, dtype=float)
    if offsets_m.shape == (1,) and offsets_m[0] == 0:
        return h[..., 0, :]
    phase = np.exp(-2j * np.pi * np.asarray(f_hz, dtype=float)[None, :]
                   * offsets_m[:, None] / speed_mps)  # (W, F)
    return np.einsum('...cwf,wf->...cf', h, phase)
