"""Output-data-rate and low-pass settings of the accelerometer chips, from their datasheets.

A chip filters and decimates on the die: the sample stamped t holds the acceleration around
t - tau, tau the group delay of the chip's digital low-pass. A datasheet gives the filter's
-3 dB cut-off for each output data rate (ODR) and bandwidth setting; a setting is named
``chip@ODR`` (``adxl355@1000Hz``) or ``chip@ODR-mode`` (``bmi088@400Hz-osr2``).

- Analog Devices ADXL355: the low-pass corner is ODR / 4 at every ODR, 4000 Hz down to
  3.906 Hz (datasheet, register FILTER (0x28) ODR_LPF; reproduced in the adxl355 Rust crate's
  ``conf.rs`` and the Zephyr ADXL355 bindings).
- Bosch BMI088 accelerometer: ACC_CONF acc_bwp normal, OSR2 or OSR4 for ODR 12.5-1600 Hz,
  -3 dB cut-offs of the table below (datasheet section 4.4.1, as reproduced in the
  bolderflight bmi088-arduino README: normal mode 145 Hz at 400 Hz, 80 Hz at 200 Hz, ...).

Neither datasheet found here gives the filter's order or type, so the delay it implies rests on
a model: ``imu.ImuSpec.chip_order`` poles of a Butterworth low-pass at the cut-off (4 by
default: tau = 2.613 / (2 pi fc) at low frequency, 5.2 ms at 80 Hz), tagged [M] in the docs.
The ADXL355 datasheet's own group-delay figures were not reachable from this project's sources;
its delay is the same model's.
"""

from __future__ import annotations

import re

from railgsa_ros.errors import ConfigError

ADXL355_ODRS_HZ = tuple(4000.0 / 2 ** k for k in range(11))  # 4000 ... 3.906 Hz
ADXL355_CORNER = 0.25  # low-pass corner / ODR

# BMI088 accelerometer: ODR Hz -> -3 dB cut-off Hz for acc_bwp normal, OSR2, OSR4
BMI088_CUTOFF_HZ = {
    1600.0: (280.0, 234.0, 145.0), 800.0: (230.0, 140.0, 80.0),
    400.0: (145.0, 75.0, 40.0), 200.0: (80.0, 38.0, 20.0), 100.0: (40.0, 19.0, 10.0),
    50.0: (20.0, 9.0, 5.0), 25.0: (10.0, 5.0, 3.0), 12.5: (5.0, 2.0, 1.0)}
BMI088_MODES = ('normal', 'osr2', 'osr4')

SOURCES = {
    'adxl355': 'ADXL354/ADXL355 datasheet, FILTER register: low-pass corner ODR/4',
    'bmi088': 'BMI088 datasheet section 4.4.1 (ACC_CONF acc_bwp): -3 dB cut-off per ODR',
}
_NAME = re.compile(r'^(?P<chip>[a-z0-9]+)@(?P<odr>[0-9.]+)Hz(?:-(?P<mode>[a-z0-9]+))?$')


def setting_name(chip: str, odr_hz: float, mode: str = 'normal') -> str:
    """``chip@ODRHz`` (normal mode) or ``chip@ODRHz-mode``."""
    return f'{chip}@{odr_hz:g}Hz' + ('' if mode == 'normal' else f'-{mode}')


def setting(name: str) -> tuple[str, float, float]:
    """(chip, ODR Hz, -3 dB cut-off Hz) of a setting name; ConfigError naming the valid ones."""
    match = _NAME.match(name)
    chip = match['chip'] if match else name.split('@')[0]
    if match is not None and chip in SOURCES:
        odr, mode = float(match['odr']), match['mode'] or 'normal'
        if chip == 'adxl355' and mode == 'normal':
            for rate in ADXL355_ODRS_HZ:
                if abs(rate / odr - 1) < 1e-3:
                    return chip, rate, ADXL355_CORNER * rate
        if chip == 'bmi088' and odr in BMI088_CUTOFF_HZ and mode in BMI088_MODES:
            return chip, odr, BMI088_CUTOFF_HZ[odr][BMI088_MODES.index(mode)]
    valid = {'adxl355': 'adxl355@ODRHz, ODR 4000, 2000, ..., 3.906 Hz',
             'bmi088': 'bmi088@ODRHz[-osr2|-osr4], ODR 1600, 800, ..., 12.5 Hz'}
    expected = valid.get(chip, ' or '.join(valid.values()))
    raise ConfigError(f'sensor setting {name!r}: expected {expected}')
