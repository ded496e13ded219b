"""Ground truth for a review: a bag's ``/track/irregularity_truth`` or a profile CSV ``x_m,u_m``.

A truth bag (point.x = chainage, point.z = irregularity, stamped like the IMU) is put on the
review's chainage by one offset: its chainage at the run's first output stamp becomes the run's
chainage there. A CSV has no stamps: its x_m must already count from the run's start (chainage 0
at the first IMU sample, as the pipeline integrates the speed). Both are compared with the
reconstruction in the same EN 13848 band by ``inverse.score``.

The review streams a truth bag (``truth_on_grid``): one pass up to the run's first output stamp
for the offset, a second one resampling every sample onto the review's 0.25 m cells
(``grid.CellInterpolator``, the same linear interpolation the comparison makes at the cell
centres): 8 bytes per cell, not 24 per IMU sample.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from railgsa_ros.bag import TRUTH_TOPIC, open_bag, read_stamped
from railgsa_ros.bag.messages import POINT_STAMPED
from railgsa_ros.bag.reader import CHUNK, iter_topics
from railgsa_ros.errors import ConfigError, InputError
from railgsa_ros.inverse.score import Score, band_distance, score
from railgsa_ros.standards.sampling import MAX_STEP_M, CellInterpolator, CellStore
from railgsa_ros.track import load_csv

DX_M = 0.25  # scoring grid, m
MARGIN_M = 100.0  # left out at both ends of the scored range (filter edges)
DEFECT_M = 10.0  # window length around the largest truth defect for the peak error, m


@dataclass(frozen=True)
class Truth:
    """Irregularity u_m (N,) at increasing chainage_m (N,), with the stamps (N,) ns of a truth
    bag (None for a CSV)."""

    source: Path
    chainage_m: np.ndarray
    u_m: np.ndarray
    stamps_ns: np.ndarray | None = None

    def aligned(self, run_stamp_ns: int, run_chainage_m: float) -> Truth:
        """On the run's chainage axis: a bag's chainage shifted so that its value at the run's
        stamp ``run_stamp_ns`` is ``run_chainage_m``; a CSV as it is."""
        if self.stamps_ns is None:
            return self
        offset = float(np.interp(run_stamp_ns, self.stamps_ns, self.chainage_m)) - run_chainage_m
        return Truth(self.source, self.chainage_m - offset, self.u_m, self.stamps_ns)


def load_truth(path: str | Path) -> Truth:
    """Read a truth bag or CSV (see the module docstring); InputError naming the file when it is
    missing, unreadable, empty or decreasing in chainage (the repeats of a standstill dropped)."""
    path = Path(path)
    if path.suffix.lower() == '.csv':
        try:
            x, u = load_csv(path)
        except ConfigError as exc:
            raise InputError(str(exc)) from None
        return Truth(path, x, u)
    data = read_stamped(path, TRUTH_TOPIC, POINT_STAMPED.msgtype)
    if data.values.shape[0] < 2:
        raise InputError(f'{path}: {TRUTH_TOPIC} has fewer than two messages')
    order = np.argsort(data.stamps_ns, kind='stable')
    stamps, x, u = data.stamps_ns[order], data.values[order, 0], data.values[order, 2]
    if not np.all(np.isfinite(x) & np.isfinite(u)) or np.any(np.diff(x) < 0):
        raise InputError(f'{path}: {TRUTH_TOPIC} chainage (point.x) must be finite and '
                         'never decrease with the stamps')
    moved = np.concatenate([[True], np.diff(x) > 0])  # a standstill repeats its chainage
    return Truth(path, x[moved], u[moved], stamps[moved])


def check_truth(path: str | Path) -> Truth | None:
    """Before the run: a CSV read (a profile file), a bag checked for two or more truth
    messages (None: streamed after the run by ``truth_on_grid``); InputError naming the file."""
    path = Path(path)
    if path.suffix.lower() == '.csv':
        return load_truth(path)
    with open_bag(path) as reader:
        conns = [c for c in reader.connections if c.topic == TRUTH_TOPIC]
        if not conns:
            have = ', '.join(sorted({c.topic for c in reader.connections})) or 'none'
            raise InputError(f'{path}: no topic {TRUTH_TOPIC} (topics: {have})')
        if conns[0].msgtype != POINT_STAMPED.msgtype:
            raise InputError(f'{path}: topic {TRUTH_TOPIC} has type {conns[0].msgtype}, '
                             f'expected {POINT_STAMPED.msgtype}')
    return None


def truth_on_grid(path: str | Path, run_stamp_ns: int, run_chainage_m: float,
                  dx_m: float = DX_M, chunk: int = CHUNK) -> Truth:
    """A truth bag streamed onto the run's chainage (``Truth.aligned``) at the centres of the
    review's cells of ``dx_m``: the valid cells (less than grid.MAX_STEP_M between the samples
    around them), no stamps. InputError naming the file when the stamps go back, the chainage
    decreases with them (a standstill repeats it: no cell) or is not finite, or fewer than two
    messages."""
    path = Path(path)
    offset = _offset(path, run_stamp_ns, chunk) - run_chainage_m
    cells, store = CellInterpolator(dx_m, MAX_STEP_M), CellStore([np.float64])
    last, count = (-np.inf, -np.inf), 0
    for batch in _truth_batches(path, chunk):
        stamps, x, u = batch.stamps_ns, batch.values[:, 0], batch.values[:, 2]
        if not np.all(np.isfinite(x) & np.isfinite(u)) or np.any(  # a standstill repeats it
                np.diff(np.concatenate([[last[1]], x])) < 0):
            raise InputError(f'{path}: {TRUTH_TOPIC} chainage (point.x) must be finite and '
                             'never decrease with the stamps')
        if np.any(np.diff(np.concatenate([[last[0]], stamps])) < 0):
            raise InputError(f'{path}: {TRUTH_TOPIC} stamps go back in log-time order')
        last, count = (stamps[-1], x[-1]), count + stamps.size
        cell, (value,), valid = cells.push(x - offset, u)
        if cell.size:
            store.put(cell, [value], valid)
    if count < 2:
        raise InputError(f'{path}: {TRUTH_TOPIC} has fewer than two messages')
    first, (u,), valid = store.take()
    x = (first + np.flatnonzero(valid) + 0.5) * dx_m
    return Truth(path, x, u[valid])


def _truth_batches(path: Path, chunk: int) -> Iterator[Any]:
    """The truth topic's messages, batch by batch (TopicData)."""
    for batch in iter_topics(path, {TRUTH_TOPIC: POINT_STAMPED.msgtype}, chunk):
        if TRUTH_TOPIC in batch:  # batches of other topics' chunks are empty
            yield batch[TRUTH_TOPIC]


