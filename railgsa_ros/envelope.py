"""The min/max envelope of a long signal: what a plot of a few thousand pixels can show of it.

Drawing the min and max of each block of samples keeps every peak visible at any length and
makes the drawing time (and an inline SVG's size) independent of the run length.
"""

from __future__ import annotations

import numpy as np

PIXELS = 1600  # envelope bins across a full-width panel


def envelope(x: np.ndarray, *ys: np.ndarray, bins: int = PIXELS) -> tuple[np.ndarray, ...]:
    """(x (B,), then min (B,) and max (B,) of every y) over consecutive blocks of samples; the
    input itself (min = max = y) when it has fewer than 2 * bins samples. Reduced in place
    (``reduceat``): no copy of a long signal."""
    x = np.asarray(x, dtype=float)
    if x.size < 2 * bins:
        return (x, *(v for y in ys for v in (y, y)))
    starts = np.arange(0, x.size, -(-x.size // bins))
    out = [np.add.reduceat(x, starts) / np.diff(np.append(starts, x.size))]
    for y in ys:  # fmin/fmax skip NaN (a block of NaN stays NaN, without a warning)
        out += [np.fmin.reduceat(y, starts), np.fmax.reduceat(y, starts)]
    return tuple(out)
