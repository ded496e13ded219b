"""The nodes' streaming core run offline over a recorded IMU stream, in chunks, without DDS.

Two streams see the same chunks: the nominal ``InversionPipeline`` (``irregularity_node``: the
reconstruction) and the rule-point bank of ``uncertainty_node``, composed from the pieces of
:class:`~railgsa_ros.uncertainty.UncertaintyStream` (the design, ``band_statistics`` and the
``WindowAnalyzer``) so that the bank outputs at the worst sample can be kept for its histogram.
The two outputs carry the same stamps one to one (the bank only emits later); they are joined on
the stamps at the end. Speed: the newest odometry sample at or before each stamp (held), the
configured speed when the bag has no odometry.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from railgsa_ros.bag import ImuStream
from railgsa_ros.errors import InputError
from railgsa_ros.inverse.pipeline import InversionPipeline, Output, vertical
from railgsa_ros.uncertainty import Band, Sensitivity, UncertaintyConfig
from railgsa_ros.uncertainty.stream import band_statistics
from railgsa_ros.uncertainty.surrogate import Design, build_design
from railgsa_ros.uncertainty.windows import WindowAnalyzer
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import VehicleParams

CHUNK = 65536  # IMU samples per push (as railgsa invert)


@dataclass(frozen=True)
class Worst:
    """The sample of largest |PCE mean|: stamp (ns), chainage (m), PCE mean (m) and the bank
    outputs (P,) m there."""

    stamp_ns: int
    chainage_m: float
    mean_m: float
    bank_u_m: np.ndarray


@dataclass(frozen=True)
class ReviewRun:
    """Result of one offline run, per emitted sample (K,): stamps (ns), chainage (m), speed (m/s),
    nominal reconstruction u (m); the band (lower/mean/upper, same stamps) or None; window
    sensitivity records; the worst sample; the nominal pipeline's counters and band delay."""

    stamps_ns: np.ndarray
    chainage_m: np.ndarray
    speed_mps: np.ndarray
    u_m: np.ndarray
    band: Band | None
    windows: list[Sensitivity]
    worst: Worst | None
    design: Design | None
    counters: dict[str, int]
    delay_samples: int

    def __len__(self) -> int:
        return int(self.stamps_ns.size)


def held_speed(stamps_ns: np.ndarray, odom_stamps_ns: np.ndarray, odom_speed_mps: np.ndarray,
               default_mps: float) -> np.ndarray:
    """Speed (m/s) at each stamp: the newest odometry at or before it (the first one before the
    odometry starts); ``default_mps`` everywhere when there is no odometry."""
    if odom_stamps_ns.size == 0:
        return np.full(np.shape(stamps_ns), float(default_mps))
    order = np.argsort(odom_stamps_ns, kind='stable')
    idx = np.searchsorted(odom_stamps_ns[order], stamps_ns, side='right') - 1
    return odom_speed_mps[order][np.clip(idx, 0, None)]


class _Bank:
    """The uncertainty node's bank: pipeline over the rule points, band, windows, worst sample."""

    def __init__(self, config: UncertaintyConfig, vehicle: VehicleParams,
                 dists: Mapping[str, Distribution], noise_variance: float | None) -> None:
        self.design = build_design(config, vehicle, dists)
        self.pipeline = InversionPipeline(config.inversion, self.design.theta, noise_variance)
        self.windows = WindowAnalyzer(config, self.design, defer=True)
        self.quantiles = (config.lower_quantile, config.upper_quantile)
        self.bands: list[Band] = []
        self.records: list[Sensitivity] = []
        self.worst: Worst | None = None

    def take(self, out: Output) -> None:
        """Band, windows and worst sample of one pipeline output."""
        if len(out) == 0:
            return
        lower, mean, upper = band_statistics(self.design, self.quantiles, out.u_m)
        self.bands.append(Band(out.stamps_ns, out.chainage_m, lower, mean, upper))
        self.windows.push(out.stamps_ns, out.chainage_m, mean, out.u_m)
        k = int(np.argmax(np.abs(mean)))
        if self.worst is None or abs(mean[k]) > abs(self.worst.mean_m):
            self.worst = Worst(int(out.stamps_ns[k]), float(out.chainage_m[k]), float(mean[k]),
                               out.u_m[:, k].copy())

    def finish(self) -> None:
        """Close the last window; the delta estimates of all windows, in batches."""
        self.windows.close()
        self.records = self.windows.analyze_deferred()


def _noise_variance(stream: ImuStream, config: UncertaintyConfig) -> float | None:
    """Median recorded accelerometer variance on the vertical axis ((m/s^2)^2), None if none."""
    inv = config.inversion
    var = stream.accel_variance(inv.noise_std_mps2 ** 2)[:, 'xyz'.index(inv.accel_axis[-1])]
    known = var[np.isfinite(var)]
    return float(np.median(known)) if known.size else None


def run_stream(stream: ImuStream, config: UncertaintyConfig, vehicle: VehicleParams,
               dists: Mapping[str, Distribution] | None, chunk: int = CHUNK,
               progress: Callable[[int], None] | None = None) -> ReviewRun:
    """Push ``stream`` through the nominal pipeline (and the bank unless ``dists`` is None) in
    chunks of ``chunk`` samples; ``progress(samples_done)`` after each chunk."""
    inv = config.inversion
    variance = _noise_variance(stream, config)
    nominal = InversionPipeline(inv, vehicle, variance)
    bank = _Bank(config, vehicle, dists, variance) if dists is not None else None
    speed = held_speed(stream.stamps_ns, stream.odom_stamps_ns, stream.speed_mps, inv.speed_mps)
    acc = vertical(stream.accel, inv.accel_axis)
    outs = []
    for lo in range(0, stream.stamps_ns.size, chunk):
        sl = slice(lo, lo + chunk)
        args = (stream.stamps_ns[sl], acc[sl], speed[sl], stream.frame_ids[sl])
        outs.append(nominal.push(*args))
        if bank is not None:
            bank.take(bank.pipeline.push(*args))
        if progress is not None:
            progress(min(lo + chunk, stream.stamps_ns.size))
    outs.append(nominal.flush())
    out = Output(*(np.concatenate([getattr(o, f) for o in outs])
                   for f in ('stamps_ns', 'chainage_m', 'u_m')))
    if len(out) == 0:
        raise InputError(f'{stream.path}: no usable IMU sample (rejected: '
                         f'{_rejections(nominal.counters)})')
    band = None
    if bank is not None:
        bank.take(bank.pipeline.flush())
        bank.finish()
        band = Band.concat(bank.bands)
        if not np.array_equal(band.stamps_ns, out.stamps_ns):
            raise AssertionError('band and irregularity stamps differ')
    out_speed = held_speed(out.stamps_ns, stream.odom_stamps_ns, stream.speed_mps, inv.speed_mps)
    return ReviewRun(out.stamps_ns, out.chainage_m, out_speed, out.u_m, band,
                     bank.records if bank else [], bank.worst if bank else None,
                     bank.design if bank else None, nominal.counters, nominal.delay_samples)


def _rejections(counters: dict[str, int]) -> str:
    """'nan 3, saturated 10' for the nonzero counters."""
    return ', '.join(f'{k} {v}' for k, v in sorted(counters.items()) if v) or 'none'
