"""The histogram's kernel density against scipy's exact gaussian_kde on the same samples."""

import numpy as np
from scipy import stats

from railgsa_ros.uq.plots import draw_histogram


def test_binned_kernel_density_matches_gaussian_kde():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rng = np.random.default_rng(0)
    samples = np.concatenate([rng.normal(0.0, 1.0, 70_000), rng.gamma(2.0, 0.5, 30_000) + 2.0])
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    draw_histogram(ax, samples, 'u [mm]')
    x, density = ax.lines[0].get_data()
    exact = stats.gaussian_kde(samples)(x)  # Scott's bandwidth on every sample
    assert np.max(np.abs(density - exact)) < 1e-3 * np.max(exact)
    assert ax.get_xlabel() == 'u [mm]' and len(ax.patches) == 1  # one filled outline
