"""The surrogate at the run's worst location (largest |PCE mean|), as in the paper's Fig. 12.

The bank outputs there (one per rule point) project onto the same PCE as the uncertainty node's
band (``Design.projector``); the surrogate is then sampled on ``N_SAMPLES`` scrambled Sobol' germ
points for the histogram and its kernel density (``uq.plots.draw_histogram``), and the
Sobol' indices come from the coefficients.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from railgsa_ros.review.figures import plot_distribution
from railgsa_ros.review.stream import Worst
from railgsa_ros.uncertainty import UncertaintyConfig
from railgsa_ros.uncertainty.surrogate import Design
from railgsa_ros.uq.analyze import Result
from railgsa_ros.uq.germ import sobol
from railgsa_ros.uq.pce import PCE

N_SAMPLES = 100_000  # surrogate samples, as the paper's 10^5
MM = 1e3


@dataclass(frozen=True)
class WorstSurrogate:
    """Surrogate of the irregularity (mm) at one location: chainage (m), stamp (ns), the GSA
    result (samples, mean, std, quantiles, Sobol' indices) and the parameter names."""

    chainage_m: float
    stamp_ns: int
    result: Result
    names: tuple[str, ...]


def worst_surrogate(design: Design, worst: Worst, config: UncertaintyConfig) -> WorstSurrogate:
    """PCE in mm from the bank outputs at the worst sample, sampled N_SAMPLES times."""
    pce = PCE(design.alpha, (design.projector @ worst.bank_u_m)[:, None] * MM, design.germ)
    samples = pce(sobol(design.alpha.shape[1], N_SAMPLES, config.seed, design.germ))[:, 0]
    result = Result(pce, samples, None, design.points, config.rule, config.order, design.fit,
                    scalar=True)
    return WorstSurrogate(worst.chainage_m, worst.stamp_ns, result, design.names)


def plot_worst(path: Path, surrogate: WorstSurrogate) -> Path:
    """Histogram of the surrogate samples with their kernel density (paper Fig. 12 style)."""
    samples = surrogate.result.samples
    return plot_distribution(path, np.reshape(samples, (len(samples), -1))[:, 0],
                             f'irregularity at {surrogate.chainage_m:.1f} m (largest |mean|) [mm]')
