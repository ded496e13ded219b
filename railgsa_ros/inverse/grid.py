"""The profile at a fixed chainage step, band-passed on distance (the sampling EN 13848 uses).

EN 13848 bands are wavelength bands. At constant speed a time-domain band is the same filter;
at variable speed its design follows the speed only sample by sample, so when the train
accelerates or brakes its window maps wavelengths off the band (measured: 0.11 mm RMS D1 error
on a run with 1.6 m/s^2 braking and a stop, against 0.07 mm for this grid; docs/inversion.md,
"Band on distance"). ``ChainageGrid`` takes the outputs of a pipeline run with the wider
time-domain pre-band ``pre_band(band)`` (a factor PRE_FACTOR beyond each edge, order
PRE_ORDER: flat over the band however the speed moves within the window), resamples them
linearly to x_j = j * step_m and filters the grid with the zero-phase band FIR |BP|^2 in
wavenumber (``band.py`` designs it with 1 / step_m as the sample rate, so D1 at 0.25 m is
exactly the scorer's filter). A grid point carries the stamp of the IMU sample it came from,
the one nearest to it in chainage (the rule of every topic: a stamp of a real sample; it is
within half an IMU period of when the wheel passed the point), and the worst quality of the
inputs in its FIR window (INVALID: u = NaN); a chainage jump of more than GAP_STEPS steps
between two outputs (a restart, a bridged dropout) is interpolated and DEGRADED. Only forward
running makes a grid (samples whose chainage does not increase are counted as ``not_forward``
and skipped: at standstill there is nothing to resample). With ``band`` None the grid is the
pre-band profile resampled, for users who filter on distance themselves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from railgsa_ros.errors import ConfigError
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.band import (
    band_limits,
    bandpass_power,
    design_grid,
    fir_taps,
    half_length,
)
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.convolve import PartitionedFir
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.models import VehicleModel
from railgsa_ros.samples import join
from railgsa_ros.vehicle import VehicleParams

PRE_FACTOR = 2.0  # the time-domain pre-band reaches this factor beyond each band edge
PRE_ORDER = 4  # its Butterworth order: |BP|^2 >= 0.998 at the band edges
#: the pre-band's speed tolerance across its window: a speed 20 % off its design maps the band
#: edges 1.2 times closer to the pre-band's, where |BP|^2 is still >= 0.985 (the band's own
#: edges lie at -6 dB); the band on distance follows the speed exactly
PRE_SPEED_TOLERANCE = 0.2
GAP_STEPS = 4  # outputs further apart than this many steps: the grid between is DEGRADED
DEFAULT_STEP_M = 0.25


def pre_band(band: str) -> str:
    """Time-domain band 'LMIN:LMAX' that the pipeline runs before the distance band."""
    lmin, lmax = band_limits(band)
    return f'{lmin / PRE_FACTOR:g}:{lmax * PRE_FACTOR:g}'


def grid_config(config: InversionConfig) -> InversionConfig:
    """The pipeline configuration in front of ``ChainageGrid.for_config(config)``: the same
    settings with the time-domain pre-band of config.band."""
    return config.with_(band=pre_band(config.band), band_order=PRE_ORDER,
                        window_speed_tolerance=PRE_SPEED_TOLERANCE)


@dataclass(frozen=True)
class GridOutput:
    """Profile on the grid: chainage_m (K,) multiples of the step, u_m (K,) in m (NaN where
    INVALID), stamps_ns (K,) int64 of the IMU sample nearest in chainage, quality (K,) uint8."""

    chainage_m: np.ndarray
    u_m: np.ndarray
    stamps_ns: np.ndarray
    quality: np.ndarray

    def __len__(self) -> int:
        return int(self.chainage_m.size)

    @classmethod
    def concat(cls, outs: list[GridOutput]) -> GridOutput:
        """Join grid outputs in order."""
        return join(outs, _EMPTY)


_EMPTY = GridOutput(np.zeros(0), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.uint8))


class ChainageGrid:
    """Streaming resampler to chainage multiples of ``step_m`` (m) with the distance band
    ``band`` (band name, None: no band) of Butterworth order ``order``, FIR cut at
    ``tolerance`` (``band.half_length``). Output j leaves when grid point j + delay has been
    made (``delay_m`` = delay * step_m of chainage)."""

    def __init__(self, step_m: float = DEFAULT_STEP_M, band: str | None = 'd1',
                 order: int = 2, tolerance: float = 1e-5) -> None:
        if not (np.isfinite(step_m) and 0.0 < step_m <= 10.0):
            raise ConfigError(f'grid: expected a chainage step in (0, 10] m, got {step_m!r}')
        self.step_m = float(step_m)
        self.delay = 0
        self._fir: PartitionedFir | None = None
        if band is not None:
            lmin, lmax = band_limits(band)
            if lmin < 2 * step_m:
                raise ConfigError(f'grid: a {step_m:g} m step cannot hold {lmin:g} m waves '
                                  f'(at least 2 steps per wave)')
            k = design_grid(1.0 / step_m, 1.0 / lmax)
            response = bandpass_power(k, 1.0 / lmax, 1.0 / lmin, order)
            self.delay = half_length(response, tolerance)
            self._fir = PartitionedFir(fir_taps(response, self.delay), 1)
        self.counters = {'grid': 0, 'not_forward': 0}
        self.reset()

    @classmethod
    def for_config(cls, config: InversionConfig, step_m: float = DEFAULT_STEP_M
                   ) -> ChainageGrid:
        """The grid with config's band, band_order and fir_tolerance (pipeline in front:
        ``grid_config(config)``)."""
        return cls(step_m, config.band, config.band_order, config.fir_tolerance)

    @property
    def delay_m(self) -> float:
        """Chainage between the newest grid point and the newest output, m."""
        return self.delay * self.step_m

    def reset(self) -> None:
        """Forget the stream (a new run)."""
        self._last: tuple[float, float, int, int] | None = None  # chainage, u, stamp, quality
        self._next: int | None = None  # index of the next grid point
        self._pending = GridOutput.concat([])  # grid points in the FIR delay line
        self._emitted = 0  # grid points emitted since the start
        # raw quality from grid index _q0 on; the d points before the start are INVALID
        self._q = np.full(self.delay, Quality.INVALID, np.uint8)
        self._q0 = -self.delay
        if self._fir is not None:
            self._fir.reset()

    def push(self, out: Output) -> GridOutput:
        """Take pipeline outputs (u (K,); chainage in stamp order); returns finished points."""
        if out.u_m.ndim != 1:
            raise ConfigError('grid: expected one parameter set (u of shape (K,))')
        q_in = out.quality if out.quality is not None else np.zeros(len(out), np.uint8)
        c, u, t, q = self._forward(out.chainage_m, out.u_m, out.stamps_ns, q_in)
        if c.size < 2:  # nothing to interpolate yet: a first sample is kept for the next push
            if c.size:
                self._last = (float(c[-1]), float(u[-1]), int(t[-1]), int(q[-1]))
            return GridOutput.concat([])
        j0 = self._next if self._next is not None else int(np.ceil(c[0] / self.step_m))
        j1 = int(np.floor(c[-1] / self.step_m))
        self._last = (float(c[-1]), float(u[-1]), int(t[-1]), int(q[-1]))
        if j1 < j0:
            return GridOutput.concat([])
        self._next = j1 + 1
        x = np.arange(j0, j1 + 1) * self.step_m
        k = np.clip(np.searchsorted(c, x, side='right'), 1, c.size - 1)  # c[k-1] <= x < c[k]
        raw_q = np.maximum(q[k - 1], q[k])
        raw_q = np.maximum(raw_q, np.where(c[k] - c[k - 1] > GAP_STEPS * self.step_m,
                                           Quality.DEGRADED, Quality.VALID)).astype(np.uint8)
        values = np.interp(x, c, np.where(q == Quality.INVALID, 0.0, u))
        values[raw_q == Quality.INVALID] = 0.0  # nothing non-finite reaches the FIR
        stamps = np.where(x - c[k - 1] <= c[k] - x, t[k - 1], t[k])  # the nearest sample
        self.counters['grid'] += x.size
        return self._filter(GridOutput(x, values, stamps, raw_q))

    def flush(self) -> GridOutput:
        """End of the stream: the last points come out (their window reaches past the end:
        INVALID); the next push starts afresh."""
        pad = self.delay
        out = _EMPTY
        if pad and self._next is not None:
            x = (self._next + np.arange(pad)) * self.step_m
            out = self._filter(GridOutput(x, np.zeros(pad), np.full(pad, -1, np.int64),
                                          np.full(pad, Quality.INVALID, np.uint8)))
        self.reset()
        return out

    def _forward(self, c: np.ndarray, u: np.ndarray, t: np.ndarray, q: np.ndarray
                 ) -> tuple[np.ndarray, ...]:
        """The samples whose chainage increases past every earlier one, after the last kept."""
        if self._last is not None:
            c0, u0, t0, q0 = self._last
            c, u, t, q = (np.concatenate([[a], b]) for a, b in
                          zip((c0, u0, t0, q0), (c, u, t, q), strict=True))
        start = 1 if self._last is not None else 0
        ahead = c > np.maximum.accumulate(np.concatenate([[-np.inf], c[:-1]]))
        ahead[:start] = True
        self.counters['not_forward'] += int((~ahead[start:]).sum())
        return c[ahead], u[ahead], t[ahead].astype(np.int64), q[ahead].astype(np.uint8)

    def _filter(self, g: GridOutput) -> GridOutput:
        """Distance band FIR and window quality; returns the points whose window is complete:
        point j leaves with FIR output j + delay, at the worst raw quality in [j - d, j + d]
        (before the first point: INVALID, the warm-up)."""
        if self._fir is None:
            u = np.where(g.quality == Quality.INVALID, np.nan, g.u_m)
            return GridOutput(g.chainage_m, u, g.stamps_ns, g.quality)
        d = self.delay
        z = self._fir.process(g.u_m)[0]
        self._pending = GridOutput.concat([self._pending, g])
        self._q = np.concatenate([self._q, g.quality])
        count = max(0, self._fir.n_total - d) - self._emitted
        if count <= 0:
            return GridOutput.concat([])
        first = self._emitted - d - self._q0  # window start of the first point, in _q
        quality = sliding_window_view(self._q[first:first + count + 2 * d], 2 * d + 1).max(1)
        head = self._pending
        emit = GridOutput(head.chainage_m[:count], np.where(quality == Quality.INVALID, np.nan,
                                                            z[z.size - count:]),
                          head.stamps_ns[:count], quality.astype(np.uint8))
        self._pending = GridOutput(head.chainage_m[count:], head.u_m[count:],
                                   head.stamps_ns[count:], head.quality[count:])
        self._emitted += count
        drop = self._emitted - d - self._q0  # raw quality no window needs any more
        self._q, self._q0 = self._q[drop:], self._q0 + drop
        return emit


class GridStream:
    """IMU and odometry in, the profile on the chainage grid out: an InputStage with the
    pre-band (``grid_config(config)``) and ``ChainageGrid.for_config(config, step_m)`` behind
    it, the pair ``railgsa invert --grid`` runs (through offline.Driver), as one object for a
    node. Methods as InputStage's; each returns the grid points that are finished."""

    def __init__(self, config: InversionConfig,
                 vehicle: VehicleParams | np.ndarray | VehicleModel | None = None,
                 options: InputOptions | None = None, step_m: float = DEFAULT_STEP_M,
                 noise_variance: float | None = None) -> None:
        self.grid = ChainageGrid.for_config(config, step_m)
        self._band = (config.band, config.band_order, config.fir_tolerance)
        self.policy = InputStage(grid_config(config), vehicle, options=options,
                                  noise_variance=noise_variance)

    def odometry(self, stamps_ns: np.ndarray, speed_mps: np.ndarray) -> GridOutput:
        """Odometry samples (the IMU samples they release reach the grid)."""
        return self.grid.push(self.policy.odometry(stamps_ns, speed_mps))

    def imu(self, stamps_ns: np.ndarray, accel: np.ndarray, frame_ids: np.ndarray | None = None,
            covariance: np.ndarray | None = None) -> GridOutput:
        """IMU samples: stamps (T,) ns, accel (T, 3) m/s^2, frame ids, REP 145 covariance."""
        return self.grid.push(self.policy.imu(stamps_ns, accel, frame_ids, covariance))

    def flush(self) -> GridOutput:
        """End of the stream: the policy's pending outputs, then the grid's last points."""
        return GridOutput.concat([self.grid.push(self.policy.flush()), self.grid.flush()])

    def rebuild(self, config: InversionConfig, vehicle: VehicleParams | np.ndarray | None = None,
                options: InputOptions | None = None) -> GridOutput:
        """A parameter change: the policy rebuilt with the new pre-band (its pending outputs
        reach the grid, the chainage continues); a new distance band ends the old grid first."""
        outs = [self.grid.push(self.policy.rebuild(grid_config(config), vehicle,
                                                   options=options))]
        band = (config.band, config.band_order, config.fir_tolerance)
        if band != self._band:
            outs.append(self.grid.flush())
            self.grid, self._band = ChainageGrid.for_config(config, self.grid.step_m), band
        return GridOutput.concat(outs)
