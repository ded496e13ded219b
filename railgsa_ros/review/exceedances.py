"""Isolated-defect exceedances of the EN 13848-5 limits along a reconstructed run.

The band-filtered reconstruction has zero mean, so its magnitude |u| is the mean-to-peak value.
With an uncertainty band [lower, upper] each sample has a nearest and a farthest magnitude (the
band's closest point to zero and its farthest one): an exceedance is a stretch of chainage where
the farthest magnitude passes the alert limit, merged over interruptions shorter than
``merge_m`` on the same side of zero. Its level is that of the central estimate; its confidence
says what the band adds:

- ``certain``: the whole band passes the same limit;
- ``likely``: the central estimate passes it, the band reaches below it;
- ``possible``: only the band's far edge passes a limit (level = that limit).

With the band's germ samples each exceedance has two probabilities at its peak: of passing the
limit of its level and of passing the alert limit (the lowest limit the table has there: AL, or
IAL in D2). A list cut by probability (``listed``) keeps a stretch when either reaches the cut,
and always keeps one whose central value passes the alert limit: a defect 30 % over the alert
limit is not dropped because it is unlikely to pass the intervention limit too.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from railgsa_ros.standards.en13848 import LEVELS, Limits, level_of
from railgsa_ros.uncertainty.exceedance import exceedance_probability
from railgsa_ros.uncertainty.surrogate import Design

CONFIDENCES = ('certain', 'likely', 'possible')


@dataclass(frozen=True)
class Exceedance:
    """One isolated defect beyond a limit: level (AL/IL/IAL), confidence, chainage start, end
    and peak (m), stamp of the peak (ns), signed central value and band at the peak (m), the
    limit passed (m), the speed at the peak (km/h), the probability of |u| passing the limit
    and the alert limit (m: the lowest limit defined at the peak) with its probability (NaN
    without a surrogate band)."""

    level: str
    confidence: str
    start_m: float
    end_m: float
    peak_m: float
    peak_stamp_ns: int
    peak_u_m: float
    lower_m: float
    upper_m: float
    limit_m: float
    speed_kmh: float
    probability: float = float('nan')  # of being beyond the limit (surrogate band), NaN without
    alert_limit_m: float = float('nan')
    alert_probability: float = float('nan')  # of being beyond the alert limit

    @property
    def severity(self) -> int:
        """1 (AL), 2 (IL), 3 (IAL)."""
        return LEVELS.index(self.level) + 1


def magnitudes(u: np.ndarray, lower: np.ndarray | None = None,
               upper: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(nearest, farthest) |value| (K,) over the interval spanned by u, lower and upper (m)."""
    u = np.asarray(u, dtype=float)
    if lower is None or upper is None:
        return np.abs(u), np.abs(u)
    lo = np.minimum(np.minimum(lower, upper), u)
    hi = np.maximum(np.maximum(lower, upper), u)
    near = np.where((lo > 0) | (hi < 0), np.minimum(np.abs(lo), np.abs(hi)), 0.0)
    return near, np.maximum(np.abs(lo), np.abs(hi))


_LIMITS = ('al', 'il', 'ial')


class ExceedanceTracker:
    """Exceedances of a run that streams in chunks (emission order, chainage increasing): the
    closed ones come out of ``push``, the last open one out of ``close``. Only the samples
    beyond a limit are looked at, and of the run still open only the few that decide its
    record (first, last, peak candidates, worst levels): memory does not grow with the run.
    The records equal those of the whole run at once (``find_exceedances``)."""

    def __init__(self, limits: Limits, merge_m: float = 1.0,
                 design: Design | None = None) -> None:
        self.limits = limits
        self.merge_m = float(merge_m)
        self.design = design  # with bank outputs: the probability of each exceedance
        self._seen = 0  # samples pushed so far: global sample indices
        self._open: dict[str, np.ndarray] | None = None  # deciding samples of the open run

    def push(self, chainage_m: np.ndarray, u_m: np.ndarray, speed_mps: np.ndarray,
             stamps_ns: np.ndarray, lower_m: np.ndarray | None = None,
             upper_m: np.ndarray | None = None,
             bank_u_m: np.ndarray | None = None,
             sensor_std_m: np.ndarray | None = None) -> list[Exceedance]:
        """Samples (K,) (bank outputs (P, K) with a design); returns the exceedances that ended
        before them."""
        u = np.asarray(u_m, dtype=float)
        thresholds = self.limits.at(chainage_m, speed_mps)
        near, far = magnitudes(u, lower_m, upper_m)
        lvl_far = level_of(far, thresholds)
        sel = np.flatnonzero(lvl_far > 0)  # near <= |u| <= far: elsewhere nothing passes
        lvl_c, lvl_near = (level_of(m[sel], thresholds[sel]) for m in (np.abs(u), near))
        cols = {'index': self._seen + sel, 'chainage': np.asarray(chainage_m, float)[sel],
                'stamp': np.asarray(stamps_ns)[sel], 'u': u[sel], 'far': far[sel],
                'lvl_c': lvl_c, 'lvl_near': lvl_near, 'lvl_far': lvl_far[sel],
                'lower': (u if lower_m is None else np.asarray(lower_m, float))[sel],
                'upper': (u if upper_m is None else np.asarray(upper_m, float))[sel],
                'speed': np.asarray(speed_mps, float)[sel],
                **{k: thresholds[sel, j] for j, k in enumerate(_LIMITS)}}
        if self.design is not None and bank_u_m is not None:  # for the probability at the peak
            cols['bank'] = np.asarray(bank_u_m, float)[:, sel].T  # (n, P)
            cols['sensor'] = np.zeros(sel.size) if sensor_std_m is None else \
                np.asarray(sensor_std_m, float)[sel]
        self._seen += u.size
        opened = self._open
        held = 0 if opened is None else opened['index'].size
        if opened is not None and held:
            cols = {k: np.concatenate([opened[k], cols[k]]) for k in cols}
        if cols['index'].size == 0:
            return []
        idx = cols['index']
        split = ((np.diff(idx) > 1) & (np.diff(cols['chainage']) > self.merge_m)) | \
            (np.diff(np.sign(cols['u'])) != 0)
        split[:max(held - 1, 0)] = False  # the held samples are one run
        starts = np.concatenate([[0], np.flatnonzero(split) + 1])
        closed = [_record({k: v[a:b] for k, v in cols.items()}, self.design)
                  for a, b in pairwise(starts)]
        last = {k: v[starts[-1]:] for k, v in cols.items()}
        self._open = {k: v[_deciding(last)] for k, v in last.items()}
        return closed

    def close(self) -> list[Exceedance]:
        """The exceedance still open at the end of the run (if any)."""
        last, self._open = self._open, None
        return [] if last is None else [_record(last, self.design)]


