"""MEMS car-body accelerometer model: specific force in ``imu_link`` as REP 145 defines it.

The chain per axis, in order (rail_domain.md section 4, "simulation recipe"):
white noise at the simulation rate -> the chip's causal low-pass (a Butterworth at the
datasheet's -3 dB cut-off, ``chip_cutoff_hz``; it delays the signal as the chip does; none in
the delay-free models ``adxl355`` and ``bmi088``) -> linear-phase anti-alias FIR and resampling
to the output rate (polyphase, delay compensated, ``MemsStream``) -> + gravity (+g on z at rest,
z up) ->
scale factor -> + bias (turn-on + random walk) -> saturation at the range -> quantisation to the
LSB; then stamps with clock drift and jitter, and Gilbert-Elliott dropout bursts. Every effect is
off when its field is 0 (range: inf), and everything random comes from one seed. ``MemsStream``
runs the chain over a stream in chunks (state kept); ``measure`` is one chunk of it.

Units: m/s^2, s, Hz; noise density in (m/s^2)/sqrt(Hz) (one-sided), bias random walk in
(m/s^2)/sqrt(s).

A sensor with a gyro (``gyro: true``) measures the angular velocity (rad/s, REP 103 body axes)
through the same chain with its own noise, bias, LSB and range (``gyro_chain``) and no gravity;
without one, messages mark angular_velocity absent (REP 145: covariance[0] = -1).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, fields, replace
from fractions import Fraction
import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal

from railgsa_ros.errors import ConfigError

G = 9.80665  # standard gravity, m/s^2
MG = 1e-3 * G
UG = 1e-6 * G
FRAME_ID = 'imu_link'
STOPBAND_DB = 80.0  # anti-alias attenuation from the output Nyquist frequency up


@dataclass(frozen=True)
class ImuSpec:
    """Accelerometer parameters (SI units); the defaults are an ideal sensor with gravity."""

    name: str = 'custom'
    output_rate_hz: float = 1000.0  # output data rate
    antialias_ratio: float = 0.45  # -6 dB cut-off of the anti-alias FIR / output rate, < 0.5
    noise_density: float = 0.0  # (m/s^2)/sqrt(Hz), white, every axis
    bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s^2 per axis x, y, z
    bias_rw: float = 0.0  # bias random walk, (m/s^2)/sqrt(s)
    scale_factor: float = 0.0  # relative gain error: output = (1 + scale_factor) * input
    gravity: float = G  # m/s^2 added to z (specific force); 0 removes it
    lsb: float = 0.0  # quantisation step, m/s^2 (0: none)
    range_mps2: float = math.inf  # saturation at +-range, m/s^2
    clock_drift_ppm: float = 0.0  # stamp clock rate error, parts per million
    stamp_jitter_s: float = 0.0  # standard deviation of the stamp error, s
    dropout_fraction: float = 0.0  # long-run fraction of lost samples, [0, 1)
    dropout_burst_s: float = 0.05  # mean length of a dropout burst, s
    gyro: bool = False  # the sensor has a gyro: angular velocity measured, else absent
    gyro_noise_density: float = 0.0  # (rad/s)/sqrt(Hz), white, every axis
    gyro_bias: float = 0.0  # rad/s, every axis (zero-rate offset)
    gyro_bias_rw: float = 0.0  # gyro bias random walk, (rad/s)/sqrt(s)
    gyro_lsb: float = 0.0  # gyro quantisation step, rad/s (0: none)
    gyro_range: float = math.inf  # gyro saturation at +-range, rad/s
    chip_cutoff_hz: float = 0.0  # -3 dB cut-off of the chip's causal low-pass, Hz (0: none)
    chip_order: float = 4.0  # its order (a Butterworth: datasheets give no order, [M])

    def __post_init__(self) -> None:
        if not isinstance(self.gyro, bool):
            raise ConfigError(f'imu.gyro: expected true or false, got {self.gyro!r}')
        for f in fields(self):
            if f.name in ('name', 'bias', 'gyro'):
                continue
            value = getattr(self, f.name)
            if isinstance(value, str):
                with contextlib.suppress(ValueError):  # YAML 1.1 leaves '2e-5' a string
                    value = float(value)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
                raise ConfigError(f'imu.{f.name}: expected a number, got {value!r}')
            object.__setattr__(self, f.name, float(value))
        try:
            bias = tuple(float(b) for b in np.broadcast_to(np.asarray(self.bias, float), 3))
        except (TypeError, ValueError):
            raise ConfigError(f'imu.bias: expected 1 or 3 numbers (m/s^2), got {self.bias!r}'
                              ) from None
        object.__setattr__(self, 'bias', bias)
        checks = {
            'output_rate_hz': self.output_rate_hz > 0 and math.isfinite(self.output_rate_hz),
            'antialias_ratio': 0 < self.antialias_ratio < 0.5,
            'range_mps2': self.range_mps2 > 0,
            'scale_factor': self.scale_factor > -1,
            'dropout_fraction': 0 <= self.dropout_fraction < 1,
            'dropout_burst_s': self.dropout_burst_s > 0,
            'bias': all(math.isfinite(b) for b in bias),
            'chip_cutoff_hz': 0 <= self.chip_cutoff_hz < self.output_rate_hz / 2,
            'chip_order': self.chip_order in range(1, 9),
        }
        for name in ('noise_density', 'bias_rw', 'gravity', 'lsb', 'stamp_jitter_s',
                     'gyro_noise_density', 'gyro_bias_rw', 'gyro_lsb'):
            checks[name] = 0 <= getattr(self, name) < math.inf
        checks['gyro_bias'] = math.isfinite(self.gyro_bias)
        checks['gyro_range'] = self.gyro_range > 0
        checks['clock_drift_ppm'] = abs(self.clock_drift_ppm) < 1e5
        for name, ok in checks.items():
            if not ok:
                why = (f' (must be below half the output rate, {self.output_rate_hz:g} Hz: '
                       'a chip setting runs at its own output rate)'
                       if name == 'chip_cutoff_hz' else '')
                raise ConfigError(f'imu.{name}: invalid value {getattr(self, name)!r}{why}')

    @property
    def antialias_hz(self) -> float:
        """-6 dB cut-off of the anti-alias filter, Hz."""
        return self.antialias_ratio * self.output_rate_hz


DEG = math.pi / 180.0  # rad per degree

PRESETS: dict[str, ImuSpec] = {
    'ideal': ImuSpec(name='ideal', gyro=True),
    # Analog Devices ADXL355 (rail_domain.md section 4): 22.5 ug/sqrt(Hz) [datasheet], +-2 g
    # range [datasheet], 20 bit = 256000 LSB/g at +-2 g, ODR 1 kHz of 3.9 Hz-4 kHz [datasheet],
    # bandwidth ODR/4 [AD forum]. Bias 3 mg = 0.15 mg/degC tempco [secondary] x 20 degC; random
    # walk 5 ug/sqrt(s), scale error 0.1 %, 20 ppm clock, 0.1 ms jitter, 0.1 % dropouts in
    # 50 ms bursts: assumptions inside the ranges of the recipe, not datasheet values.
    'adxl355': ImuSpec(name='adxl355', output_rate_hz=1000.0, antialias_ratio=0.25,
                       noise_density=22.5 * UG, bias=(3 * MG, 3 * MG, 3 * MG), bias_rw=5 * UG,
                       scale_factor=1e-3, lsb=G / 256000, range_mps2=2 * G,
                       clock_drift_ppm=20.0, stamp_jitter_s=1e-4, dropout_fraction=1e-3,
                       dropout_burst_s=0.05),
    # Bosch BMI088 accelerometer: ~175 ug/sqrt(Hz) [secondary], +-3 g with 10920 LSB/g
    # [datasheet], ODR 400 Hz of 12.5-1600 Hz, bandwidth 0.4 ODR (ODR 50 Hz -> 20 Hz [code]).
    # Bias 10 mg (20 degC in the 3-15 mg range), 20 ug/sqrt(s) random walk, 0.2 % scale error,
    # 50 ppm clock, 0.2 ms jitter, 0.5 % dropouts in 50 ms bursts: assumptions as above.
    # Its gyro: 0.014 deg/s/sqrt(Hz) [datasheet], the +-125 deg/s range (the finest: a car body
    # pitches at well under 1 deg/s) with 16 bit = 262.1 LSB/(deg/s) [datasheet], zero-rate
    # offset 0.5 deg/s (inside the +-1 deg/s of the datasheet), random walk 1e-4 (rad/s)/sqrt(s):
    # assumptions.
    'bmi088': ImuSpec(name='bmi088', output_rate_hz=400.0, antialias_ratio=0.4,
                      noise_density=175 * UG, bias=(10 * MG, 10 * MG, 10 * MG), bias_rw=20 * UG,
                      scale_factor=2e-3, lsb=G / 10920, range_mps2=3 * G, clock_drift_ppm=50.0,
                      stamp_jitter_s=2e-4, dropout_fraction=5e-3, dropout_burst_s=0.05,
                      gyro=True, gyro_noise_density=0.014 * DEG, gyro_bias=0.5 * DEG,
                      gyro_bias_rw=1e-4, gyro_lsb=125 * DEG / 32768, gyro_range=125 * DEG),
}
SETTING_ANTIALIAS_RATIO = 0.45  # with a chip filter the FIR only guards the decimation


def setting_spec(name: str) -> ImuSpec:
    """The chip at a datasheet setting (``datasheets``: ``adxl355@1000Hz``, ``bmi088@400Hz``,
    ``bmi088@400Hz-osr2``): the chip's preset at that output rate, its causal low-pass at the
    datasheet's cut-off, so that the simulated bag is delayed as the chip's is."""
    from railgsa_ros.datasheets import setting

    chip, odr, cutoff = setting(name)
    return replace(PRESETS[chip], name=name, output_rate_hz=odr,
                   antialias_ratio=SETTING_ANTIALIAS_RATIO, chip_cutoff_hz=cutoff)


PRESETS.update({n: setting_spec(n) for n in ('adxl355@1000Hz', 'bmi088@400Hz', 'bmi088@200Hz')})


def imu_spec(name: str, **overrides: Any) -> ImuSpec:
    """A preset by name (or any datasheet setting ``chip@ODRHz[-mode]``) with fields
    overridden; unknown preset, setting or field -> ConfigError."""
    if name not in PRESETS and '@' not in name:
        raise ConfigError(f'sensor: unknown preset {name!r}; expected {", ".join(PRESETS)} '
                          'or a chip setting chip@ODRHz')
    from railgsa_ros.config import key_list

    known = {f.name for f in fields(ImuSpec)} - {'name'}
    unknown = [k for k in overrides if k not in known]
    if unknown:
        raise ConfigError(f'imu: unknown field(s) {key_list(unknown)}')
    return replace(PRESETS[name] if name in PRESETS else setting_spec(name), **overrides)


def load_imu(path: str | Path) -> ImuSpec:
    """Read ``imu: {preset: NAME, <field>: value, ...}`` from a YAML file (see config/imu.yaml)."""
    from railgsa_ros.config import load_yaml

    doc = load_yaml(path)
    section = doc.get('imu') if isinstance(doc, dict) else None
    if not isinstance(section, dict):
        raise ConfigError(f'{path}: missing top-level "imu:" mapping')
    from railgsa_ros.config import key_list

    odd = [k for k in section if not isinstance(k, str)]
    if odd:
        raise ConfigError(f'{path}: imu: field names must be text, got {key_list(odd)}')
    section = dict(section)
    try:
        return imu_spec(str(section.pop('preset', 'ideal')), **section)
    except ConfigError as exc:
        raise ConfigError(f'{path}: {exc}') from None


def gyro_chain(spec: ImuSpec) -> ImuSpec:
    """The gyro of ``spec`` as the accelerometer chain runs it (``MemsStream`` on angular
    velocities, rad/s): its noise, bias on every axis, walk, LSB and range, no gravity; the
    rate, filter, scale error and clock of the sensor."""
    return replace(spec, name=f'{spec.name} gyro', noise_density=spec.gyro_noise_density,
                   bias=(spec.gyro_bias,) * 3, bias_rw=spec.gyro_bias_rw, gravity=0.0,
                   lsb=spec.gyro_lsb, range_mps2=spec.gyro_range)


def noise_bandwidth_hz(spec: ImuSpec) -> float:
    """Equivalent noise bandwidth (Hz) of the chip and anti-alias filters: integral of |H(f)|^2
    over [0, fs/2]; nearly independent of the filters' own rate, here four times the output
    rate. Without a chip filter (fs / 2) sum h^2 (Parseval)."""
    fs = 4 * spec.output_rate_hz
    taps = antialias_fir(spec, fs)
    chip = chip_filter(spec, fs)
    if chip is None:
        return 0.5 * fs * float(np.sum(taps ** 2))
    f = np.linspace(0.0, fs / 2, 16385)
    power = np.abs(signal.freqz(taps, 1.0, f, fs=fs)[1] * signal.sosfreqz(chip, f, fs=fs)[1]) ** 2
    return float(np.trapezoid(power, f))


def accel_covariance(spec: ImuSpec) -> float:
    """Per-axis variance ((m/s^2)^2) for the REP 145 covariance diagonal.

    White noise over the output bandwidth (noise density^2 * noise bandwidth of the anti-alias
    filter) plus the quantisation variance LSB^2 / 12.
    """
    return spec.noise_density ** 2 * noise_bandwidth_hz(spec) + spec.lsb ** 2 / 12


def gyro_covariance(spec: ImuSpec) -> float:
    """Per-axis gyro variance ((rad/s)^2) for the REP 145 diagonal, as ``accel_covariance``;
    -1 (REP 145: absent) for a sensor without a gyro."""
    return accel_covariance(gyro_chain(spec)) if spec.gyro else -1.0


@dataclass(frozen=True)
class ImuSamples:
    """Accelerometer output: stamps (int64 ns), specific force (T, 3) m/s^2 in imu_link, a mask
    of delivered samples (False = dropped) and the true sample times (s)."""

    stamps_ns: np.ndarray
    accel: np.ndarray
    valid: np.ndarray
    t_true_s: np.ndarray


def antialias_fir(spec: ImuSpec, fs_filter: float) -> np.ndarray:
    """Linear-phase Kaiser low-pass (odd length, DC gain 1) run at ``fs_filter`` Hz.

    -6 dB at ``spec.antialias_hz``, STOPBAND_DB down from the output Nyquist frequency.
    """
    width = (0.5 - spec.antialias_ratio) * 2 * spec.output_rate_hz
    numtaps, beta = signal.kaiserord(STOPBAND_DB, width / (0.5 * fs_filter))
    return signal.firwin(numtaps | 1, spec.antialias_hz, window=('kaiser', beta), fs=fs_filter)


def chip_filter(spec: ImuSpec, fs_filter: float) -> np.ndarray | None:
    """The chip's causal low-pass run at ``fs_filter`` Hz as second-order sections: a
    Butterworth of ``spec.chip_order`` poles, -3 dB at ``spec.chip_cutoff_hz`` (None without)."""
    if spec.chip_cutoff_hz == 0:
        return None
    if spec.chip_cutoff_hz >= fs_filter / 2:
        raise ConfigError(f'imu.chip_cutoff_hz: {spec.chip_cutoff_hz:g} Hz must be below half '
                          f'the simulation rate {fs_filter:g} Hz')
    return signal.butter(int(spec.chip_order), spec.chip_cutoff_hz, fs=fs_filter, output='sos')


def rate_ratio(fs_in: float, fs_out: float) -> tuple[int, int]:
    """(up, down) with fs_out = fs_in * up / down exactly; ConfigError otherwise."""
    ratio = Fraction(fs_out / fs_in).limit_denominator(10_000)
    if abs(float(ratio) - fs_out / fs_in) > 1e-9 * fs_out / fs_in or ratio > Fraction(1, 2):
        raise ConfigError(f'imu.output_rate_hz: {fs_out:g} Hz must be a simple fraction of at '
                          f'most half the simulation rate {fs_in:g} Hz')
    return ratio.numerator, ratio.denominator


class Dropouts:
    """Gilbert-Elliott dropout bursts as a stream: ``take(n)`` -> mask, True where delivered.

    Two-state Markov chain with geometric run lengths: bad runs of mean dropout_burst_s, good
    runs of mean burst * (1 - f) / f, so that the long-run lost fraction is f. The chain starts
    in its stationary distribution (geometric runs are memoryless, so the first run is a full
    one). Run lengths are drawn in fixed batches: the masks do not depend on how n is split.
    """

    BATCH = 256

    def __init__(self, spec: ImuSpec, rng: np.random.Generator) -> None:
        self.rng = rng
        self.enabled = spec.dropout_fraction > 0
        if not self.enabled:
            return
        frac = spec.dropout_fraction
        bad_mean = max(1.0, spec.dropout_burst_s * spec.output_rate_hz)
        good_mean = max(1.0, bad_mean * (1 - frac) / frac)
        self._p = {True: 1 / bad_mean, False: 1 / good_mean}  # state "bad" -> geometric p
        self._lengths: dict[bool, list[int]] = {True: [], False: []}
        self.bad = bool(rng.random() < bad_mean / (bad_mean + good_mean))
        self.left = self._next(self.bad)

    def _next(self, bad: bool) -> int:
        if not self._lengths[bad]:
            self._lengths[bad] = self.rng.geometric(self._p[bad], self.BATCH).tolist()[::-1]
        return self._lengths[bad].pop()

    def take(self, n: int) -> np.ndarray:
        """The next n samples' delivery mask."""
        out = np.ones(n, bool)
        if not self.enabled:
            return out
        pos = 0
        while pos < n:  # one step per run: runs are long (mean >= 1 burst) next to a chunk
            step = min(self.left, n - pos)
            out[pos:pos + step] = not self.bad
            pos += step
            self.left -= step
            if self.left == 0:
                self.bad = not self.bad
                self.left = self._next(self.bad)
        return out