def _offset(path: Path, stamp_ns: int, chunk: int) -> float:
    """The truth's chainage at ``stamp_ns`` (linear between the samples around it; the first
    or last one outside them), reading only as far as that stamp."""
    previous = None
    for batch in _truth_batches(path, chunk):
        stamps, x = batch.stamps_ns, batch.values[:, 0]
        if previous is not None:
            stamps, x = np.concatenate([[previous[0]], stamps]), np.concatenate([[previous[1]], x])
        if stamps[-1] >= stamp_ns:
            return float(np.interp(stamp_ns, stamps, x))
        previous = (stamps[-1], x[-1])
    if previous is None:
        raise InputError(f'{path}: {TRUTH_TOPIC} has fewer than two messages')
    return float(previous[1])


@dataclass(frozen=True)
class Comparison:
    """Reconstruction and band-filtered truth on a common grid x (N,) m, the scored part of the
    grid (N,) (the ends are left out), the score and the chainage of the largest truth defect."""

    x_m: np.ndarray
    rec_m: np.ndarray
    truth_m: np.ndarray
    scored: np.ndarray
    score: Score
    defect_m: float


def compare(chainage_m: np.ndarray, u_m: np.ndarray, truth: Truth, band: str) -> Comparison:
    """Score the reconstruction against the truth in ``band`` (RMSE, correlation, peak error at
    the largest defect of the band-filtered truth); InputError when they barely overlap."""
    lo = max(chainage_m[0], truth.chainage_m[0])
    lo = (np.ceil(lo / DX_M - 0.5) + 0.5) * DX_M  # on the review's grid: no second interpolation
    chainage_m, u_m = chainage_m[chainage_m >= lo - 1e-9], u_m[chainage_m >= lo - 1e-9]
    hi = min(chainage_m[-1], truth.chainage_m[-1])
    if hi - lo <= 2 * MARGIN_M + DEFECT_M:
        raise InputError(f'{truth.source}: the truth overlaps the run over {max(hi - lo, 0):.0f} '
                         f'm, fewer than the {2 * MARGIN_M + DEFECT_M:.0f} m needed to score')
    x = np.arange(lo, hi, DX_M)
    truth_band = band_distance(np.interp(x, truth.chainage_m, truth.u_m), DX_M, band)
    rec = np.interp(x, chainage_m, u_m)
    inner = (x >= lo + MARGIN_M) & (x <= hi - MARGIN_M)
    peak = float(x[inner][np.argmax(np.abs(truth_band[inner]))])
    result = score(chainage_m, u_m, truth.chainage_m, truth.u_m, band, DX_M, MARGIN_M,
                   defect=(peak - DEFECT_M / 2, DEFECT_M))
    return Comparison(x, rec, truth_band, inner, result, peak)
