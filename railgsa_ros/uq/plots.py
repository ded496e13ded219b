"""Figures of a GSA result (matplotlib, Agg): the output histogram with its kernel density
(paper Fig. 12) and the sensitivity bars (Fig. 13 and 14)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy import ndimage

from railgsa_ros.uq.analyze import Result

DENSITY_POINTS = 400  # grid of the kernel density over the histogram


def _figure():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.0), layout='constrained')
    FigureCanvasAgg(fig)
    return fig


def draw_histogram(ax, samples: np.ndarray, label: str) -> None:
    """Histogram of samples (N,) as one filled outline with their Gaussian kernel density
    (Scott's bandwidth, the default of scipy.stats.gaussian_kde) on the axes ``ax``.

    Why not gaussian_kde itself: it sums N kernels at each grid point (100,000 x 400 for a
    paper-size sample). The samples' histogram on DENSITY_POINTS cells smoothed by the kernel
    (scipy.ndimage) is within 1e-3 of the peak of gaussian_kde on all the samples (6e-4 for a
    review's 100,000 surrogate samples, 9e-4 for a skewed two-mode sample), in a fraction of
    the time (the review's figure: 0.09 instead of 0.33 s with 100 bar patches,
    measured on one core).
    """
    samples = np.asarray(samples, dtype=float)
    ax.hist(samples, bins=100, density=True, histtype='stepfilled', color='0.75',
            label=f'{samples.size:,} PCE samples')
    counts, edges = np.histogram(samples, bins=DENSITY_POINTS)
    step = edges[1] - edges[0]
    bandwidth = np.std(samples, ddof=1) * samples.size ** -0.2
    if step > 0:
        density = ndimage.gaussian_filter1d(counts / (samples.size * step), bandwidth / step,
                                            mode='constant')
        ax.plot((edges[:-1] + edges[1:]) / 2, density, 'k', label='kernel density')
    ax.set_xlabel(label)
    ax.set_ylabel('density')
    ax.legend()


def plot_histogram(result: Result, out: Path, label: str) -> Path:
    """Histogram of the surrogate samples with their kernel density (``draw_histogram``)."""
    fig = _figure()
    draw_histogram(fig.add_subplot(), np.reshape(result.samples, (len(result.samples), -1))[:, 0],
                   label)
    fig.savefig(out, dpi=120)
    return out


def plot_sensitivities(result: Result, names: Sequence[str], out: Path, title: str) -> Path:
    """Grouped bars: first-order and total Sobol' indices and Borgonovo delta per parameter."""
    fig = _figure()
    ax = fig.add_subplot()
    x = np.arange(len(names))
    bars = [('Sobol first', result.sobol_first), ('Sobol total', result.sobol_total)]
    if result.delta is not None:
        bars.append(('Borgonovo delta', result.delta))
    width = 0.8 / len(bars)
    for j, (label, value) in enumerate(bars):
        ax.bar(x + (j - (len(bars) - 1) / 2) * width, np.reshape(value, (-1, len(names)))[0],
               width, label=label)
    ax.set_xticks(x, names)
    ax.set_ylim(0, 1)
    ax.set_ylabel('index')
    ax.set_title(title)
    ax.legend()
    fig.savefig(out, dpi=120)
    return out