def _peak_key(run: dict[str, np.ndarray]) -> np.ndarray:
    """Peak: largest central magnitude in the run; when it passes nothing, the farthest edge."""
    return np.abs(run['u']) if run['lvl_c'].max() > 0 else run['far']


def _deciding(run: dict[str, np.ndarray]) -> np.ndarray:
    """Indices of the samples that decide a run's record, whatever follows: first, last, and
    the first maximum of each level and of both peak keys."""
    keys = (run['lvl_c'], run['lvl_near'], run['lvl_far'], np.abs(run['u']), run['far'])
    return np.unique([0, run['u'].size - 1, *(int(np.argmax(k)) for k in keys)])


def _record(run: dict[str, np.ndarray], design: Design | None = None) -> Exceedance:
    """The exceedance of one run of samples beyond a limit; its probabilities (with bank outputs
    ``run['bank']`` and a design, else NaN) are those of |u| passing its limit and the alert
    limit at its peak (``uncertainty.exceedance.exceedance_probability``: the germ samples the
    band's quantiles come from, with the sensor terms).

    Why at the record only, not at every sample beyond a limit: the record uses the peak's
    alone, and with a wide band (the location term grows with the run) most samples are beyond
    one: computing each one's (1024 germ samples, 3 limits) made a 2 h review 4x slower."""
    worst_c, worst_near, worst_far = (int(run[k].max()) for k in ('lvl_c', 'lvl_near', 'lvl_far'))
    level = worst_c if worst_c > 0 else worst_far
    confidence = ('possible' if worst_c == 0 else
                  'certain' if worst_near >= worst_c else 'likely')
    k = int(np.argmax(_peak_key(run)))
    limit = run[_LIMITS[level - 1]][k]
    alert = next((v for v in (run[name][k] for name in _LIMITS) if np.isfinite(v)), np.nan)
    probability = alert_probability = np.nan
    if design is not None and 'bank' in run:
        bank = run['bank'][k][:, None]
        probability, alert_probability = exceedance_probability(
            design, np.hstack([bank, bank]), np.array([limit, alert]), run['sensor'][k])
    return Exceedance(LEVELS[level - 1], confidence, float(run['chainage'][0]),
                      float(run['chainage'][-1]), float(run['chainage'][k]),
                      int(run['stamp'][k]), float(run['u'][k]), float(run['lower'][k]),
                      float(run['upper'][k]), float(limit), float(abs(run['speed'][k]) * 3.6),
                      float(probability), float(alert), float(alert_probability))


def listed(exceedances: list[Exceedance], min_probability: float) -> list[Exceedance]:
    """The exceedances a list cut at ``min_probability`` keeps: those whose central value
    passes the alert limit, those whose probability of passing their limit or the alert limit
    reaches the cut, and those without a probability (no band)."""
    return [e for e in exceedances
            if abs(e.peak_u_m) > e.alert_limit_m
            or not max(e.probability, e.alert_probability) < min_probability
            or np.isnan(e.probability)]


def find_exceedances(chainage_m: np.ndarray, u_m: np.ndarray, speed_mps: np.ndarray,
                     stamps_ns: np.ndarray, limits: Limits, lower_m: np.ndarray | None = None,
                     upper_m: np.ndarray | None = None, merge_m: float = 1.0
                     ) -> list[Exceedance]:
    """Exceedances along a run (all inputs (K,), chainage increasing), in chainage order."""
    tracker = ExceedanceTracker(limits, merge_m)
    return tracker.push(chainage_m, u_m, speed_mps, stamps_ns, lower_m, upper_m) + \
        tracker.close()


def count_by_level(exceedances: list[Exceedance]) -> dict[str, Counter[str]]:
    """Level -> Counter of confidences, every level present (empty counters included)."""
    counts: dict[str, Counter[str]] = {level: Counter() for level in LEVELS}
    for e in exceedances:
        counts[e.level][e.confidence] += 1
    return counts


def describe_counts(exceedances: list[Exceedance]) -> dict[str, str]:
    """Level -> 'n' or 'n (a certain, b likely, c possible)', most severe level first."""
    out = {}
    for level, counts in reversed(count_by_level(exceedances).items()):
        parts = ', '.join(f'{counts[c]} {c}' for c in CONFIDENCES if counts[c])
        total = sum(counts.values())
        out[level] = f'{total} ({parts})' if total else '0'
    return out