def dropout_mask(n: int, spec: ImuSpec, rng: np.random.Generator) -> np.ndarray:
    """Gilbert-Elliott bursts (``Dropouts``) over n samples: True where a sample is delivered."""
    return Dropouts(spec, rng).take(n)


class MemsStream:
    """The accelerometer model run over a stream of true accelerations in chunks.

    ``process(a_true)`` takes the next chunk at the input rate ``fs_in`` (Hz) and returns every
    output sample whose anti-alias window is complete; ``process(..., final=True)`` ends the
    stream (the signal is held at its last value beyond it, and at its first before the start).
    Every effect keeps its state (filter history, bias walk, dropout chain, sample counter,
    random streams), so the output does not depend on how the stream is chunked.

    Why our own polyphase loop instead of ``scipy.signal.resample_poly``: resample_poly only
    filters a whole array; here each output is a sum over taps in a fixed order, identical
    whatever the chunk boundaries (bit for bit).
    """

    def __init__(self, spec: ImuSpec, fs_in: float, seed: int | None = 0,
                 t0_s: float = 0.0) -> None:
        self.spec = spec
        self.fs_in = float(fs_in)
        self.up, self.down = rate_ratio(fs_in, spec.output_rate_hz)
        self.taps = antialias_fir(spec, fs_in * self.up) * self.up
        self.chip = chip_filter(spec, self.fs_in)  # causal: not compensated
        self._chip_state: np.ndarray | None = None
        self.half = (self.taps.size - 1) // 2  # delay of the linear-phase FIR, upsampled samples
        # one independent stream per effect: switching one effect leaves the others unchanged
        self._noise, self._walk, self._jitter, drop = np.random.default_rng(seed).spawn(4)
        self.dropouts = Dropouts(spec, drop)
        self.t0_s = float(t0_s)
        self.t0_ns = np.int64(round(t0_s * 1e9))
        self.pad = (self.taps.size + self.up - 1) // self.up + 1  # held samples at each edge
        self._buf = np.zeros((0, 3))
        self._buf_start = 0  # input index of _buf[0] (negative: the held start)
        self.n_in = 0
        self.n_out = 0
        self._walk_sum = np.zeros((1, 3))

    def _available(self, final: bool) -> int:
        """Number of outputs that the input so far allows."""
        if final:
            return -(-self.n_in * self.up // self.down)
        # output k needs input index floor((k down + half) / up) <= n_in - 1
        return max(0, (self.n_in * self.up - 1 - self.half) // self.down + 1)

    def process(self, a_true: np.ndarray, final: bool = False) -> ImuSamples:
        """Feed the next chunk ((n,) vertical or (n, 3), m/s^2); outputs as ``ImuSamples``."""
        a = np.asarray(a_true, dtype=float)
        if a.ndim == 1:
            a = np.column_stack([np.zeros_like(a), np.zeros_like(a), a])
        spec = self.spec
        if spec.noise_density > 0:
            a = a + self._noise.normal(0.0, spec.noise_density * np.sqrt(self.fs_in / 2),
                                       a.shape)
        if self.chip is not None and a.shape[0]:
            if self._chip_state is None:  # at rest on the first value before the start
                self._chip_state = signal.sosfilt_zi(self.chip)[:, :, None] * a[0]
            a, self._chip_state = signal.sosfilt(self.chip, a, axis=0, zi=self._chip_state)
        if self.n_in == 0 and a.shape[0]:
            self._buf = np.repeat(a[:1], self.pad, axis=0)
            self._buf_start = -self.pad
        self._buf = np.concatenate([self._buf, a])
        self.n_in += a.shape[0]
        if final and self.n_in:
            self._buf = np.concatenate([self._buf, np.repeat(self._buf[-1:], self.pad, axis=0)])
        k = np.arange(self.n_out, self._available(final))
        y = self._filter(k)
        self.n_out += k.size
        if k.size:  # keep the inputs the next output still needs
            first = (self.n_out * self.down + self.half - self.taps.size + 1) // self.up
            drop = max(0, first - self._buf_start)
            self._buf = self._buf[drop:]
            self._buf_start += drop
        return self._sample(k, y)

    def _filter(self, k: np.ndarray) -> np.ndarray:
        """Anti-alias FIR and resampling: outputs k (n,) -> (n, 3), taps summed in order."""
        y = np.zeros((k.size, 3))
        top = k * self.down + self.half  # upsampled input index under tap 0
        for n, h in enumerate(self.taps):
            m = top - n
            if self.up == 1:
                y += h * self._buf[m - self._buf_start]
            else:
                on = m % self.up == 0
                y[on] += h * self._buf[m[on] // self.up - self._buf_start]
        return y

    def _sample(self, k: np.ndarray, y: np.ndarray) -> ImuSamples:
        """Gravity, scale, bias and its walk, ADC, stamps and dropouts of outputs k."""
        spec = self.spec
        dt_out = 1.0 / spec.output_rate_hz
        y[:, 2] += spec.gravity
        y *= 1.0 + spec.scale_factor
        y += np.asarray(spec.bias)
        if spec.bias_rw > 0:
            steps = self._walk.normal(0.0, spec.bias_rw * np.sqrt(dt_out), (k.size, 3))
            walk = np.cumsum(np.concatenate([self._walk_sum, steps]), axis=0)
            self._walk_sum = walk[-1:]
            y += walk[1:]
        if spec.lsb > 0:  # saturate in ADC codes, so that |output| <= range stays a code
            full = np.floor(spec.range_mps2 / spec.lsb)
            y = np.clip(np.rint(y / spec.lsb), -full, full) * spec.lsb
        else:
            y = np.clip(y, -spec.range_mps2, spec.range_mps2)
        elapsed = k * dt_out * (1.0 + 1e-6 * spec.clock_drift_ppm)
        if spec.stamp_jitter_s > 0:
            elapsed = elapsed + self._jitter.normal(0.0, spec.stamp_jitter_s, k.size)
        stamps = self.t0_ns + np.rint(elapsed * 1e9).astype(np.int64)
        return ImuSamples(stamps, y, self.dropouts.take(k.size), self.t0_s + k * dt_out)


def measure(t_s: np.ndarray, a_true: np.ndarray, spec: ImuSpec, seed: int | None = 0
            ) -> ImuSamples:
    """Simulate the accelerometer on a true kinematic acceleration (``MemsStream``, one chunk).

    t_s: uniform simulation times (s), rate at least twice ``spec.output_rate_hz``;
    a_true: vertical acceleration (T,) or all axes (T, 3), m/s^2, body frame z up.
    Output samples lie at t_s[0] + k / output_rate_hz (true times); stamps_ns carry clock drift
    and jitter relative to t_s[0].
    """
    t_s = np.asarray(t_s, dtype=float)
    a = np.asarray(a_true, dtype=float)
    if a.ndim == 1:
        a = np.column_stack([np.zeros_like(a), np.zeros_like(a), a])
    if t_s.ndim != 1 or t_s.size < 2 or a.shape != (t_s.size, 3):
        raise ValueError(f'measure: t_s (T,) and a_true (T,) or (T, 3), got {t_s.shape}, '
                         f'{np.shape(a_true)}')
    steps = np.diff(t_s)
    if steps.min() <= 0 or np.ptp(steps) > 1e-6 * steps.mean():
        raise ValueError('measure: t_s must be uniformly spaced and increasing')
    return MemsStream(spec, 1.0 / steps.mean(), seed, t_s[0]).process(a, final=True)
