"""The input options that are not inversion parameters (the nodes' parameters of these names)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from railgsa_ros.errors import ConfigError
from railgsa_ros.input.sanitize import SMALL
from railgsa_ros.inverse.config import InversionConfig

#: default re-order window, s: a recorder's receipt jitter and a driver's bursts are a few ms
REORDER_WINDOW_S = 0.05
REORDER_CAP = 4  #: the re-order buffer holds at most this many windows of samples at rate_hz


@dataclass(frozen=True)
class InputOptions:
    """Input options that are not inversion parameters (the nodes' parameters of these names).

    use_odom: speed from odometry (false: ``speed_mps`` for every sample); odom_timeout_s (s):
    odometry older than this is missing; wrong_frame_policy: 'accept' (default: a driver's own
    frame_id is used, with a WARN finding) or 'reject' (strict: such samples are rejected);
    stuck_s (s, 0 = off) and backward_reset_s (s): see ``InputSanitizer``; reorder_window_s
    (s, 0 = off): IMU samples are re-ordered by header stamp within this window before any
    other decision (``input.reorder``; it adds this much latency).
    """

    use_odom: bool = True
    odom_timeout_s: float = 1.0
    wrong_frame_policy: str = 'accept'
    stuck_s: float = 0.5
    backward_reset_s: float = 1.0
    reorder_window_s: float = REORDER_WINDOW_S

    def __post_init__(self) -> None:
        if self.wrong_frame_policy not in ('accept', 'reject'):
            raise ConfigError(f'wrong_frame_policy: expected accept or reject, got '
                              f'{self.wrong_frame_policy!r}')
        for name in ('odom_timeout_s', 'backward_reset_s'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f'{name}: expected a positive number of s, got {value!r}')
        if not (np.isfinite(self.stuck_s) and self.stuck_s >= 0):
            raise ConfigError(f'stuck_s: expected >= 0 s, got {self.stuck_s!r}')
        if not (0 <= self.reorder_window_s < self.backward_reset_s):
            raise ConfigError(f'reorder_window_s: expected >= 0 s and below backward_reset_s '
                              f'({self.backward_reset_s:g} s), got {self.reorder_window_s!r}')

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> InputOptions:
        """The options found in ``values`` (e.g. a node's parameters); other keys ignored."""
        return cls(**{f.name: values[f.name] for f in fields(cls) if f.name in values})

    def reorder_limits(self, rate_hz: float) -> tuple[float, float, int]:
        """The re-order buffer's window (s), backward jump (s) and cap (samples) at rate_hz."""
        cap = max(SMALL, int(np.ceil(REORDER_CAP * self.reorder_window_s * rate_hz)))
        return self.reorder_window_s, self.backward_reset_s, cap

    def check_speed(self, config: InversionConfig) -> None:
        """ConfigError unless the speed is known: from odometry, or a positive speed_mps."""
        if self.use_odom is False and config.speed_mps <= 0:
            raise ConfigError('speed_mps: use_odom is false, so speed_mps is the speed of every '
                              'sample and must be > 0')
