"""Inversion pipeline parameters: defaults, units, ranges and validation (no ROS import).

The same names are the ROS parameters of ``irregularity_node`` (``config/irregularity.yaml``);
each field's metadata gives its description, inclusive numeric bounds or string choices so that
the node can declare descriptors from it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
import math
from pathlib import Path
from typing import Any

from railgsa_ros.config import check_field, key_list, load_yaml, ros_parameters
from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.band import band_limits
from railgsa_ros.inverse.feedback import UNSUPPORTED, check_gain

NODE_NAME = 'irregularity_node'
METHODS = ('spectral', 'feedback', 'kalman')
AXES = ('z', '-z', 'x', '-x', 'y', '-y')
MOUNTINGS = ('estimate', 'axis', 'rotation')
INF = math.inf


def _p(default: Any, doc: str, bounds: tuple[float, float] | None = None,
       choices: tuple[str, ...] = ()) -> Any:
    return field(default=default, metadata={'doc': doc, 'bounds': bounds, 'choices': choices})


@dataclass(frozen=True)
class InversionConfig:
    """Validated pipeline parameters (SI units); see docs/inversion.md for the full table."""

    method: str = _p('spectral', 'inversion method', choices=METHODS)
    band: str = _p('d1', 'wavelength band: d1 3-25 m, d2 25-70 m, d3 70-200 m (EN 13848), wide '
                         '1-200 m, LMIN:LMAX in m, none (paper mode)')
    gain: float = _p(1000.0, 'feedback gain K^c of Eq. 7, s^2 (m of u per m/s^2), > 0', (0.0, INF))
    band_order: int = _p(2, 'Butterworth band-pass prototype order n (run forward-backward)',
                         (1, 8))
    fir_tolerance: float = _p(1e-5, 'band FIR cut where the impulse response L1 tail < this',
                              (1e-9, 1e-2))
    rate_hz: float = _p(1000.0, 'nominal IMU sample rate, Hz', (1.0, 1e5))
    speed_mps: float = _p(20.0, 'speed of every sample when use_odom is false (offline: '
                                '--speed), m/s', (0.0, 200.0))
    min_design_speed_mps: float = _p(10.0, 'band held at this speed below it; sets delay, m/s',
                                     (0.5, 200.0))
    max_speed_mps: float = _p(70.0, 'band held at this speed above it; sets the multirate '
                                    'decimation R, m/s', (0.5, 200.0))
    multirate: bool = _p(True, 'run the band FIR at fs / R (anti-alias decimation, polyphase '
                               'interpolation); single rate when false or R < 2')
    speed_tolerance: float = _p(0.005, 'relative speed change that triggers a filter redesign',
                                (1e-4, 1.0))
    window_speed_tolerance: float = _p(0.05, 'an output is DEGRADED where the speed across its '
                                             'band window differs from its band design by more '
                                             'than this fraction (acceleration, braking)',
                                       (1e-3, 10.0))
    sensor_delay_s: float = _p(0.0, 'group delay of the IMU digital low-pass filter, s: the '
                                     'signal is advanced by it (inverse.sensor.sensor_delay_s '
                                     'gives it for a preset)', (0.0, 1.0))
    accel_axis: str = _p('z', 'IMU axis (with sign) pointing up in the car body', choices=AXES)
    gravity_mps2: float = _p(9.80665, 'gravity subtracted from the vertical axis, m/s^2',
                             (0.0, 20.0))
    mounting: str = _p('estimate', 'vertical: estimate (accel_axis while gravity is within '
                                   'tilt_tolerance_deg of it, else the estimated gravity '
                                   'direction), axis (accel_axis as is), rotation (accel_axis '
                                   'turned by mount_roll_deg, mount_pitch_deg)', choices=MOUNTINGS)
    mount_roll_deg: float = _p(0.0, 'mounting rotation: roll of the sensor about its x axis, '
                                    'deg', (-180.0, 180.0))
    mount_pitch_deg: float = _p(0.0, 'mounting rotation: pitch of the sensor about its y axis '
                                     '(after the roll), deg', (-90.0, 90.0))
    tilt_tolerance_deg: float = _p(2.0, 'estimated gravity further than this from the axis in '
                                        'use: outputs DEGRADED (estimate: projected on it), deg',
                                   (0.0, 90.0))
    max_tilt_deg: float = _p(40.0, 'mounting estimate: tilt from accel_axis beyond which '
                                   'outputs are DEGRADED, deg', (0.0, 90.0))
    remove_bias: bool = _p(False, 'subtract the running mean of the acceleration since the '
                                  '(re)start, an estimate of a constant bias')
    taper_s: float = _p(0.5, 'raised-cosine fade-in after a (re)start and fade-out at flush, s',
                        (0.0, 60.0))
    noise_std_mps2: float = _p(5e-3, 'kalman: accel noise std when the IMU covariance is '
                                     'absent or unknown, m/s^2', (1e-9, 10.0))
    gyro_noise_std_rads: float = _p(5.5e-3, 'coach with pitch rate: gyro noise std at rate_hz, '
                                           'rad/s (5.5e-3: 0.014 deg/s/sqrt(Hz) at 1 kHz)',
                                    (1e-9, 10.0))
    track_spectrum_av: float = _p(4.032e-7, 'kalman: German spectrum amplitude A_v, m rad '
                                            '(4.032e-7 low, 1.080e-6 high)', (1e-12, 1e-3))
    bias_walk_mps2: float = _p(1e-6, 'kalman: accelerometer bias random walk, '
                                     '(m/s^2)/sqrt(s)', (0.0, 1.0))
    smoother: bool = _p(False, 'kalman: offline RTS smoother (outputs at flush)')
    gap_factor: float = _p(3.0, 'a step above this many nominal periods is a gap', (1.0, 1e6))
    gap_policy: str = _p('bridge', 'gap handling', choices=('reset', 'bridge'))
    max_bridge_s: float = _p(1.2, 'bridge policy: longest gap filled by the model (gapfill), '
                                  's', (0.0, 10.0))
    gap_hold_s: float = _p(0.5, 'bridge policy: samples after a gap that condition its fill '
                                '(outputs after a gap wait as long), s', (0.0, 10.0))
    saturation_mps2: float = _p(19.6133, 'accelerometer range, m/s^2 (0 = no check; '
                                                  'ADXL355 +-2 g)',
                                (0.0, 1e4))
    saturation_margin_mps2: float = _p(0.01, 'samples within this of the range are saturated',
                                       (0.0, 1e3))
    frame_id: str = _p('imu_link', "expected IMU frame_id ('' accepts any)")
    noise_limit_m: float = _p(1e-4, 'sensor noise propagated into the band above which an '
                                    'output is INVALID (DEGRADED above half of it), m',
                              (1e-9, 1.0))
    rate_tolerance: float = _p(0.02, 'relative difference of the measured IMU rate from '
                                     'rate_hz beyond which outputs are INVALID', (1e-4, 1.0))

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            object.__setattr__(self, f.name, _check(f.name, value, f.default, f.metadata))
        if self.band != 'none':
            band_limits(self.band)
        if self.method == 'spectral' and self.band == 'none':
            raise ConfigError('band: the spectral method needs a band (d1, d2, ...): the exact '
                              'inverse has a double pole at s = 0')
        if self.method == 'spectral' and self.band_order < 2:
            raise ConfigError('band_order: the spectral method needs 2 or more: |BP|^2 / G falls '
                              'only as 1/f with order 1 (1/G grows as f), so no FIR fits it')
        if self.max_speed_mps < self.min_design_speed_mps:
            raise ConfigError(f'max_speed_mps: {self.max_speed_mps:g} is below '
                              f'min_design_speed_mps ({self.min_design_speed_mps:g})')
        if self.smoother and self.method != 'kalman':
            raise ConfigError('smoother: the RTS smoother belongs to the kalman method')

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = 'parameters'
                     ) -> InversionConfig:
        """Defaults overridden by ``data``; unknown names are a ConfigError naming ``source``."""
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ConfigError(f'{source}: unknown parameter(s) {key_list(unknown)}')
        try:
            return cls(**dict(data))
        except ConfigError as exc:
            raise ConfigError(f'{source}: {exc}') from None

    def with_(self, **changes: Any) -> InversionConfig:
        """A validated copy with some fields changed."""
        return replace(self, **changes)


def _check(name: str, value: Any, default: Any, meta: Mapping[str, Any]) -> Any:
    """``config.check_field`` plus the refused methods and the gain's stability check."""
    if name == 'method' and value in ('analytical', 'flatness'):
        raise ConfigError(f'method: {UNSUPPORTED[value]}')
    number = check_field(name, value, default, meta)
    return check_gain(number) if name == 'gain' else number


def load_config(path: str | Path) -> InversionConfig:
    """Read ``irregularity_node: ros__parameters:`` of a params file; other keys are ignored."""
    params = ros_parameters(load_yaml(path), NODE_NAME, source=str(path))
    keep = {f.name for f in fields(InversionConfig)}
    return InversionConfig.from_mapping({k: v for k, v in params.items() if k in keep},
                                        source=str(path))
