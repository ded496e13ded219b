"""Sensitivity windows: per-window quantities of interest of every rule point, then Sobol' and
Borgonovo indices from the window's PCE (uq.pce, uq.delta).

Windows are consecutive, of ``window_length`` seconds of stamps (origin: the first output stamp)
or metres of chainage (origin: chainage 0). A window closes when a sample of a later window is
emitted, or at ``flush``. Quantities of interest per rule point j (metres):
- ``peak``: u_j at the window's sample of largest |PCE mean| (first one on ties): the paper's
  t = 7 s choice (the largest deviation of the profile), found on the stream;
- ``rms``: sqrt(mean over the window of u_j^2).
Both accumulate sample by sample, so the records do not depend on chunking.

The delta estimates evaluate every window's surrogate at the same germ points
(``uq.delta.delta_design``), whose PCE basis the analyzer builds once (``DeltaBasis``).
Offline (``defer=True``), closed windows wait and ``analyze_deferred`` runs their delta
estimates together, ``DEFER_BATCH`` windows per call: the same records to rounding (each
output's estimate uses the same samples; BLAS may sum a batch in another order, and a delta's
sign decisions can flip on 1 ulp: 5e-5) in less time per window (measured on one core: 10
instead of 14 ms; more windows per call save nothing more). The basis takes 4 MB, an
estimate up to 7 MB for one window and 13 MB for six (tracemalloc).
"""

from __future__ import annotations

from dataclasses import dataclass
import time

import numpy as np

from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uncertainty.surrogate import Design
from railgsa_ros.uq.delta import delta_design, delta_from_outputs
from railgsa_ros.uq.pce import PCE, basis

DEFER_BATCH = 6  # windows per delta estimate offline: 13 MB peak with 2 QoIs (measured)


@dataclass(frozen=True)
class Sensitivity:
    """One quantity of interest over one window: indices (n,) ordered as ``names``, the QoI's
    PCE mean and std (m), the window's stamps (ns), chainage (m) and sample count, the peak
    sample's stamp (peak only, else -1), the rule, its model evaluations and the compute time."""

    qoi: str
    names: tuple[str, ...]
    sobol_first: np.ndarray
    sobol_total: np.ndarray
    delta: np.ndarray
    mean_m: float
    std_m: float
    first_stamp_ns: int
    last_stamp_ns: int
    chainage_start_m: float
    chainage_end_m: float
    samples: int
    peak_stamp_ns: int
    rule: str
    order: int
    evaluations: int
    compute_s: float


@dataclass
class _Window:
    """Running sums of one open window."""

    index: int
    first_stamp: int
    first_chain: float
    points: int
    last_stamp: int = 0
    last_chain: float = 0.0
    count: int = 0
    peak_abs: float = -1.0
    peak_stamp: int = -1

    def __post_init__(self) -> None:
        self.sumsq = np.zeros(self.points)
        self.peak_u = np.zeros(self.points)

    def add(self, stamps: np.ndarray, chain: np.ndarray, mean: np.ndarray,
            u: np.ndarray) -> None:
        """Accumulate samples (K,) with bank outputs u (P, K) of this window."""
        self.sumsq += np.einsum('pk,pk->p', u, u)
        self.count += stamps.size
        self.last_stamp, self.last_chain = int(stamps[-1]), float(chain[-1])
        k = int(np.argmax(np.abs(mean)))
        if abs(mean[k]) > self.peak_abs:
            self.peak_abs, self.peak_stamp = abs(mean[k]), int(stamps[k])
            self.peak_u = u[:, k].copy()

    def quantities(self, qois: tuple[str, ...]) -> np.ndarray:
        """QoI values of every rule point, shape (P, m)."""
        values = {'peak': self.peak_u, 'rms': np.sqrt(self.sumsq / self.count)}
        return np.stack([values[q] for q in qois], axis=1)


