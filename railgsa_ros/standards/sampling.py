"""EN 13848 sampling on distance: a run resampled on a fixed 0.25 m chainage grid while it
streams, what the review and the fleet keep instead of every sample.

Cell i is centred at (i + 1/2) dx m of chainage (dx = 0.25 m, as EN 13848 samples at <= 0.5 m).
A cell takes the linear interpolation between the two consecutive samples whose chainage
brackets its centre (c_a < x <= c_b), as ``np.interp`` of the whole run would, and counts as
valid when they lie less than ``max_step_m`` apart (a gap in the data is not bridged) and both
have a value (INVALID samples carry NaN). Pairs that do not advance (standstill, c_b <= c_a)
fill no cell. The grid holds the reconstruction (float64), the band's lower and upper quantiles
and the speed (float32: for the figures only) and the validity: 21 bytes per cell, 84 bytes per
metre of run, whatever the sample rate (10 h at 30 m/s: 1,080 km, 91 MB).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import mmap

import numpy as np

DX_M = 0.25
MAX_STEP_M = 1.0
BLOCK = 1 << 16  # cells per storage block (16 km at 0.25 m)


@dataclass(frozen=True)
class Grid:
    """The cells of a run from cell ``first`` on: u_m (N,) float64, lower_m and upper_m (N,)
    float32 (NaN without a band), speed_mps (N,) float32, valid (N,); invalid cells hold NaN.
    The centres ``x_m`` are computed when asked."""

    dx_m: float
    first: int
    u_m: np.ndarray
    lower_m: np.ndarray
    upper_m: np.ndarray
    speed_mps: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.u_m.size)

    @property
    def x_m(self) -> np.ndarray:
        """Cell centres (N,) m."""
        return (self.first + np.arange(self.u_m.size) + 0.5) * self.dx_m

    @property
    def has_band(self) -> bool:
        """Whether the run had an uncertainty band."""
        return bool(np.any(np.isfinite(self.lower_m)))

    def window(self, lo_m: float, hi_m: float) -> Grid:
        """The cells with centres in [lo_m, hi_m]."""
        i = int(np.clip(np.ceil(lo_m / self.dx_m - 0.5) - self.first, 0, len(self)))
        j = int(np.clip(np.floor(hi_m / self.dx_m - 0.5) - self.first + 1, i, len(self)))
        return Grid(self.dx_m, self.first + i, *(getattr(self, f)[i:j] for f in
                                                 ('u_m', 'lower_m', 'upper_m', 'speed_mps',
                                                  'valid')))


class CellStore:
    """Columns of per-cell values (one dtype each, NaN until set) and a validity flag, in
    blocks of BLOCK cells allocated as the run reaches them: no copies as it grows, memory by
    the cells reached (the review's run grid and its truth grid)."""

    def __init__(self, dtypes: Sequence[type | str]) -> None:
        self.dtypes = [np.dtype(d) for d in dtypes]
        self._blocks: dict[int, tuple[list[np.ndarray], np.ndarray]] = {}

    def put(self, cell: np.ndarray, values: Sequence[np.ndarray], valid: np.ndarray) -> None:
        """Set cells (N,) int64 (ascending) to ``values`` (one (N,) array per column; NaN where
        not ``valid``)."""
        block, offset = np.divmod(cell, BLOCK)
        cuts = np.flatnonzero(np.diff(block)) + 1
        for lo, hi in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [cell.size]]),
                          strict=True):
            columns, ok = self._block(int(block[lo]))
            at, good = offset[lo:hi], valid[lo:hi]
            for column, v in zip(columns, values, strict=True):
                column[at] = np.where(good, v[lo:hi], np.nan)
            ok[at] = good

    def _block(self, index: int) -> tuple[list[np.ndarray], np.ndarray]:
        if index not in self._blocks:
            self._blocks[index] = ([_mapped(BLOCK, d, np.nan) for d in self.dtypes],
                                   _mapped(BLOCK, np.dtype(bool), False))
        return self._blocks[index]

    @property
    def nbytes(self) -> int:
        """Bytes held by the cells."""
        return sum(c.nbytes for cols, ok in self._blocks.values() for c in (*cols, ok))

    def take(self) -> tuple[int, list[np.ndarray], np.ndarray]:
        """(first cell, columns (N,), valid (N,)) from the first to the last valid cell; the
        blocks are handed over one at a time (the store is empty afterwards: the run is held
        once, plus one block)."""
        valid_at = [i * BLOCK + np.flatnonzero(ok)[[0, -1]]
                    for i, (_, ok) in sorted(self._blocks.items()) if ok.any()]
        if not valid_at:
            self._blocks.clear()
            return 0, [np.zeros(0, d) for d in self.dtypes], np.zeros(0, bool)
        first, last = int(valid_at[0][0]), int(valid_at[-1][1])
        n = last - first + 1
        columns = [np.full(n, np.nan, d) for d in self.dtypes]
        valid = np.zeros(n, bool)
        for i in sorted(self._blocks):
            cols, ok = self._blocks.pop(i)
            lo, hi = max(i * BLOCK, first), min((i + 1) * BLOCK, last + 1)
            if lo < hi:
                for out, col in zip(columns, cols, strict=True):
                    out[lo - first:hi - first] = col[lo - i * BLOCK:hi - i * BLOCK]
                valid[lo - first:hi - first] = ok[lo - i * BLOCK:hi - i * BLOCK]
        return first, columns, valid


