"""Streaming uncertainty bands and window sensitivities of the reconstructed irregularity.

One :class:`~railgsa_ros.inverse.pipeline.InversionPipeline` runs the P rule points as a single
vectorised bank (theta (P, 5)). Every emitted sample k carries the bank outputs u (P,); its PCE
coefficients are a fixed linear map of them (``Design.projector``), the mean is exact from the
coefficients (c_0), and the lower/upper quantiles come from the surrogate on a fixed scrambled
Sobol' germ sample (``Design.germ_basis``), per sample. The bank is fed by an
:class:`~railgsa_ros.input.stage.InputStage` with the nominal vehicle: its decisions (speed,
noise, sanitiser, quality) are a function of the input data and the inversion config alone, so
they equal those of irregularity_node's policy and the band's stamps and qualities are the
``track/irregularity`` ones one to one (only the emission lags by the bank's longer FIR delay).

Quality: an INVALID sample's band is NaN (lower, mean, upper); near a bridged gap the band
holds the fill's own error (``Output.gap_std_m``, ``uncertainty.terms``); a sample DEGRADED for
another reason (band design held, noise near the limit) is widened by the sensor terms' floor
(std at least max(sigma_u(v), noise_limit_m), sigma_u from the policy's noise floor).
Sensitivity windows use the samples that are not INVALID.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.pipeline import InversionPipeline, Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.samples import join, pieces
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uncertainty.parameters import table3
from railgsa_ros.uncertainty.surrogate import Design, build_design
from railgsa_ros.uncertainty.terms import SensorTerms
from railgsa_ros.uncertainty.windows import Sensitivity, WindowAnalyzer
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import VehicleParams

BLOCK = 256  # samples per quantile block: 2 MB at 1024 germ samples (cache-sized, 10 % faster)
GEMM_ROWS = 16  # samples per BLAS call (16 x 9 x 1024 is below OpenBLAS's threading threshold)
SORT_WIDTH = 256  # float64 values that numpy's SIMD sort sorts with a network (AVX-512)


@dataclass(frozen=True)
class Band:
    """Per emitted IMU sample: stamps_ns (K,) int64, chainage_m (K,), lower_m, mean_m and
    upper_m (K,) in metres (quantiles and PCE mean of the irregularity; NaN where INVALID,
    widened where DEGRADED) and quality (K,) uint8 (Quality codes; None in bands built by
    hand)."""

    stamps_ns: np.ndarray
    chainage_m: np.ndarray
    lower_m: np.ndarray
    mean_m: np.ndarray
    upper_m: np.ndarray
    quality: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.stamps_ns.size)

    @classmethod
    def concat(cls, bands: list[Band]) -> Band:
        """Join bands in order."""
        empty = np.zeros(0)
        return join(bands, cls(np.zeros(0, np.int64), empty, empty, empty, empty,
                               np.zeros(0, np.uint8)))


@dataclass(frozen=True)
class Update:
    """What one push/flush produced: the band samples, the closed windows' records, the bank
    outputs (P, K) m of the band samples (one row per rule point; NaN where INVALID) and their
    sensor std (K,) m (``uncertainty.terms``)."""

    band: Band
    windows: list[Sensitivity]
    bank_u_m: np.ndarray | None = None
    sensor_std_m: np.ndarray | None = None


def band_statistics(design: Design, quantiles: tuple[float, float], u: np.ndarray,
                    sensor_std_m: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lower, mean, upper), each (K,), from bank outputs u (P, K) in metres; ``sensor_std_m``
    (K,) m: the independent sensor terms (``uncertainty.terms``), added to surrogate sample j as
    sensor_std_m * design.noise_germ[j].

    The mean is the PCE's c_0. The quantiles are those of ``np.quantile`` (method 'linear') over
    the S surrogate samples c_0 + c[1:] @ germ_basis: the two ranks around each quantile are
    selected exactly by :func:`order_statistics` (2.1 us per row of 1024 on one core, where
    ``np.quantile``'s partition takes 12 us) and interpolated as ``np.quantile`` does. The
    products run as stacked (GEMM_ROWS, T) x (T, S) BLAS calls, the sensor std being one more
    coefficient of the noise germ (the sum's last rounding is BLAS's: a separate outer product
    and addition took as long as the product itself, 0.75 us per row of 1024): each call stays
    below OpenBLAS's threading threshold, so a multi-threaded OpenBLAS never spins threads here
    (on the loaded 2-core machine that took 22 ms for one (50, 19) x (19, 1024) product), the
    sums of each row are the same whatever the chunking, and it is 20x faster than einsum.
    """
    coef = pce_coefficients(design, u)
    count, size = coef.shape[0], design.germ_basis.shape[1]
    pos = np.asarray(quantiles) * (size - 1)
    rank = np.floor(pos).astype(np.int64)
    frac = pos - rank
    rows = -(-count // GEMM_ROWS) * GEMM_ROWS
    dev = np.zeros((rows, coef.shape[1]))  # c[1:] and the sensor std: one product
    dev[:count, :-1] = coef[:, 1:]
    if sensor_std_m is not None:
        dev[:count, -1] = sensor_std_m
    germ = np.vstack([design.germ_basis, design.noise_germ])  # (T, S)
    bounds = np.empty((rows, 2))
    for lo in range(0, rows, BLOCK):
        block = dev[lo:lo + BLOCK]
        surrogate = (block.reshape(-1, GEMM_ROWS, block.shape[1]) @ germ
                     ).reshape(block.shape[0], size)  # deviations from the mean, (K', S)
        picked = order_statistics(surrogate, np.concatenate([rank, rank + 1]))
        below, above = picked[:, :2], picked[:, 2:]
        bounds[lo:lo + BLOCK] = below + (above - below) * frac
    mean = coef[:, 0]
    return mean + bounds[:count, 0], mean, mean + bounds[:count, 1]


def pce_coefficients(design: Design, u: np.ndarray) -> np.ndarray:
    """PCE coefficients (K, T) of bank outputs u (P, K) m; column 0 is the mean."""
    return np.einsum('tp,pk->kt', design.projector, u)


def deviation_bound(design: Design, u: np.ndarray, sensor_std_m: np.ndarray) -> np.ndarray:
    """A bound (K,) m on |surrogate sample - mean| over every germ sample of the band of bank
    outputs u (P, K) with sensor terms (K,) m (Cauchy-Schwarz on c[1:] . psi_j + s n_j): each
    quantile of :func:`band_statistics` lies within mean +- bound. NaN where u is."""
    coef = pce_coefficients(design, u)
    reach = np.sqrt(np.max(np.sum(design.germ_basis ** 2, axis=0) + design.noise_germ ** 2))
    return np.sqrt(np.sum(coef[:, 1:] ** 2, axis=1) + np.square(sensor_std_m)) * reach


def order_statistics(values: np.ndarray, ranks: np.ndarray) -> np.ndarray:
    """``np.sort(values, axis=1)[:, ranks]`` for values (K, S) and 0-based ranks (R,): (K, R),
    the same floats (NaN sorts last, as in ``np.sort``). ``values`` (C-contiguous) is scratch:
    its rows are sorted in place, piecewise (saves a copy: 10 % of the band's time).

    Why not one sort per row: numpy's SIMD sort (x86-simd-sort) sorts up to SORT_WIDTH float64
    with a sorting network, so 4 pieces of 256 sort about twice as fast as one row of 1024.
    For ranks in the tails, each row is cut into pieces of at most SORT_WIDTH values and each
    piece is sorted; the n smallest values of a row are among the n smallest of its pieces (and
    the n largest among the n largest), so one more sort of those candidates gives them
    exactly. Rows of 1024 with the default 2.5 and 97.5 % quantiles (n = 27): 2.1 instead of
    3.5 us per row of a review's surrogate samples (1.4 instead of 2.4 us for normal random
    rows; one core, AVX-512). Ranks the candidates cannot cover in one network sort (central
    quantiles, S not a multiple of the piece count) get the full sort.
    """
    count, size = values.shape
    ranks = np.asarray(ranks)
    pieces = -(-size // SORT_WIDTH)
    n_low = int(ranks[ranks < size // 2].max(initial=-1)) + 1  # smallest values needed
    n_high = size - int(ranks[ranks >= size // 2].min(initial=size))  # largest values needed
    if pieces == 1 or size % pieces or max(n_low, n_high) * pieces > SORT_WIDTH:
        values.sort(axis=1)
        return values[:, ranks]
    width = size // pieces
    parts = values.reshape(count * pieces, width)  # a view: values is contiguous
    parts.sort(axis=1)
    rows = parts.reshape(count, pieces, width)
    lowest = np.sort(rows[:, :, :n_low].reshape(count, -1), axis=1)  # (K, pieces n_low)
    highest = np.sort(rows[:, :, width - n_high:].reshape(count, -1), axis=1)
    low = ranks < size // 2
    out = np.empty((count, ranks.size))
    out[:, low] = lowest[:, ranks[low]]
    out[:, ~low] = highest[:, ranks[~low] - size + pieces * n_high]
    return out


class UncertaintyStream:
    """Chunks of IMU samples in, per-sample bands and per-window sensitivities out.

    ``config``: UncertaintyConfig (its ``inversion`` must equal irregularity_node's config for
    the stamps to match); ``vehicle``: nominal parameters (Table 1 by default); ``dists``:
    uncertain parameter name -> Distribution (Table 3 around ``vehicle`` by default);
    ``noise_variance``: a fixed accelerometer variance, (m/s^2)^2 (None: the policy's rule);
    ``options``: the policy's InputOptions; ``quantiles`` False: the bands hold the mean
    only (lower/upper NaN: the review computes the quantiles of the samples it keeps);
    ``stage``: an input stage of the same stream to share (offline: the nominal one, which
    then feeds the bank pipeline; ``update`` and ``close`` take its ``bank_outputs``), None:
    a stage of its own (``odometry``, ``imu``, ``flush``).
    """

    def __init__(self, config: UncertaintyConfig | None = None,
                 vehicle: VehicleParams | None = None,
                 dists: Mapping[str, Distribution] | None = None,
                 noise_variance: float | None = None,
                 options: InputOptions | None = None, *, defer: bool = False,
                 quantiles: bool = True, stage: InputStage | None = None) -> None:
        self.config = config if config is not None else UncertaintyConfig()
        vehicle = vehicle if vehicle is not None else VehicleParams()
        self.design = build_design(self.config, vehicle,
                                   dists if dists is not None else table3(vehicle))
        if stage is None:
            stage = InputStage(self.config.inversion, vehicle, bank=self.design.theta,
                               options=options, noise_variance=noise_variance)
        else:
            stage.feed_bank(self.design.theta)
        self.policy = stage
        # the sensor terms use the policy's noise floor (its noise decision from the data)
        self.terms = SensorTerms(self.config, self.policy.noise.sigma_m)
        self.windows = WindowAnalyzer(self.config, self.design, defer=defer)
        self._quantiles = ((self.config.lower_quantile, self.config.upper_quantile)
                           if quantiles else None)

    @property
    def pipeline(self) -> InversionPipeline:
        """The bank pipeline (built now if the policy has not decided the noise yet)."""
        return self.policy.start()

    @property
    def counters(self) -> dict[str, int]:
        """The policy's counters: rejected samples by reason, gaps, resets, quality, ..."""
        return self.policy.counters

    @property
    def delay_samples(self) -> int:
        """Samples between an IMU sample's arrival and its band output (the bank's FIR delay)."""
        return self.pipeline.delay_samples

    def odometry(self, stamps_ns: np.ndarray, speed_mps: np.ndarray) -> Update:
        """Odometry samples, as ``InputStage.odometry``."""
        return self.update(self.policy.odometry(stamps_ns, speed_mps))

    def imu(self, stamps_ns: np.ndarray, accel: np.ndarray,
            frame_ids: np.ndarray | None = None,
            covariance: np.ndarray | None = None) -> Update:
        """IMU samples, as ``InputStage.imu``: stamps (T,) ns, accel (T, 3) m/s^2, frame ids
        (T,), REP 145 covariance (T, 9)."""
        return self.update(self.policy.imu(stamps_ns, accel, frame_ids, covariance))

    def push(self, stamps_ns: np.ndarray, acc_z: np.ndarray,
             speed_mps: np.ndarray | float | None = None,
             frame_ids: np.ndarray | None = None) -> Update:
        """Vertical samples straight into the bank pipeline, past the input policy (its
        sanitiser and delay-line quality only; no speed, noise, mounting, gravity or rate
        decision): the bank's own tests and benchmarks. The node and the CLI use ``imu`` and
        ``odometry``."""
        return self.update(self.policy.finish(self.pipeline.push(stamps_ns, acc_z, speed_mps,
                                                                 frame_ids)))

    def flush(self) -> Update:
        """End of a stream (or a restart): emit every pending sample, close the window."""
        return self.close(self.policy.flush())

    def close(self, out: Output) -> Update:
        """Band and windows of a stream's last outputs ``out``; the open window closed."""
        update = self.update(out)
        return Update(update.band, update.windows + self.windows.close(), update.bank_u_m,
                      update.sensor_std_m)

    def analyze_deferred(self) -> list[Sensitivity]:
        """With ``defer``: the records of the windows closed so far, in order."""
        return self.windows.analyze_deferred()

    def update(self, out: Output) -> Update:
        """Band and closed windows of policy outputs ``out`` (u (P, K), NaN where INVALID)."""
        band, sensor = band_update(self.design, self.terms, self._quantiles, out)
        return Update(band, self.windows.push(out.stamps_ns, out.chainage_m, band.mean_m,
                                              out.u_m, out.graded != Quality.INVALID),
                      out.u_m, sensor)


def band_update(design: Design, terms: SensorTerms, quantiles: tuple[float, float] | None,
                out: Output) -> tuple[Band, np.ndarray]:
    """The band of bank outputs ``out`` (u (P, K)) and its sensor std (K,) m from ``terms``
    (streamed: call in output order)."""
    sensor = terms.std(out.stamps_ns, design.projector[0] @ out.u_m, out.speed_mps,
                       out.quality, out.gap_std_m, out.chainage_m)
    return bank_band(design, quantiles, out, sensor), sensor


def bank_band(design: Design, quantiles: tuple[float, float] | None, out: Output,
              sensor_std_m: np.ndarray) -> Band:
    """The band of bank outputs ``out`` with the sensor terms ``sensor_std_m`` (K,) m: NaN
    where INVALID (the statistics run on the other samples only); ``quantiles`` None: the
    mean only (the PCE's c_0, as ``band_statistics`` has it), lower and upper NaN."""
    good = out.graded != Quality.INVALID
    if quantiles is None:
        nan = np.full(len(out), np.nan)
        mean = np.where(good, pce_coefficients(design, out.u_m)[:, 0], np.nan)
        return Band(out.stamps_ns, out.chainage_m, nan, mean, nan.copy(), out.quality)
    if good.all():
        lower, mean, upper = band_statistics(design, quantiles, out.u_m, sensor_std_m)
        return Band(out.stamps_ns, out.chainage_m, lower, mean, upper, out.quality)
    lower, mean, upper = (np.full(len(out), np.nan) for _ in range(3))
    if good.any():
        lower[good], mean[good], upper[good] = band_statistics(
            design, quantiles, out.u_m[:, good], sensor_std_m[good])
    return Band(out.stamps_ns, out.chainage_m, lower, mean, upper, out.quality)


def offline_bands(stamps_ns: np.ndarray, accel: np.ndarray,
                  odometry: tuple[np.ndarray, np.ndarray] | None = None,
                  frame_ids: np.ndarray | None = None,
                  covariance: np.ndarray | None = None,
                  config: UncertaintyConfig | None = None,
                  vehicle: VehicleParams | None = None,
                  dists: Mapping[str, Distribution] | None = None,
                  noise_variance: float | None = None,
                  options: InputOptions | None = None) -> Band:
    """Bands of a whole stream in memory (tests, calibration ensembles): the node's streaming
    code, odometry (stamps, speeds) first, then the IMU in ``samples.CHUNK`` pieces, flushed;
    stamps equal the nominal policy's stamps for the same input."""
    config = (config if config is not None else UncertaintyConfig()).with_(qoi='')
    stream = UncertaintyStream(config, vehicle, dists, noise_variance, options)
    parts = [stream.odometry(*odometry).band] if odometry is not None else []
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    for sl in pieces(stamps.size):
        parts.append(stream.imu(stamps[sl], accel[sl],
                                None if frame_ids is None else frame_ids[sl],
                                None if covariance is None else covariance[sl]).band)
    parts.append(stream.flush().band)
    return Band.concat(parts)