class WindowAnalyzer:
    """Streams samples into windows and returns a Sensitivity per QoI for each closed window
    (``defer``: keeps closed windows for ``analyze_deferred`` and returns none)."""

    def __init__(self, config: UncertaintyConfig, design: Design, defer: bool = False) -> None:
        self.config = config
        self.design = design
        self._length_ns = round(config.window_length * 1e9)
        self._origin: int | None = None
        self._open: _Window | None = None
        self._deferred: list[_Window] | None = [] if defer else None
        self._delta_basis: DeltaBasis | None = None

    def _index(self, stamps: np.ndarray, chain: np.ndarray) -> np.ndarray:
        """Window index of each sample."""
        if self.config.window_unit == 'm':
            return np.floor(chain / self.config.window_length).astype(np.int64)
        if self._origin is None:
            self._origin = int(stamps[0])
        return (stamps - self._origin) // self._length_ns

    def push(self, stamps: np.ndarray, chain: np.ndarray, mean: np.ndarray,
             u: np.ndarray, valid: np.ndarray | None = None) -> list[Sensitivity]:
        """Emitted samples: stamps (K,) ns, chainage (K,) m, PCE mean (K,), bank u (P, K);
        ``valid`` (K,): the samples the windows take. Every sample places the windows (origin:
        the first emitted stamp) and closes the open one when it lies in a later window; the
        others (INVALID ones) add nothing, and a window without a valid sample has no record."""
        if not self.config.qois or stamps.size == 0:
            return []
        idx = self._index(stamps, chain)
        valid = np.ones(idx.size, bool) if valid is None else np.asarray(valid, bool)
        cuts = np.flatnonzero(np.diff(idx)) + 1
        out = []
        for lo, hi in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [idx.size]]),
                          strict=True):
            if self._open is not None and self._open.index != idx[lo]:
                out += self.close()
            keep = np.flatnonzero(valid[lo:hi]) + lo
            if keep.size == 0:
                continue
            if self._open is None:
                self._open = _Window(int(idx[lo]), int(stamps[keep[0]]), float(chain[keep[0]]),
                                     self.design.points)
            self._open.add(stamps[keep], chain[keep], mean[keep], u[:, keep])
        return out

    def close(self) -> list[Sensitivity]:
        """Close the open window (if any) and return its records."""
        window, self._open = self._open, None
        if window is None:
            return []
        if self._deferred is not None:
            self._deferred.append(window)
            return []
        return analyze_windows(self.config, self.design, [window], self.delta_basis)

    def analyze_deferred(self) -> list[Sensitivity]:
        """Records of the windows closed so far with ``defer``, in order (then forgotten)."""
        windows, self._deferred = self._deferred or [], []
        return [r for lo in range(0, len(windows), DEFER_BATCH)
                for r in analyze_windows(self.config, self.design,
                                         windows[lo:lo + DEFER_BATCH], self.delta_basis)]

    @property
    def delta_basis(self) -> DeltaBasis:
        """The delta estimate's germ points and their PCE basis, built at the first use."""
        if self._delta_basis is None:
            self._delta_basis = DeltaBasis.build(self.config, self.design)
        return self._delta_basis


@dataclass(frozen=True)
class DeltaBasis:
    """The PCE basis at the germ points of ``uq.delta.delta_design`` (fixed by the config's
    seed): ``ref`` (N, T) and ``cond`` (n, n_outer, n_inner, T). Every window's delta estimate
    evaluates its surrogate at the same points, so the basis is built once (measured: 10 of
    the 65 ms of one delta_indices call at n_mc 20000)."""

    ref: np.ndarray
    cond: np.ndarray

    @classmethod
    def build(cls, config: UncertaintyConfig, design: Design) -> DeltaBasis:
        """Basis of ``design.alpha`` at the delta design of ``config`` (n_mc, seed, germ)."""
        n = design.alpha.shape[1]
        points = delta_design(n, config.n_mc, seed=config.seed, germ=design.germ)
        cond = basis(points.cond.reshape(-1, n), design.alpha, design.germ)
        return cls(basis(points.ref, design.alpha, design.germ),
                   cond.reshape(*points.cond.shape[:3], -1))


def analyze_windows(config: UncertaintyConfig, design: Design, windows: list[_Window],
                    delta_basis: DeltaBasis) -> list[Sensitivity]:
    """Sobol' indices from each window PCE's coefficients and delta by surrogate Monte Carlo
    (one call for all windows and QoIs); records per window, then per QoI. ``compute_s`` is the
    time per window."""
    start = time.perf_counter()
    qois = config.qois
    values = np.concatenate([w.quantities(qois) for w in windows], axis=1)  # (P, W m)
    pce = PCE(design.alpha, design.projector @ values, design.germ)
    delta = delta_from_outputs(delta_basis.ref @ pce.coef, delta_basis.cond @ pce.coef)
    std = np.sqrt(pce.variance)
    elapsed = (time.perf_counter() - start) / len(windows)
    records = []
    for i, (w, q) in enumerate((w, q) for w in windows for q in qois):  # columns of values
        records.append(Sensitivity(q, design.names, pce.sobol_first[i], pce.sobol_total[i],
                                   delta[i], float(pce.mean[i]), float(std[i]), w.first_stamp,
                                   w.last_stamp, w.first_chain, w.last_chain, w.count,
                                   w.peak_stamp if q == 'peak' else -1, config.rule,
                                   config.order, design.points, elapsed))
    return records