def _mapped(count: int, dtype: np.dtype, fill: float | bool) -> np.ndarray:
    """``count`` values ``fill`` in an anonymous memory map of their own, not in the malloc
    heap: ``CellStore.take`` hands the blocks back to the system one by one (freed heap blocks
    stay resident; measured at the end of a 10 h review: 100 MB of freed blocks)."""
    out = np.frombuffer(mmap.mmap(-1, count * dtype.itemsize), dtype)
    out[:] = fill
    return out


class CellInterpolator:
    """Streams samples (chainage, values...) to the cells of the module docstring: the last
    sample of a chunk is kept to interpolate across chunk boundaries."""

    def __init__(self, dx_m: float = DX_M, max_step_m: float = MAX_STEP_M) -> None:
        self.dx_m = float(dx_m)
        self.max_step_m = float(max_step_m)
        self._last: tuple[float, ...] | None = None

    def push(self, chainage_m: np.ndarray, *columns: np.ndarray
             ) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
        """Samples (K,) in order: (cells (N,), the columns at their centres (N,) each, valid
        (N,): less than max_step_m between the samples around it and the first column finite)."""
        cols = [np.asarray(chainage_m, float), *(np.asarray(c, float) for c in columns)]
        if self._last is not None:
            cols = [np.concatenate([[v], c]) for v, c in zip(self._last, cols, strict=True)]
        if cols[0].size:
            self._last = tuple(float(c[-1]) for c in cols)
        c = cols[0]
        lo, hi = c[:-1], c[1:]
        first, count = cells_between(lo, hi, self.dx_m)
        pair = np.repeat(np.arange(lo.size), count)
        cell = first[pair] + (np.arange(pair.size) - np.repeat(np.cumsum(count) - count, count))
        t = ((cell + 0.5) * self.dx_m - lo[pair]) / (hi[pair] - lo[pair])
        values = [v[pair] + t * (v[pair + 1] - v[pair]) for v in cols[1:]]
        valid = ((hi - lo)[pair] < self.max_step_m) & np.isfinite(values[0])  # NaN: INVALID
        return cell, values, valid


def cells_between(lo: np.ndarray, hi: np.ndarray, dx_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(first cell, cell count) (K,) int64 of the sample pairs with chainages lo, hi (K,) m: the
    cells whose centre x has lo < x <= hi (none where a chainage is NaN or hi <= lo)."""
    with np.errstate(invalid='ignore'):
        ok = np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
        first = np.where(ok, np.floor(lo / dx_m - 0.5), 0).astype(np.int64) + 1
        last = np.where(ok, np.floor(hi / dx_m - 0.5), 0).astype(np.int64)
    return first, np.where(ok, np.maximum(last - first + 1, 0), 0)


class GridBuilder:
    """Streams samples (chainage, u, speed[, lower, upper]) into a :class:`Grid` (a
    ``CellInterpolator`` into a ``CellStore``)."""

    def __init__(self, dx_m: float = DX_M, max_step_m: float = MAX_STEP_M) -> None:
        self.dx_m = float(dx_m)
        self._cells = CellInterpolator(dx_m, max_step_m)
        self._store = CellStore([np.float64, np.float32, np.float32, np.float32])

    def push(self, chainage_m: np.ndarray, u_m: np.ndarray, speed_mps: np.ndarray,
             lower_m: np.ndarray | None = None, upper_m: np.ndarray | None = None) -> None:
        """Samples (K,) in emission order."""
        if np.size(chainage_m) == 0:
            return
        nan = np.full(np.shape(u_m), np.nan)
        cell, values, valid = self._cells.push(
            chainage_m, u_m, nan if lower_m is None else lower_m,
            nan if upper_m is None else upper_m, speed_mps)
        if cell.size:
            self._store.put(cell, values, valid)

    @property
    def nbytes(self) -> int:
        """Bytes held by the cells."""
        return self._store.nbytes

    def grid(self) -> Grid:
        """The cells from the first to the last valid one (the builder is empty afterwards: no
        second copy of the run)."""
        first, (u, lower, upper, speed), valid = self._store.take()
        return Grid(self.dx_m, first, u, lower, upper, speed, valid)
