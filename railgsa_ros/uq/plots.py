"""Figures of a GSA result (matplotlib, Agg): the output histogram with its kernel density
(paper Fig. 12) and the sensitivity bars (Fig. 13 and 14)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy import stats

from railgsa_ros.uq.analyze import Result


def _figure():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.0), layout='constrained')
    FigureCanvasAgg(fig)
    return fig


def plot_histogram(result: Result, out: Path, label: str) -> Path:
    """Histogram of the surrogate samples with a Gaussian kernel density (Silverman bandwidth)."""
    samples = np.asarray(result.samples).reshape(len(result.samples), -1)[:, 0]
    fig = _figure()
    ax = fig.add_subplot()
    ax.hist(samples, bins=100, density=True, color='0.75', label=f'{len(samples):,} PCE samples')
    grid = np.linspace(samples.min(), samples.max(), 400)
    kde = stats.gaussian_kde(samples[:: max(len(samples) // 20_000, 1)])  # display only
    ax.plot(grid, kde(grid), 'k', label='kernel density')
    ax.set_xlabel(label)
    ax.set_ylabel('density')
    ax.legend()
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
