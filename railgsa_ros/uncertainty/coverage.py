"""Calibration of the band: how often it holds the truth on simulated runs drawn from the priors.

An ensemble run draws its TRUE vehicle from the uncertain-parameter law (``draw_vehicle``) and its
TRUE sensor around a preset (``draw_sensor``: noise density x lognormal(0, 0.3), scale factor
N(0, preset's), bias N(0, preset's) per axis, the preset's dropouts); the band is computed with the
nominal vehicle, the law and the preset's datasheet noise (what a user knows). ``coverage`` is the
fraction of the band's published samples (not INVALID, away from the ends) whose truth,
band-passed on distance as the inversion does, lies inside the band of each nominal level; the
same split into the samples within NEAR_M of a dropout (of the last sample before it or the first
after it) and the others (the gap term's test).
``with_dropouts`` cuts dropouts of a chosen length into a run (the gap term at 0.2-1 s).
``bank_coverage`` scores the bands of a bank pipeline driven directly (a coach: every level's
band from one run of the bank, its estimator's error term included).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace

import numpy as np

from railgsa_ros.imu import ImuSpec, accel_covariance, imu_spec
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, Output, vertical
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.models import VehicleModel, as_model
from railgsa_ros.scenario import Run
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uncertainty.stream import Band, bank_band, offline_bands
from railgsa_ros.uncertainty.surrogate import Design
from railgsa_ros.uncertainty.terms import SensorTerms, bank_terms
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import VehicleParams

NOISE_SPREAD = 0.3  # log-std of the true noise density around the datasheet value
DX_M = 0.25  # distance grid of the band-passed truth, m
MARGIN_M = 100.0  # left out at both ends (filter edges), m
NEAR_M = 50.0  # a sample this close to a dropout is "near" it, m


def draw_vehicle(nominal: VehicleParams | VehicleModel, dists: Mapping[str, Distribution],
                 rng: np.random.Generator) -> np.ndarray:
    """A true theta (n,) of the model (the quarter car's VehicleParams: (5,)): the uncertain
    parameters drawn from ``dists``, the rest nominal."""
    model = as_model(nominal)
    theta = model.theta.copy()
    for name, dist in dists.items():
        theta[model.param_names.index(name)] = float(dist.sample(1, rng)[0])
    return theta


def draw_sensor(preset: str, rng: np.random.Generator) -> ImuSpec:
    """A true sensor around a preset (module docstring)."""
    spec = imu_spec(preset)
    return replace(spec, name=f'{preset}-drawn',
                   noise_density=spec.noise_density * float(np.exp(NOISE_SPREAD *
                                                                   rng.standard_normal())),
                   scale_factor=spec.scale_factor * float(rng.standard_normal()),
                   bias=tuple(np.asarray(spec.bias) * rng.standard_normal(3)))


def with_dropouts(run: Run, starts_s: Sequence[float], length_s: float) -> Run:
    """The run without its samples stamped within [start, start + length_s) s of the first
    stamp, for each start (s): dropouts of that length (``Run.track`` keeps the truth)."""
    t = (run.stamps_ns - run.stamps_ns[0]) * 1e-9
    keep = np.ones(t.size, bool)
    for start in starts_s:
        keep &= (t < start) | (t >= start + length_s)
    arrays = {f.name: getattr(run, f.name)[keep] for f in fields(run)
              if isinstance(getattr(run, f.name), np.ndarray) and f.name != 'vehicle'}
    return replace(run, n_dropped=run.n_dropped + int(np.sum(~keep)), **arrays)


@dataclass(frozen=True)
class Coverage:
    """Per nominal level (probability): fraction of samples whose truth is inside the band, the
    band's mean half-width (m), and the samples scored; the fraction inside among the samples
    within NEAR_M of a dropout (NaN without any) and among the others, and their counts."""

    levels: tuple[float, ...]
    inside: tuple[float, ...]
    half_width_m: tuple[float, ...]
    samples: int
    near: tuple[float, ...] = ()
    away: tuple[float, ...] = ()
    near_samples: int = 0


def truth_at(run: Run, band: Band, inversion: InversionConfig) -> np.ndarray:
    """The run's truth band-passed on distance like the reconstruction, at the band's samples
    (band chainage from the first sample, as the pipeline counts it), m. The truth is the
    run's track (``Run.track``) on the grid, not the truth at the delivered samples: across a
    dropout those would be joined by a straight line, whose band-passed error next to a 0.5 s
    gap (15 m at 30 m/s) is 0.4 mm rms, twice the gap's own fill error (docs/uq.md)."""
    x = np.arange(run.chainage_m[0], run.chainage_m[-1], DX_M)
    u = run.track(x) if run.track is not None else np.interp(x, run.chainage_m, run.truth_u_m)
    truth_x = band_distance(u, DX_M, inversion.band, inversion.band_order)
    return np.interp(band.chainage_m + run.chainage_m[0], x, truth_x)


def coverage(run: Run, config: UncertaintyConfig, vehicle: VehicleParams,
             dists: Mapping[str, Distribution], preset: str,
             levels: Sequence[float] = (0.5, 0.95, 0.99), near_m: float = NEAR_M) -> Coverage:
    """Coverage of the bands of each central ``level`` on ``run`` (its odometry = run speed),
    computed with the datasheet noise of ``preset``; "near" a dropout: within near_m (m)."""
    edges_m = dropout_edges_m(run)
    scores = []
    for level in levels:
        cfg = config.with_(lower_quantile=(1 - level) / 2, upper_quantile=(1 + level) / 2)
        band = offline_bands(run.stamps_ns, run.accel, (run.stamps_ns, run.speed_mps),
                             config=cfg,
                             vehicle=vehicle, dists=dists,
                             noise_variance=accel_covariance(imu_spec(preset)))
        scores.append(score_band(run, band, config.inversion, edges_m, near_m))
    return _coverage(levels, scores)


def bank_coverage(run: Run, pipeline: InversionPipeline, design: Design,
                  config: UncertaintyConfig, levels: Sequence[float] = (0.5, 0.95, 0.99),
                  near_m: float = NEAR_M, estimator: bool = True) -> Coverage:
    """Coverage of the bands of each central ``level`` on ``run``, from a fresh bank
    ``pipeline`` (theta ``design.theta``, nominal its nominal vehicle; consumed) driven
    directly: the run's speeds as odometry, the gyro's pitch rate when the pipeline takes a
    second channel; the terms of ``bank_terms`` (``estimator`` False: without the estimator's
    error term); every level's band from the same bank outputs."""
    rates = {'rates': run.gyro[:, 1]} if pipeline.extra_channels and run.gyro is not None \
        else {}
    out = Output.concat([pipeline.push(run.stamps_ns, vertical(run.accel, 'z'), run.speed_mps,
                                       **rates), pipeline.flush()], design.points)
    terms = bank_terms(config, pipeline, None) if estimator else SensorTerms(config, None)
    sensor = terms.std(out.stamps_ns, design.projector[0] @ out.u_m, out.speed_mps,
                       out.quality, out.gap_std_m, out.chainage_m)
    edges_m = dropout_edges_m(run)
    return _coverage(levels, [score_band(run, bank_band(design, ((1 - q) / 2, (1 + q) / 2),
                                                       out, sensor),
                                         config.inversion, edges_m, near_m) for q in levels])


def dropout_edges_m(run: Run) -> np.ndarray:
    """Chainage (m, sorted) of the samples either side of the run's dropouts."""
    period_ns = 1e9 / run.rate_hz
    ends = np.flatnonzero(np.diff(run.stamps_ns) > 1.5 * period_ns)  # last sample before a gap
    return np.sort(run.chainage_m[np.concatenate([ends, ends + 1])])


def score_band(run: Run, band: Band, inversion: InversionConfig, edges_m: np.ndarray,
               near_m: float) -> tuple[float, float, float, float, int, int]:
    """(inside, inside near a dropout, inside away from them, mean half-width m, samples,
    samples near) of one band on the run's published samples away from the ends."""
    chain = band.chainage_m + run.chainage_m[0]
    truth = truth_at(run, band, inversion)
    keep = ((chain > chain[0] + MARGIN_M) & (chain < chain[-1] - MARGIN_M)
            & np.isfinite(band.mean_m) & (band.quality != Quality.INVALID))
    lo, hi = band.lower_m[keep], band.upper_m[keep]
    hit = (truth[keep] >= lo) & (truth[keep] <= hi)
    near = np.zeros(hit.size, bool)
    if edges_m.size:
        j = np.searchsorted(edges_m, chain[keep])
        near = np.minimum(np.abs(chain[keep] - edges_m[np.maximum(j - 1, 0)]),
                          np.abs(chain[keep] - edges_m[np.minimum(j, edges_m.size - 1)])
                          ) <= near_m
    return (float(np.mean(hit)), float(np.mean(hit[near])) if near.any() else float('nan'),
            float(np.mean(hit[~near])) if (~near).any() else float('nan'),
            float(np.mean(hi - lo) / 2), int(keep.sum()), int(near.sum()))


def _coverage(levels: Sequence[float], scores: list[tuple[float, float, float, float, int, int]]
              ) -> Coverage:
    inside, near, away, width, count, near_count = zip(*scores, strict=True)
    return Coverage(tuple(levels), inside, width, count[-1], near, away, near_count[-1])
