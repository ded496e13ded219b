"""The streaming inversion pipeline shared by ``irregularity_node`` and ``railgsa invert``.

Per sample (sanitised by the input stage, ``railgsa_ros.input``, or by ``push``'s own
sanitiser): chainage (trapezoidal integral of speed over the stamps) -> vertical
acceleration minus gravity (optionally minus a running-mean bias) -> raised-cosine fade-in after
each (re)start -> method -> band FIR with a fixed delay of D samples. The output for sample k is
emitted when sample k + D has arrived and carries sample k's stamp and chainage.

Methods (all run a bank of P parameter sets):
- ``spectral``: the exact inverse 1/G(j w) folded into the band FIR, |BP|^2 / G: one FIR stage;
  for a coach (``model=``) its LMMSE inverse from one or more channels (``design.py``), one
  FIR per channel, summed (``channelsum.py``).
- ``feedback``: Eq. 7 (exact FOH), then the band FIR; that order lets the band remove the drift of
  the marginally damped slow pole pair (+-j / sqrt(K)) and costs one shared FIR design.
- ``kalman``: the steady-state Kalman filter (or, offline, the RTS smoother), then the band FIR.

The band FIR runs at fs / R between an anti-alias decimator and a polyphase interpolator
(``multirate.py``; R from ``rate_hz`` and ``max_speed_mps``, single rate when R < 2 or
``multirate`` is false). Band designs follow the speed at the output sample, are held at
``min_design_speed_mps`` below it and ``max_speed_mps`` above it, and are swapped every
``switch_period`` samples when the speed moved by more than ``speed_tolerance``; D is fixed by the
design at the minimum speed (the longest impulse response) plus the anti-alias delays.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from railgsa_ros.errors import ConfigError, InputError
from railgsa_ros.input.sanitize import SMALL, SPEED_LIMIT_MPS, Clean, InputSanitizer
from railgsa_ros.inverse.band import (
    band_edges_hz,
    bandpass_power,
    design_grid,
    fir_taps,
    half_length,
    truncation_error,
)
from railgsa_ros.inverse.channelsum import ChannelSum
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.convolve import PartitionedFir
from railgsa_ros.inverse.design import (
    GRID_SPANS,
    WINDOW_SPEED_TOLERANCE,
    Observability,
    WienerDesign,
    channel_variances,
    half_width,
    model_theta,
    tapered,
)
from railgsa_ros.inverse.feedback import FeedbackInverse, Stability
from railgsa_ros.inverse.gapfill import GapFiller
from railgsa_ros.inverse.kalman import KalmanInverse
from railgsa_ros.inverse.multirate import (
    MultirateFir,
    antialias_taps,
    decimation,
    rate_dtype,
    rolloff,
)
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.models import VehicleModel
from railgsa_ros.samples import join
from railgsa_ros.vehicle import VehicleParams, as_theta, frequency_response

#: the band window that decides an output's quality: the taps outside it hold less than this
#: fraction of the impulse response's L1 norm (the FIR itself is cut at fir_tolerance)
WINDOW_TOLERANCE = 1e-3
NO_BAND_SWITCH = 2048  # samples between Kalman speed checks when there is no band FIR
DESIGN_PERIODS = 32  # first design grid: this many periods of the lowest band frequency
MAX_DESIGN_BINS = 1 << 21  # largest design grid tried (rfft bins)
#: a coach's outputs are DEGRADED where the data leave more than this fraction of the band's
#: truth variance unobserved (posterior / prior): the error std is then above a third of the
#: band's RMS (correlation with the truth below 0.95), see docs/inversion.md, "Coach"
UNOBSERVED_LIMIT = 0.1
_VALID, _DEGRADED, _INVALID = int(Quality.VALID), int(Quality.DEGRADED), int(Quality.INVALID)


@dataclass(frozen=True)
class Output:
    """Reconstruction: stamps_ns (K,) int64 of the IMU samples, chainage_m (K,), u_m (K,) in m,
    or (P, K) for a bank of parameter sets; quality (K,) uint8 (:class:`Quality` codes) and the
    speed at each sample speed_mps (K,) m/s (None only in outputs built by hand); gap_std_m
    (K,) m: std of the error that filling bridged gaps leaves in u (``GapFiller.
    error_variance``; 0 away from gaps, None in outputs built by hand)."""

    stamps_ns: np.ndarray
    chainage_m: np.ndarray
    u_m: np.ndarray
    quality: np.ndarray | None = None
    speed_mps: np.ndarray | None = None
    gap_std_m: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.stamps_ns.size)

    @property
    def graded(self) -> np.ndarray:
        """The quality codes (K,) uint8: VALID everywhere when none were given."""
        return np.zeros(len(self), np.uint8) if self.quality is None else self.quality

    @classmethod
    def concat(cls, outs: list[Output], channels: int | None = None) -> Output:
        """Join outputs in order; ``channels``: P of a (P, K) bank when ``outs`` may be empty."""
        u0 = np.zeros(0) if channels is None else np.zeros((channels, 0))
        return join(outs, cls(np.zeros(0, np.int64), np.zeros(0), u0, np.zeros(0, np.uint8),
                              np.zeros(0), np.zeros(0)))


def vertical(accel: np.ndarray, axis: str) -> np.ndarray:
    """Upward specific force (m/s^2, +g at rest) from accel (T, 3) and an axis ('z', '-y', ...)."""
    col = 'xyz'.index(axis[-1])
    sign = -1.0 if axis.startswith('-') else 1.0
    return sign * np.asarray(accel, dtype=float)[:, col]


def inverse_response(theta: np.ndarray, grid_hz: np.ndarray) -> np.ndarray:
    """1/G (P, F) on a design grid starting at f = 0, where it is set to 0 (G has its double
    zero there only, and every band response |BP|^2 vanishes there)."""
    g = frequency_response(np.atleast_2d(theta), 2j * np.pi * grid_hz[1:])
    return np.concatenate([np.zeros((g.shape[0], 1)), 1.0 / g], axis=1)


def taper(n: np.ndarray, length: int) -> np.ndarray:
    """Raised-cosine ramp 0 -> 1 over ``length`` samples evaluated at sample indices n."""
    ramp = np.ones(np.shape(n))
    if length > 0:  # the cosine only where it is needed: most samples lie past the ramp
        head = n < length
        ramp[head] = 0.5 - 0.5 * np.cos(np.pi * n[head] / length)
    return ramp


class _Meta:
    """Per-sample metadata waiting in the delay line: stamps, chainage, speed, emit flag, input
    quality. Columns with room to grow (a live push appends one sample to D waiting ones; a
    concatenation would copy all D each time); samples are written past the newest only, so
    the views ``pop`` returns stay valid. The ``back`` samples popped last stay readable
    (``speed_at``: the speed behind an output sample's band window)."""

    DTYPES = (np.int64, np.float64, np.float64, np.bool_, np.uint8)
    MIN_ROOM = 1024  # samples

    def __init__(self, back: int = 0) -> None:
        self._cols = [np.zeros(0, dtype) for dtype in self.DTYPES]
        self._lo = self._hi = 0  # the waiting samples are [_lo, _hi) of every column
        self._back = back

    @property
    def speed(self) -> np.ndarray:
        """Speeds (m/s) of the waiting samples, oldest first."""
        return self._cols[2][self._lo:self._hi]

    @property
    def speeds(self) -> tuple[np.ndarray, int, int]:
        """The speed column (m/s), the column index of the oldest waiting sample and that of
        the newest plus one: the ``back`` samples before the oldest (as far as there were any)
        and the waiting ones after it are readable."""
        return self._cols[2], self._lo, self._hi

    def extend(self, *values: np.ndarray) -> None:
        """Append (stamps, chainage, speed, emit, quality), all (N,)."""
        n = values[0].size
        if self._hi + n > self._cols[0].size:  # new columns: back, waiting samples, room
            keep = self._lo - max(self._lo - self._back, 0)
            size = self._hi - self._lo + keep
            room = max(size + n, self.MIN_ROOM)
            self._cols = [np.concatenate([c[self._lo - keep:self._hi], np.empty(room, c.dtype)])
                          for c in self._cols]
            self._lo, self._hi = keep, size
        for col, value in zip(self._cols, values, strict=True):
            col[self._hi:self._hi + n] = value
        self._hi += n

    def pop(self, count: int) -> tuple[np.ndarray, ...]:
        """(stamps, chainage, speed, emit, quality) of the oldest ``count`` samples."""
        count = min(count, self._hi - self._lo)
        out = tuple(c[self._lo:self._lo + count] for c in self._cols)
        self._lo += count
        return out


class InversionPipeline:
    """Streaming irregularity reconstruction; see the module docstring and docs/inversion.md.

    ``vehicle``: VehicleParams, theta (5,) or a bank theta (P, 5); ``noise_variance``: IMU
    accelerometer variance ((m/s^2)^2) for the Kalman method, else ``config.noise_std_mps2``^2;
    ``start_chainage_m``: chainage of the first sample (m; a rebuilt pipeline continues its
    predecessor's); ``stuck_s``, ``backward_reset_s``: the sanitiser of ``push`` (see
    :class:`InputSanitizer`; an input stage sanitises and calls ``feed``);
    ``nominal``: the vehicle theta (5,) whose band response sets the quality window
    (``window_half_width``; default: the widest of the bank), so that a bank and the nominal
    pipeline grade their outputs alike.

    ``model``: a ``railgsa_ros.models`` vehicle; a coach inverts with its LMMSE design
    (``design.py``; ``vehicle``, ``nominal``: its theta (n,) or (P, n), default its nominal)
    from the data ``channels`` (``model.channels`` names, accelerometer first; the others come
    as ``push(rates=...)``); None or a quarter car: the exact inverse 1/G of theta (5,).
    """

    _inv_g: np.ndarray | None  # 1/G on the design grid (computed at the first design)

    def __init__(self, config: InversionConfig | None = None,
                 vehicle: VehicleParams | np.ndarray | None = None,
                 noise_variance: float | None = None, *, start_chainage_m: float = 0.0,
                 stuck_s: float = 0.0, backward_reset_s: float = 1.0,
                 nominal: np.ndarray | None = None, model: VehicleModel | None = None,
                 channels: Sequence[str] = ('accel_z',)) -> None:
        cfg = self.config = config if config is not None else InversionConfig()
        coach = None if model is None or model.kind == 'quarter_car' else model
        if coach is None:
            theta = as_theta(vehicle if vehicle is not None else
                             VehicleParams() if model is None else model.theta)
            self._nominal = None if nominal is None else np.atleast_2d(as_theta(nominal))
        else:
            theta = model_theta(coach, vehicle)
            self._nominal = None if nominal is None else np.atleast_2d(
                model_theta(coach, nominal))
        self._squeeze = theta.ndim == 1
        self.theta = np.atleast_2d(theta)
        accel_var = cfg.noise_std_mps2 ** 2 if noise_variance is None else float(noise_variance)
        self._wiener = self._wiener_nominal = None
        self.observability: Observability | None = None  #: a coach's unobserved band part
        self.extra_channels = 0  #: rows of ``push(rates=...)``: the data channels after accel
        if coach is not None:
            if cfg.method != 'spectral':
                raise ConfigError(f'method: {cfg.method} inverts the quarter car only; a coach '
                                  'inverts with spectral (its LMMSE design)')
            self.config = cfg = cfg.with_(window_speed_tolerance=min(
                cfg.window_speed_tolerance, max(WINDOW_SPEED_TOLERANCE, 2 * cfg.speed_tolerance)))
            variances = channel_variances(coach, channels, accel_var,
                                          cfg.gyro_noise_std_rads ** 2)
            self.extra_channels = len(channels) - 1
            self._wiener = WienerDesign(coach, self.theta, channels, variances,
                                        cfg.track_spectrum_av, cfg.rate_hz)
            nominal_theta = self._nominal if self._nominal is not None else \
                self.theta.mean(axis=0, keepdims=True)
            self._wiener_nominal = self._wiener if np.array_equal(nominal_theta, self.theta) \
                else WienerDesign(coach, nominal_theta, channels, variances,
                                  cfg.track_spectrum_av, cfg.rate_hz)
        self._extra: list[np.ndarray] = []  # extra channel columns (C - 1, N) not yet fed
        self._last_extra = np.zeros(self.extra_channels)  # last finite value of each
        self.dt = 1.0 / cfg.rate_hz
        self._limits = (stuck_s, backward_reset_s)
        self._sanitizer: InputSanitizer | None = None  # push's, made at the first push
        self._counters: Counter[str] = Counter()
        self.stability: Stability | None = None
        self._stage: FeedbackInverse | KalmanInverse | None = None
        if cfg.method == 'feedback':
            self._stage = FeedbackInverse(self.theta, cfg.gain, self.dt)
            self.stability = self._stage.stability
        elif cfg.method == 'kalman':
            var = cfg.noise_std_mps2 ** 2 if noise_variance is None else float(noise_variance)
            self._stage = KalmanInverse(self.theta, cfg.track_spectrum_av, cfg.bias_walk_mps2,
                                        var, self.dt,
                                        cfg.speed_mps, cfg.speed_tolerance,
                                        cfg.min_design_speed_mps, cfg.max_speed_mps)
        self._fir: PartitionedFir | MultirateFir | ChannelSum | None = None
        self.delay_samples = 0
        self._window = (0, 0, 1)  # significant half-width: fixed part, low-rate part at vmin, R
        self.decimation = 1
        self.band_taps = 0
        self.truncation_error = 0.0
        self.switch_period = NO_BAND_SWITCH
        if cfg.band != 'none':
            self._fir = self._band_stage()
            self.switch_period = self._fir.switch_period
            self._design_speed = cfg.min_design_speed_mps
            if self._wiener_nominal is not None:
                self.observability = Observability(
                    self._wiener_nominal, cfg.band, cfg.band_order, cfg.min_design_speed_mps,
                    cfg.max_speed_mps, self._grid, self._half, self._rolloff)
        self._gap_taps: dict[float, np.ndarray] = {}  # design speed -> error FIR
        self._gaps = GapFiller(np.mean(self.theta, axis=0), cfg.track_spectrum_av, cfg.rate_hz,
                               cfg.noise_std_mps2 ** 2 if noise_variance is None
                               else float(noise_variance),
                               None if cfg.band == 'none' else self._error_taps,
                               hold=round(cfg.gap_hold_s * cfg.rate_hz),
                               response=None if self._wiener_nominal is None
                               else self._wiener_nominal.accel_response)
        self._chain: tuple[int, float, float] | None = None  # last stamp, chainage, speed
        self.start_chainage_m = float(start_chainage_m)  #: chainage of the first sample, m
        self._offline: list[tuple[np.ndarray, ...]] = []
        self._start_segment()

    # ----------------------------------------------------------------- public interface
    @property
    def counters(self) -> dict[str, int]:
        """Counts by reason: emitted, redesign, reset_<reason>; after ``push`` also its
        sanitiser's: rejected samples (nan, wrong_frame, saturated, stuck, out_of_order,
        duplicate), gap, reset, time_reset, bridged, accepted."""
        if self._sanitizer is None:
            return dict(+self._counters)
        return dict(self._sanitizer.counters + self._counters)

    @property
    def chainage_m(self) -> float:
        """Chainage of the newest sample pushed (m); the start chainage before any."""
        return self._chain[1] if self._chain is not None else self.start_chainage_m

    def add_distance(self, metres: float) -> None:
        """Move the chainage on by ``metres`` before the next sample (a distance the speeds
        fed did not cover: ``InputStage`` across samples without a known speed)."""
        if self._chain is None:
            self.start_chainage_m += metres
        else:
            t, c, v = self._chain
            self._chain = (t, c + metres, v)

    @property
    def speed_changed(self) -> int:
        """VALID outputs so far made DEGRADED by the speed change across their band window
        (``counters['speed_change']``, cheaply)."""
        return self._counters['speed_change']

    @property
    def stability_margin(self) -> float:
        """Decay rate (1/s) of the least-damped mode of the recursive stage; inf for spectral."""
        if self.stability is not None:
            return self.stability.margin
        if isinstance(self._stage, KalmanInverse):
            return -np.log(self._stage.design.spectral_radius) / self.dt
        return float('inf')

    def push(self, stamps_ns: np.ndarray, acc_z: np.ndarray,
             speed_mps: np.ndarray | float | None = None,
             frame_ids: np.ndarray | None = None,
             quality: np.ndarray | None = None, rates: np.ndarray | None = None) -> Output:
        """Feed raw samples without an input stage (tests, scoring, calibration): stamps (T,)
        int64 ns, upward specific force (T,) m/s^2 (+g at rest, see ``vertical``), speed (T,)
        or scalar m/s (None: ``config.speed_mps``), frame ids (T,), input quality (T,)
        :class:`Quality` codes (None: VALID), ``rates`` the data channels after the
        accelerometer (see ``feed``); sanitised by the pipeline's own :class:`InputSanitizer`,
        then ``feed``."""
        speed = self.config.speed_mps if speed_mps is None else speed_mps
        if self._sanitizer is None:
            self._sanitizer = InputSanitizer.for_config(self.config, *self._limits)
        clean = self._sanitizer.process(stamps_ns, acc_z, speed, frame_ids)
        return self.feed(clean, clean.carry(quality), rates, np.shape(acc_z)[0])

    def feed(self, clean: Clean, quality: np.ndarray, rates: np.ndarray | None = None,
             count: int | None = None) -> Output:
        """Filter a sanitised batch ``clean`` (an input stage's ``InputSanitizer.process``)
        with its input quality (N,) :class:`Quality` codes per clean sample, which the delay
        line carries to each output (raised there for the warm-up, the tail and bridged
        input); the filters restart where ``clean.reset_before`` says. ``rates``: the raw
        batch's data channels after the accelerometer (``extra_channels`` rows of ``count``
        samples, (T,) for one: the pitch rate in rad/s), required exactly when the pipeline
        was built with them."""
        if count is None:
            count = 0 if rates is None else np.shape(rates)[-1]
        extra = self._check_extra(rates, count)
        if extra is not None:
            self._extra.append(self._extra_columns(extra, clean))
        if clean.index is None and not clean.reset_before[:1].any():  # one piece, no restart
            return self._public(self._run(clean, quality, slice(None)))
        cuts = np.flatnonzero(clean.reset_before)
        outs = []
        for lo, hi in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [clean.accel.size]]),
                          strict=True):
            if lo in cuts:
                outs.append(self._end_segment())
            if hi > lo:
                outs.append(self._run(clean, quality, slice(lo, hi)))
        return self._public(self._join(outs))

    def flush(self) -> Output:
        """End an offline stream: pad D samples (the last acceleration faded out over
        ``taper_s``, then zeros) and emit every pending sample; the next push starts afresh."""
        out = self._end_segment()
        if self._sanitizer is not None:
            self._sanitizer.reset()
        return self._public(out)

    def reset(self, reason: str = 'request') -> Output:
        """Restart the filters (e.g. after a time jump); returns the flushed pending outputs."""
        self._counters[f'reset_{reason}'] += 1
        return self.flush()

    # ----------------------------------------------------------------- internals
    def _check_extra(self, rates: np.ndarray | None, count: int) -> np.ndarray | None:
        """``rates`` as (C - 1, T) floats; InputError when they do not match the design."""
        if rates is None and not self.extra_channels:
            return None
        if rates is None or not self.extra_channels:
            raise InputError(f'rates: the inversion was designed for {self.extra_channels} '
                             f'channel(s) after the accelerometer, got '
                             f'{"none" if rates is None else "some"}')
        extra = np.asarray(rates, dtype=float).reshape(-1, count) if count else \
            np.zeros((self.extra_channels, 0))
        if extra.shape[0] != self.extra_channels:
            raise InputError(f'rates: expected {self.extra_channels} row(s) of {count} samples, '
                             f'got shape {np.shape(rates)}')
        return extra

    def _extra_columns(self, extra: np.ndarray, clean: Clean) -> np.ndarray:
        """The extra channels (C - 1, N) at the clean samples; bridged samples and non-finite
        values hold the channel's last finite value (0 before any)."""
        cols = extra if clean.index is None else np.where(
            clean.index >= 0, extra[:, np.maximum(clean.index, 0)], np.nan)
        ok = np.isfinite(cols)
        if not ok.all():
            last = np.maximum.accumulate(np.where(ok, np.arange(cols.shape[1]), -1), axis=1)
            cols = np.where(last >= 0, np.take_along_axis(cols, np.maximum(last, 0), axis=1),
                            self._last_extra[:, None])
        if cols.shape[1]:
            self._last_extra = cols[:, -1].copy()
        return cols

    def _take_extra(self, count: int) -> np.ndarray:
        """The oldest ``count`` extra-channel columns queued by ``push`` (released in order)."""
        queued = np.concatenate(self._extra, axis=1) if len(self._extra) > 1 else self._extra[0]
        self._extra = [queued[:, count:]]
        return queued[:, :count]

    def _band_power(self, speed: float) -> np.ndarray:
        """|BP|^2 (1, F) on the design grid at ``speed`` (held at min_design_speed_mps),
        advanced by ``sensor_delay_s``: the output at an IMU stamp is the track under the wheel
        at that stamp, so stamp and chainage stay the sample's own."""
        cfg = self.config
        lo, hi = band_edges_hz(cfg.band, max(speed, cfg.min_design_speed_mps))
        bp = bandpass_power(self._grid, lo, hi, cfg.band_order)[None] * self._rolloff
        if cfg.sensor_delay_s:  # advance by the sensor's group delay: exp(+j w tau)
            bp = bp * np.exp(2j * np.pi * self._grid * cfg.sensor_delay_s)
        return bp

    def _response(self, speed: float) -> np.ndarray:
        """Band response on the design grid at ``speed``: (1, F) or (P, F) with 1/G folded in,
        for a coach (P C, F) with its LMMSE inverse (row p C + c: channel c of set p)."""
        bp = self._band_power(speed)
        if self.config.method != 'spectral':
            return bp
        if self._wiener is not None:  # the coach's inverse depends on the speed (the delays)
            return tapered(bp[:, None] * self._wiener.response(self._grid, speed),
                           self._half).reshape(-1, self._grid.size)
        if self._inv_g is None:  # 1/G on the design grid does not depend on the speed
            self._inv_g = inverse_response(self.theta, self._grid)
        return bp * self._inv_g

    def _band_stage(self) -> PartitionedFir | MultirateFir | ChannelSum:
        """Band FIR designed at min_design_speed_mps (the longest impulse response), run at
        fs / R when R >= 2; sets ``decimation`` (R, 1 = single rate), ``band_taps`` (at that
        rate), ``delay_samples`` (input samples) and ``truncation_error``."""
        cfg = self.config
        f_top = band_edges_hz(cfg.band, cfg.max_speed_mps)[1]
        r = decimation(cfg.rate_hz, f_top) if cfg.multirate else 1
        self.decimation = r if r >= 2 else 1
        vmin = cfg.min_design_speed_mps
        rate = cfg.rate_hz / self.decimation
        periods: float = DESIGN_PERIODS
        spans = 4  # the grid must hold the whole FIR twice over (no circular wrap)
        if self._wiener is not None:  # the coach: a fixed span, cut from a longer response
            self._half = half_width(vmin, rate)
            spans = GRID_SPANS  # a grid that holds them at once
            periods = max(periods, (spans * self._half + 2) * band_edges_hz(cfg.band, vmin)[0]
                          / rate)
        while True:
            self._grid = design_grid(rate, band_edges_hz(cfg.band, vmin)[0], periods)
            self._rolloff = rolloff(self._grid, f_top, rate) if self.decimation > 1 else 1.0
            self._inv_g = None
            response = self._response(vmin)
            if self._wiener is None:
                self._half = half_length(response, cfg.fir_tolerance)  # delay, low samples
            if spans * self._half + 2 <= 2 * (self._grid.size - 1):
                break
            if self._grid.size > MAX_DESIGN_BINS:
                span = 2 * (self._grid.size - 1)
                raise ConfigError(f'fir_tolerance: the band response does not decay below '
                                  f'{cfg.fir_tolerance:g} within {span} samples; raise '
                                  'fir_tolerance or band_order')
            periods *= 2
        taps = fir_taps(response, self._half)
        self.band_taps = taps.shape[-1]
        self.truncation_error = truncation_error(taps, response)
        channels = self.theta.shape[0] * (self.extra_channels + 1)
        graded = response
        if self._wiener_nominal is not None:
            graded = tapered(self._band_power(vmin)[:, None] * self._wiener_nominal.response(
                self._grid, vmin), self._half).reshape(-1, self._grid.size)
        elif self._nominal is not None and cfg.method == 'spectral':
            graded = self._band_power(vmin) * inverse_response(self._nominal, self._grid)
        significant = half_length(graded, max(WINDOW_TOLERANCE, cfg.fir_tolerance))
        fir: PartitionedFir | MultirateFir
        if self.decimation == 1:
            self.delay_samples = self._half
            self._window = (0, significant, 1)
            fir = PartitionedFir(taps, channels)
        else:
            antialias = antialias_taps(cfg.rate_hz, self.decimation, f_top, cfg.fir_tolerance)
            fir = MultirateFir(taps, channels, self.decimation, antialias,
                               rate_dtype(cfg.fir_tolerance, self._stage is None))
            self.delay_samples = self.decimation * self._half + 2 * fir.half_delay
            self._window = (2 * fir.half_delay, significant, self.decimation)
        if self.extra_channels:  # one FIR per data channel, summed
            return ChannelSum(fir, self.theta.shape[0], self.extra_channels + 1)
        return fir

    def _error_taps(self, speed: float) -> np.ndarray:
        """Single-rate band FIR |BP|^2 / G (2 d + 1,) from acceleration to u at the speed's
        design (held as the band's), nominal vehicle: how a gap's fill error reaches the outputs
        (the same response for every method)."""
        cfg = self.config
        v = min(max(speed, cfg.min_design_speed_mps), cfg.max_speed_mps)
        if v not in self._gap_taps:
            grid = design_grid(cfg.rate_hz, band_edges_hz(cfg.band, v)[0], DESIGN_PERIODS)
            lo, hi = band_edges_hz(cfg.band, v)
            theta = self._nominal if self._nominal is not None else np.mean(self.theta, axis=0)
            if self._wiener_nominal is None:
                response = bandpass_power(grid, lo, hi, cfg.band_order) * \
                    inverse_response(theta, grid)[0]
                half = half_length(response, cfg.fir_tolerance)
            else:  # the coach: its accelerometer's FIR, as the band stage cuts it
                half = half_width(cfg.min_design_speed_mps, cfg.rate_hz)
                response = tapered(bandpass_power(grid, lo, hi, cfg.band_order)
                                   * self._wiener_nominal.response(grid, v)[0, 0], half)
            self._gap_taps = {v: fir_taps(response, half)}
        return self._gap_taps[v]

    def _start_segment(self) -> None:
        """Zero the filters and the segment's sample counter."""
        self._n = 0
        self._meta = _Meta(self._window[0] + self._window[1] * self._window[2])
        self._meta_start = 0  # segment index of the oldest sample in the delay line
        self._bridged = np.zeros(0, np.int64)  # segment indices of bridged samples still seen
        self._last_real = np.iinfo(np.int64).max  # segment index of the last real sample (at end)
        self._last_a: float | np.ndarray = 0.0  # last input (C, 1) with extra channels
        self._bias = (0.0, 0)  # running sum (m/s^2) and count of the segment's samples
        self._offset: np.ndarray | None = None  # first method output of the segment (P, 1)
        self._gap_var: list[tuple[int, np.ndarray]] = []  # (first segment index, variance m^2)
        self._gaps.reset()
        if self._stage is not None:
            self._stage.reset()
        if self._fir is not None:
            self._fir.reset()

    def _run(self, clean: Clean, quality: np.ndarray, sl: slice) -> Output:
        """Process clean samples of one segment (input quality codes ``quality`` (N,)); samples
        from a bridged gap on wait in the gap filler for its hold."""
        stamps, speed = clean.stamps_ns[sl], clean.speed[sl]
        chain = self._chainage(stamps, speed)
        return self._feed(*self._gaps.bridge(stamps, clean.accel[sl], clean.synthetic[sl],
                                             speed, chain, quality[sl]))

    def _feed(self, stamps: np.ndarray, accel: np.ndarray, synthetic: np.ndarray,
              speed: np.ndarray, chain: np.ndarray, quality: np.ndarray) -> Output:
        """Samples the gap filler released (gaps filled) through bias, fade-in, method, band."""
        if not stamps.size:
            return self._join([])
        cfg = self.config
        a_s = accel - cfg.gravity_mps2
        if cfg.remove_bias:
            a_s = self._remove_bias(a_s)
        if self.extra_channels:  # the data channels after the accelerometer: rows 1..
            a_s = np.vstack([a_s, self._take_extra(a_s.size)])
        n0 = self._n + sum(x[0].size for x in self._offline)
        self._gap_var += self._gaps.errors  # (first segment index, variance)
        self._gaps.errors = []
        ramp = round(cfg.taper_s * cfg.rate_hz)
        if n0 < ramp:  # fade-in still running
            a_s = a_s * taper(n0 + np.arange(a_s.shape[-1]), ramp)
        self._last_a = a_s[:, -1:] if self.extra_channels else float(a_s[-1])
        emit = ~synthetic
        if cfg.smoother:
            self._offline.append((a_s, stamps, chain, speed, emit, quality))
            return self._join([])
        return self._advance(a_s, stamps, chain, speed, emit, quality)

    def _chainage(self, stamps: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Trapezoidal integral of speed over the stamps, continued across calls (m); time going
        backwards (a time reset) adds no distance; speeds beyond SPEED_LIMIT_MPS count as that.
        The stamps of one segment piece increase strictly (the sanitiser's contract) except,
        after a time reset, at the first sample."""
        lim = SPEED_LIMIT_MPS
        constant = speed.strides == (0,)  # one speed broadcast over the chunk
        if constant or stamps.size <= SMALL:  # clipped as Python floats (a live push)
            v = [min(max(x, -lim), lim) for x in (speed[:1] if constant else speed).tolist()]
        else:
            speed = np.clip(speed, -lim, lim)
            v = [float(speed[0]), float(speed[-1])]
        t0, c0, v0 = self._chain if self._chain is not None else \
            (stamps[0], self.start_chainage_m, v[0])
        first = max(int(stamps[0]) - int(t0), 0)  # ns since the previous sample
        if constant:  # c0 + v0-v trapezoid of the first step + v (t - t[0]): no running sum
            chain = (stamps - stamps[0]).astype(float)
            chain *= v[0] * 1e-9
            chain += c0 + 0.5 * (v0 + v[0]) * first * 1e-9
        elif stamps.size <= SMALL:  # the same sum in Python floats
            t = stamps.tolist()
            c = c0 + (v0 + v[0]) * first * 0.5e-9
            sums = [c]
            for k in range(1, len(t)):
                step = (t[k] - t[k - 1] + (1 << 63)) % (1 << 64) - (1 << 63)  # int64 wrap
                c += float(step) * (v[k] + v[k - 1]) * 0.5e-9
                sums.append(c)
            chain = np.array(sums)
        else:  # c0, then one step 0.5 (v[k] + v[k-1]) (t[k] - t[k-1]) 1e-9 after the other:
            # a running sum that starts from c0 is the same for any chunking
            steps = np.empty(stamps.size + 1)
            steps[0] = c0
            steps[1] = (v0 + speed[0]) * first * 0.5e-9
            np.subtract(stamps[1:], stamps[:-1], out=steps[2:])
            steps[2:] *= speed[1:] + speed[:-1]
            steps[2:] *= 0.5e-9
            chain = np.cumsum(steps)[1:]
        self._chain = (int(stamps[-1]), float(chain[-1]), v[-1])
        return chain

    def _remove_bias(self, a_s: np.ndarray) -> np.ndarray:
        """Subtract the running mean of the segment so far (m/s^2): exact for a constant bias,
        unlike an exponential mean, whose decaying residual the double integration amplifies."""
        total, count = self._bias
        sums = total + np.cumsum(a_s)
        counts = count + np.arange(1, a_s.size + 1)
        self._bias = (float(sums[-1]), int(counts[-1]))
        return a_s - sums / counts

    def _advance(self, a_s: np.ndarray, stamps: np.ndarray, chain: np.ndarray,
                 speed: np.ndarray, emit: np.ndarray, quality: np.ndarray,
                 u: np.ndarray | None = None) -> Output:
        """Method + band over one segment piece, split only where a filter is redesigned."""
        n0 = self._n
        self._meta.extend(stamps, chain, speed, emit, quality)
        bridged = np.flatnonzero(~emit)
        if bridged.size and self._last_real == np.iinfo(np.int64).max:  # not the end pad
            self._bridged = np.concatenate([self._bridged, n0 + bridged])
        per = self.switch_period
        bounds = np.arange(-(-n0 // per) * per, n0 + a_s.shape[-1], per)  # segment indices
        outs = []
        lo = 0
        while True:
            due = bounds  # empty: no switch boundary in this piece (the usual live push)
            if bounds.size:
                v_kf, v_band = self._targets(bounds)
                due = np.flatnonzero(np.isfinite(v_kf) | np.isfinite(v_band))
            b = int(bounds[due[0]]) - n0 if due.size else a_s.shape[-1]
            if b > lo:
                x = u[:, lo:b] if u is not None else (
                    a_s[..., lo:b] if self._stage is None else self._stage.process(a_s[lo:b]))
                if self._offset is None:
                    self._offset = np.atleast_2d(x)[:, :1].copy()
                outs.append(self._band(np.atleast_2d(x) - self._offset))
            if not due.size:
                return self._join(outs)
            self._redesign(float(v_kf[due[0]]), float(v_band[due[0]]))
            bounds, lo = bounds[due[0] + 1:], b

    def _targets(self, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Design speeds (m/s) due at switch boundaries n (segment sample indices still in the
        delay line), NaN where the current design stays: Kalman gains for the newest sample n,
        band for the middle n - D + P / 2 of the P = ``switch_period`` outputs the design will
        serve (not their first: under acceleration a the speed then misses by a P / 2 at most,
        not a P); both held at min_design_speed_mps."""
        keep = np.full(n.shape, np.nan)
        if n.size == 0:  # the usual live push: no switch boundary inside
            return keep, keep
        cfg = self.config
        speed = self._meta.speed

        def due(v: np.ndarray, current: float) -> np.ndarray:
            return np.where(np.abs(v - current) > cfg.speed_tolerance * current, v, np.nan)

        v_kf = v_band = keep
        vmin = cfg.min_design_speed_mps
        if isinstance(self._stage, KalmanInverse):
            v_kf = due(np.maximum(np.abs(speed[n - self._meta_start]), vmin),
                       self._stage.design.speed)
        if self._fir is not None:
            mid = np.minimum(np.minimum(n - self.delay_samples + self.switch_period // 2, n),
                             self._last_real)  # the end pad has no speed
            v = np.abs(speed[np.maximum(mid, 0) - self._meta_start])
            v_band = due(np.minimum(np.maximum(v, vmin), cfg.max_speed_mps), self._design_speed)
        return v_kf, v_band

    def _redesign(self, v_kf: float, v_band: float) -> None:
        """Apply the designs due (m/s; NaN: keep)."""
        if np.isfinite(v_kf) and isinstance(self._stage, KalmanInverse):
            self._stage.set_speed(v_kf)
            self._counters['redesign'] += 1
        if np.isfinite(v_band) and self._fir is not None:
            self._fir.set_taps(fir_taps(self._response(v_band), self._half))
            self._design_speed = v_band
            self._counters['redesign'] += 1

    def _band(self, x: np.ndarray) -> Output:
        """Band FIR (or pass-through) and the delay line; returns the emitted samples."""
        t_len = x.shape[-1]
        z = np.atleast_2d(x) if self._fir is None else self._fir.process(x)
        d = self.delay_samples
        n_old, self._n = self._n, self._n + t_len
        count = max(0, self._n - d) - max(0, n_old - d)
        first = self._meta_start
        stamps, chain, speed, emit, quality = self._meta.pop(count)
        self._meta_start += count
        every = bool(emit.all())
        keep = slice(None) if every else emit  # no bridged samples: views, no copies
        self._counters['emitted'] += count if every else int(emit.sum())
        quality = self._window_quality(first, quality, speed)
        if self.observability is not None and count:  # a coach: where the data are blind,
            # or the design held at min_design_speed_mps / max_speed_mps has the wrong delays
            cfg, v = self.config, np.abs(speed)
            blind = (self.observability.fraction(speed) > UNOBSERVED_LIMIT) | (
                v < cfg.min_design_speed_mps * (1 - cfg.window_speed_tolerance)) | (
                v > cfg.max_speed_mps * (1 + cfg.window_speed_tolerance))
            quality = np.maximum(quality, np.where(blind, _DEGRADED, _VALID)).astype(np.uint8)
        gap_std = np.sqrt(self._gap_variance(first, count)) if self._gap_var else \
            np.zeros(count)
        return Output(stamps[keep], chain[keep], z[:, t_len - count:][:, keep], quality[keep],
                      speed[keep], gap_std[keep])

    def _gap_variance(self, first: int, count: int) -> np.ndarray:
        """Variance (count,) m^2 of the fill errors at segment indices first.. (the gaps'
        ``error_variance`` summed: independent gaps); forgets the gaps whose reach has passed."""
        var = np.zeros(count)
        for start, v in self._gap_var:
            lo, hi = max(start, first), min(start + v.size, first + count)
            if hi > lo:
                var[lo - first:hi - first] += v[lo - start:hi - start]
        self._gap_var = [(s0, v) for s0, v in self._gap_var if s0 + v.size > first + count]
        return var

    def window_half_width(self, speed_mps: np.ndarray) -> np.ndarray:
        """Significant half-width (input samples) of the band window of outputs at these speeds:
        the taps beyond it hold < WINDOW_TOLERANCE of the L1 norm; it scales as 1 / v with the
        design (held at min_design_speed_mps and max_speed_mps)."""
        fixed, low, r = self._window
        cfg = self.config
        v = np.clip(np.abs(speed_mps), cfg.min_design_speed_mps, cfg.max_speed_mps)
        return fixed + r * np.ceil(low * cfg.min_design_speed_mps / v).astype(np.int64)

    def _half_width_at(self, speed_mps: float) -> int:
        """``window_half_width`` of one output at |speed| ``speed_mps`` (the live push's
        Python-float paths)."""
        fixed, low, r = self._window
        vmin = self.config.min_design_speed_mps
        return fixed + r * math.ceil(low * vmin / min(max(speed_mps, vmin),
                                                      self.config.max_speed_mps))

    def _window_quality(self, first: int, quality: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Input quality of the samples at segment indices first.. raised by their band window
        [n - w, n + w] (w = ``window_half_width``): INVALID where it reaches into the fade-in
        or before the segment start (n < w + taper) or past the segment's last real sample
        (the tail before a reset or flush), at least DEGRADED where it holds a bridged
        sample or where the speed across it is off its band design (``_speed_quality``)."""
        widest = self._window[0] + self._window[1] * self._window[2]
        ramp = round(self.config.taper_s * self.config.rate_hz)
        last = first + quality.size
        if first >= widest + ramp and last - 1 + widest <= self._last_real and (
                self._bridged.size == 0 or self._bridged[-1] < first - widest):
            self._bridged = self._bridged[-1:]  # the usual case: nothing else to raise
            return self._speed_quality(first, quality, speed)
        if quality.size <= SMALL and not self._bridged.size:  # per sample, in Python
            codes = []
            for k, q, v in zip(range(first, last), quality.tolist(), np.abs(speed).tolist(),
                               strict=True):
                half = self._half_width_at(v)
                codes.append(max(q, _INVALID if k < half + ramp or k + half > self._last_real
                                 else q))
            return self._speed_quality(first, np.array(codes, np.uint8), speed)
        n = np.arange(first, last)
        w = self.window_half_width(speed)
        out = np.maximum(quality, np.where((n < w + ramp) | (n + w > self._last_real),
                                           Quality.INVALID, Quality.VALID)).astype(np.uint8)
        if self._bridged.size:
            hits = (np.searchsorted(self._bridged, n + w, side='right')
                    - np.searchsorted(self._bridged, n - w, side='left'))
            out = np.maximum(out, np.where(hits > 0, Quality.DEGRADED, Quality.VALID)
                             ).astype(np.uint8)
            self._bridged = self._bridged[self._bridged >= last - widest]
        return self._speed_quality(first, out, speed)

    def _speed_quality(self, first: int, quality: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Raise to DEGRADED the outputs at segment indices first.. whose band window sees
        speeds off their band design by more than ``window_speed_tolerance`` (relative), and
        count the VALID ones it raises as ``speed_change``. The time-domain band maps the
        wavelengths across its window [n - w, n + w] by the design speed: the speed there is
        off the output's own v(n) by up to dw = max |v(n +- w) - v(n)|, and the design by up
        to dp = max |v(n +- P / 2) - v(n)| (it is the speed in the middle of the P =
        ``switch_period`` outputs it serves) plus ``speed_tolerance``: DEGRADED where
        (dw + dp) / v(n) + speed_tolerance exceeds the tolerance. Speeds are held at
        min_design_speed_mps and max_speed_mps as the design is; the bound does not depend on
        D, so a bank and its nominal pipeline grade alike."""
        if self._fir is None:  # no band FIR: no wavelength mapping
            return quality
        cfg = self.config
        vmin, vmax = cfg.min_design_speed_mps, cfg.max_speed_mps
        tol = cfg.window_speed_tolerance - cfg.speed_tolerance
        half = self.switch_period // 2
        col, lo, hi = self._meta.speeds
        base = lo - self._meta_start  # column index of segment index 0 (may be < 0)
        # the oldest and newest readable samples (the end pad has no speed: its zeros read as
        # a stop made outputs near a flush DEGRADED where the reach outran the INVALID tail)
        floor, top = max(base, 0), min(hi - 1, base + int(self._last_real))
        if quality.size <= SMALL:  # per sample, in Python
            codes, raised = quality.tolist(), 0
            held = col.item  # a Python float per lookup

            def spread(j: int, h: int, vc: float) -> float:
                """max |v - vc| of the held speeds h samples behind and ahead of index j."""
                return max(abs(min(max(abs(held(max(j - h, floor))), vmin), vmax) - vc),
                           abs(min(max(abs(held(min(j + h, top))), vmin), vmax) - vc))
            for i, v in enumerate(np.abs(speed).tolist()):
                j = base + first + i
                vc = min(max(v, vmin), vmax)
                if spread(j, self._half_width_at(v), vc) + spread(j, half, vc) > tol * vc:
                    raised += codes[i] == _VALID
                    codes[i] = max(codes[i], _DEGRADED)
            self._counters['speed_change'] += raised
            return np.array(codes, np.uint8)
        at = base + np.arange(first, first + quality.size)
        own = np.clip(np.abs(speed), vmin, vmax)
        off = np.zeros(quality.size)
        for reach in (self.window_half_width(speed), np.full(at.size, half)):
            back = np.clip(np.abs(col[np.maximum(at - reach, floor)]), vmin, vmax)
            ahead = np.clip(np.abs(col[np.minimum(at + reach, top)]), vmin, vmax)
            off += np.maximum(np.abs(back - own), np.abs(ahead - own))
        raise_ = off > tol * own
        if not raise_.any():
            return quality
        self._counters['speed_change'] += int(np.count_nonzero(raise_ & (quality == _VALID)))
        return np.maximum(quality, np.where(raise_, _DEGRADED, _VALID)).astype(np.uint8)

    def _end_segment(self) -> Output:
        """Emit the samples waiting for a gap's hold, pad the segment with a faded-out
        acceleration, emit what is pending, restart."""
        held = self._gaps.flush()
        out = [] if held is None else [self._feed(*held)]
        d = self.delay_samples
        cfg = self.config
        pending = self._n + sum(x[0].size for x in self._offline)
        if pending:
            fade = 1.0 - taper(np.arange(d), round(cfg.taper_s * cfg.rate_hz))
            pad = (self._last_a * fade, np.zeros(d, np.int64), np.zeros(d), np.zeros(d),
                   np.zeros(d, bool), np.zeros(d, np.uint8))
            self._last_real = pending - 1  # outputs whose window reaches past it: INVALID
            if cfg.smoother:
                a_s, stamps, chain, speed, emit, quality = (
                    np.concatenate(parts) for parts in zip(*self._offline, pad, strict=True))
                self._offline = []
                self._bridged = np.flatnonzero(~emit[:pending])
                if isinstance(self._stage, KalmanInverse):
                    self._stage.set_speed(float(np.median(speed[emit])))
                    out.append(self._advance(a_s, stamps, chain, speed, emit, quality,
                                             u=self._stage.smooth(a_s)))
            else:
                out.append(self._advance(*pad))
        self._start_segment()
        return self._join(out)

    def _join(self, outs: list[Output]) -> Output:
        """Concatenate internal outputs (u always (P, K))."""
        if len(outs) == 1 and len(outs[0]):
            return outs[0]  # what concat returns, without building its empty default
        return Output.concat(outs, self.theta.shape[0])

    def _public(self, out: Output) -> Output:
        """u as (K,) for a single parameter set, (P, K) for a bank."""
        return Output(out.stamps_ns, out.chainage_m, out.u_m[0] if self._squeeze else out.u_m,
                      out.quality, out.speed_mps, out.gap_std_m)
