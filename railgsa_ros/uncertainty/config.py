"""Parameters of the uncertainty stream (no ROS import): rule, band quantiles, windows, QoIs.

The same names are the ROS parameters of ``uncertainty_node`` (``config/uncertainty_node.yaml``),
next to every ``InversionConfig`` name (the inversion must match ``irregularity_node``'s). Each
field's metadata gives its description, inclusive numeric bounds or string choices, from which
the node declares its descriptors.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from railgsa_ros.config import check_field, key_list, load_yaml, ros_parameters
from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.uq.germ import AUTO, GERMS
from railgsa_ros.uq.rules import RULES

NODE_NAME = 'uncertainty_node'
QOIS = ('peak', 'rms')
WINDOW_UNITS = ('s', 'm')


def _p(default: Any, doc: str, bounds: tuple[float, float] | None = None,
       choices: tuple[str, ...] = ()) -> Any:
    return field(default=default, metadata={'doc': doc, 'bounds': bounds, 'choices': choices})


@dataclass(frozen=True)
class UncertaintyConfig:
    """Validated parameters of :class:`~railgsa_ros.uncertainty.stream.UncertaintyStream`."""

    rule: str = _p('pem5', 'rule points (inverse filters): pem5 (2n^2+1), pem3, gauss, lstsq',
                   choices=RULES)
    order: int = _p(2, 'total PCE order; pem5 projects exactly up to 2, pem3 up to 1', (1, 4))
    rule_size: int = _p(0, 'lstsq: number of points (0 = twice the PCE terms)', (0, 4096))
    germ: str = _p(AUTO, 'PCE germ: auto (legendre if every input is uniform and the rule is '
                         'not PEM, else hermite), hermite or legendre', choices=(AUTO, *GERMS))
    lower_quantile: float = _p(0.025, 'band lower quantile (probability)', (1e-4, 0.5))
    upper_quantile: float = _p(0.975, 'band upper quantile (probability)', (0.5, 1.0 - 1e-4))
    germ_samples: int = _p(1024, 'quasi-random germ points for the band quantiles', (16, 65536))
    seed: int = _p(0, 'seed of the quasi-random germ points', (0, 2**31 - 1))
    window_length: float = _p(5.0, 'sensitivity window length, in window_unit', (1e-3, 1e6))
    window_unit: str = _p('s', 'sensitivity window unit: s (stamps) or m (chainage)',
                          choices=WINDOW_UNITS)
    qoi: str = _p('peak,rms', "window quantities of interest, comma-separated: peak (u at the "
                              "largest |mean|), rms; '' = no sensitivity windows")
    n_mc: int = _p(20000, 'surrogate Monte Carlo samples per delta estimate', (256, 10**7))
    sensor_noise: bool = _p(True, 'add the sensor noise propagated through the inverse and the '
                                  'band (from the IMU covariance or noise_std_mps2) to the band')
    delay_std_s: float = _p(5e-4, 'standard uncertainty of the sensor delay after compensation, '
                                  's: adds |du/dt| * delay_std_s to the band', (0.0, 1.0))
    scale_std: float = _p(2e-3, 'standard uncertainty of the accelerometer scale factor '
                                '(relative): adds scale_std * |u| to the band', (0.0, 1.0))
    clock_std_ppm: float = _p(0.0, 'standard uncertainty of the IMU stamp clock rate, ppm, '
                                   'when the stamps come from the sensor\'s own free-running '
                                   'clock (bmi088 preset 50, adxl355 20; 0: host-stamped, '
                                   'as ROS drivers do): the stamps\' time error '
                                   'grows as clock_std_ppm 1e-6 x the time since the first '
                                   'sample; adds |du/dt| x that to the band', (0.0, 1e5))
    odometry_scale_std: float = _p(0.0, 'standard uncertainty of the odometry scale (relative; '
                                        'an uncorrected wheel diameter: tenths of a percent; 0: '
                                        'chainage exact or corrected): the chainage error grows '
                                        'as odometry_scale_std x the distance from the first '
                                        'sample; adds |du/dx| x that to the band', (0.0, 0.1))
    discrepancy_std_m: float = _p(0.0, 'model-discrepancy std, m (what calibrate measured beyond '
                                       'the other terms; the uncertainty file\'s '
                                       'discrepancy_std_m if larger): added in variance',
                                  (0.0, 1.0))
    inversion: InversionConfig = field(default_factory=InversionConfig)

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name != 'inversion':
                value = check_field(f.name, getattr(self, f.name), f.default, f.metadata)
                object.__setattr__(self, f.name, value)
        unknown = sorted(set(self.qois) - set(QOIS))
        if unknown:
            raise ConfigError(f'qoi: unknown quantity {unknown[0]!r}; expected any of '
                              f'{", ".join(QOIS)}')
        if not self.lower_quantile < self.upper_quantile:
            raise ConfigError('lower_quantile/upper_quantile: need lower < upper')

    @property
    def qois(self) -> tuple[str, ...]:
        """The quantities of interest in configured order."""
        return tuple(q.strip() for q in self.qoi.split(',') if q.strip())

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = 'parameters'
                     ) -> UncertaintyConfig:
        """Defaults overridden by ``data`` (uncertainty and inversion names together)."""
        own = {f.name for f in fields(cls)} - {'inversion'}
        inv = {f.name for f in fields(InversionConfig)}
        unknown = set(data) - own - inv
        if unknown:
            raise ConfigError(f'{source}: unknown parameter(s) {key_list(unknown)}')
        inversion = InversionConfig.from_mapping({k: v for k, v in data.items() if k in inv},
                                                 source)
        try:
            return cls(**{k: v for k, v in data.items() if k in own}, inversion=inversion)
        except ConfigError as exc:
            raise ConfigError(f'{source}: {exc}') from None

    def with_(self, **changes: Any) -> UncertaintyConfig:
        """A validated copy with some fields changed."""
        return replace(self, **changes)


def load_config(path: str | Path) -> UncertaintyConfig:
    """Read ``uncertainty_node: ros__parameters:`` of a params file (node-only keys such as
    ``vehicle_file`` are ignored here)."""
    params = ros_parameters(load_yaml(path), NODE_NAME, source=str(path))
    keep = {f.name for f in fields(UncertaintyConfig)} | {f.name for f in
                                                          fields(InversionConfig)}
    return UncertaintyConfig.from_mapping({k: v for k, v in params.items() if k in keep},
                                          source=str(path))
