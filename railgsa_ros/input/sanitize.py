"""Input sanitiser: classify every IMU sample before inversion; never raises on data.

Rejected samples are counted by reason: ``nan`` (non-finite acceleration or speed),
``wrong_frame``, ``saturated`` (|a| >= range - margin), ``stuck`` (the same value for longer than
``stuck_s``: a frozen sensor; off when 0), ``out_of_order`` and ``duplicate`` (stamp below or equal
to the newest accepted one). Time going backwards by more than ``backward_reset_s`` (a looped bag,
a simulated-clock reset) is a new stream: counted as ``time_reset``, the filters restart at that
sample instead of rejecting everything until the stamps pass the old maximum. Accepted samples
more than ``gap_factor`` nominal periods apart form a ``gap``: with policy ``reset`` the pipeline
restarts its filters there; with ``bridge`` a gap up to ``max_bridge_s`` is filled with synthetic
samples on the nominal period, linearly interpolated (they produce no output), and a longer gap
resets.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
import itertools

import numpy as np

from railgsa_ros.inverse.config import InversionConfig

#: fastest plausible rail vehicle (m/s, 720 km/h): odometry beyond it is a unit or data error
SPEED_LIMIT_MPS = 200.0
REASONS = ('nan', 'wrong_frame', 'saturated', 'stuck', 'out_of_order', 'duplicate')
#: chunks up to this many samples take the scalar paths of the sanitiser, the pipeline and the
#: policy (Python floats, the same operations in the same order as the vectorised ones:
#: bit-identical; a live push is 1-5 samples, where the fixed cost of numpy calls was most of
#: the cost)
SMALL = 8


def text_array(frame_ids: np.ndarray | Sequence[str]) -> np.ndarray:
    """frame_ids (T,) as a numpy str array when they are text (the reader's array: no copy),
    else as objects. A str array compares without a conversion: turning the reader's str
    arrays into objects and back to str cost about 3 ms per 16,384 samples and policy
    (measured on one core)."""
    ids = np.asarray(frame_ids)
    return ids if ids.dtype.kind == 'U' else np.asarray(frame_ids, dtype=object)


def frame_mask(frame_ids: np.ndarray | None, expected: str) -> np.ndarray | None:
    """True where a sample's frame_id is ``expected``; None when unchecked (no ids or '')."""
    if frame_ids is None or not expected:
        return None
    ids = np.asarray(frame_ids)
    return (ids if ids.dtype.kind == 'U' else ids.astype(str)) == expected


@dataclass(frozen=True)
class Clean:
    """Samples to invert: stamps_ns (N,) int64, accel (N,) m/s^2, speed (N,) m/s, synthetic (N,)
    (bridged, no output), reset_before (N,) (restart the filters before this sample) and index
    (N,) int64: the position of each sample in the chunk given to ``process`` (-1 for synthetic
    samples), None when every sample was accepted in order (index = arange)."""

    stamps_ns: np.ndarray
    accel: np.ndarray
    speed: np.ndarray
    synthetic: np.ndarray
    reset_before: np.ndarray
    index: np.ndarray | None = None

    def positions(self) -> np.ndarray:
        """``index`` as an array (arange when None)."""
        return np.arange(self.stamps_ns.size) if self.index is None else self.index

    def carry(self, quality: np.ndarray | None) -> np.ndarray:
        """The input quality codes (T,) of the chunk given to ``process`` (None: VALID) for
        these samples (N,) uint8: a synthetic sample's is VALID."""
        if quality is None:
            return np.zeros(self.accel.size, np.uint8)
        if self.index is None:  # every sample accepted in order
            return np.array(quality, np.uint8)
        pos = self.positions()
        return np.where(pos >= 0, np.asarray(quality, np.uint8)[np.maximum(pos, 0)], 0
                        ).astype(np.uint8)


class InputSanitizer:
    """Streaming classifier; ``counters`` holds rejected counts by reason plus gaps, resets and
    time resets. ``stuck_s`` (s, 0 = off) and ``backward_reset_s`` (s) as in the module text."""

    def __init__(self, rate_hz: float, gap_factor: float = 3.0, gap_policy: str = 'reset',
                 max_bridge_s: float = 0.05, saturation_mps2: float = 0.0,
                 saturation_margin_mps2: float = 0.0, frame_id: str = '', *,
                 stuck_s: float = 0.0, backward_reset_s: float = 1.0) -> None:
        self.period_ns = 1e9 / rate_hz
        self.gap_ns = gap_factor * self.period_ns
        self.gap_policy = gap_policy
        self.max_bridge_ns = max_bridge_s * 1e9
        self.limit = saturation_mps2 - saturation_margin_mps2 if saturation_mps2 > 0 else np.inf
        self.frame_id = frame_id
        self.set_limits(stuck_s, backward_reset_s)
        self.counters: Counter[str] = Counter()
        self._last: tuple[int, float, float] | None = None  # stamp, accel, speed of last accepted
        self._newest = np.iinfo(np.int64).min  # newest stamp seen (any sample)
        self._run: tuple[float, int] = (np.nan, 0)  # value and first stamp of the current run

    @classmethod
    def for_config(cls, config: InversionConfig, stuck_s: float = 0.0,
                   backward_reset_s: float = 1.0) -> InputSanitizer:
        """The sanitiser of an inversion config (rate, gaps, saturation, frame_id)."""
        return cls(config.rate_hz, config.gap_factor, config.gap_policy, config.max_bridge_s,
                   config.saturation_mps2, config.saturation_margin_mps2, config.frame_id,
                   stuck_s=stuck_s, backward_reset_s=backward_reset_s)

    def set_limits(self, stuck_s: float, backward_reset_s: float) -> None:
        """Stuck duration (s, 0 = off) and backward time jump (s) that starts a new stream."""
        self.stuck_ns = stuck_s * 1e9 if stuck_s > 0 else np.inf
        self.backward_ns = backward_reset_s * 1e9

    def reset(self) -> None:
        """Forget the last accepted sample (the next one starts a new stream)."""
        self._last = None
        self._newest = np.iinfo(np.int64).min
        self._run = (np.nan, 0)

    def process(self, stamps_ns: np.ndarray, accel: np.ndarray, speed: np.ndarray | float,
                frame_ids: np.ndarray | None = None) -> Clean:
        """Classify a chunk (stamps int64 ns, vertical accel m/s^2, speed m/s per sample or
        one for all, optional ids)."""
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        accel = np.asarray(accel, dtype=float)
        speed = np.asarray(speed, dtype=float)
        if speed.shape != accel.shape:  # (broadcast_to costs a live push 5 us)
            speed = np.broadcast_to(speed, accel.shape)
        if self._all_clean(stamps, accel, speed, frame_ids):
            return self._accept_all(stamps, accel, speed)
        parts, start, jumped = [], 0, False
        while True:  # one stream per backward time jump
            newest = np.maximum.accumulate(np.concatenate([[self._newest], stamps[start:]]))
            jumps = np.flatnonzero(stamps[start:] < newest[:-1] - self.backward_ns)
            end = stamps.size if jumps.size == 0 else start + int(jumps[0])
            self._newest = int(newest[end - start])
            sl = slice(start, end)
            part = self._classify(stamps[sl], accel[sl], speed[sl],
                                  None if frame_ids is None else frame_ids[sl])
            part.reset_before[:1] |= jumped  # time went backwards here: a new stream
            pos = part.positions()
            parts.append(Clean(part.stamps_ns, part.accel, part.speed, part.synthetic,
                               part.reset_before, np.where(pos >= 0, pos + start, -1)))
            if end == stamps.size:
                break
            self.reset()
            self.counters['time_reset'] += 1
            start, jumped = end, True
        if len(parts) == 1:
            return parts[0]
        return Clean(*(np.concatenate(f) for f in zip(
            *((p.stamps_ns, p.accel, p.speed, p.synthetic, p.reset_before, p.index)
              for p in parts), strict=True)))

    def _all_clean(self, stamps: np.ndarray, accel: np.ndarray, speed: np.ndarray,
                   frame_ids: np.ndarray | None) -> bool:
        """True when the full classification would accept every sample of the chunk and find
        no gap and no time reset: every frame the expected one (or unchecked), no value
        repeated (when stuck detection is on: every sample then starts a run, none is stuck),
        every |accel| below the saturation limit (so finite: NaN fails every comparison),
        speed finite, stamps strictly increasing from the newest accepted one with steps up to
        the gap limit, and the first stamp no backward jump. A handful of reductions instead of
        the per-sample masks."""
        if stamps.size == 0:
            return False
        frames = frame_mask(frame_ids, self.frame_id)
        if frames is not None and not frames.all():
            return False
        speed = speed[:1] if speed.strides == (0,) else speed  # one value broadcast
        if stamps.size <= SMALL:  # the same comparisons in Python floats (a live push)
            a, v, limit = accel.tolist(), speed.tolist(), self.limit
            if self.stuck_ns < np.inf and (a[0] == self._run[0] or any(
                    x == y for x, y in zip(a[1:], a[:-1], strict=True))):
                return False
            if not (all(-limit < x < limit for x in a) and all(-np.inf < x < np.inf for x in v)):
                return False
        else:
            if self.stuck_ns < np.inf and (accel[0] == self._run[0]
                                           or np.any(accel[1:] == accel[:-1])):
                return False
            if not (accel.max() < self.limit and accel.min() > -self.limit
                    and speed.max() < np.inf and speed.min() > -np.inf):
                return False
        first = stamps[0]
        if self._last is not None:
            if not (first > self._last[0] and first - self._last[0] <= self.gap_ns):
                return False
        elif first == np.iinfo(np.int64).min:  # equal to the initial newest: a duplicate
            return False
        if first < self._newest - self.backward_ns:
            return False
        if stamps.size == 1:
            return True
        if stamps.size <= SMALL:  # exact steps (a range >= 2^62 has a step beyond the gap)
            t = stamps.tolist()
            steps = [b - a for a, b in itertools.pairwise(t)]
            return min(steps) > 0 and max(steps) <= self.gap_ns
        # steps as the int64 differences (stamps within 2^62 ns of each other cannot wrap; others
        # go to the full classification, which compares them directly)
        if int(stamps.max()) - int(stamps.min()) >= 1 << 62:
            return False
        steps = stamps[1:] - stamps[:-1]
        return bool(steps.min() > 0 and steps.max() <= self.gap_ns)

    def _accept_all(self, stamps: np.ndarray, accel: np.ndarray, speed: np.ndarray) -> Clean:
        """Outcome of the classification for a chunk that ``_all_clean`` passed."""
        n = stamps.size
        self._newest = max(self._newest, int(stamps[-1]))
        self._last = (int(stamps[-1]), float(accel[-1]), float(speed[-1]))
        if np.isfinite(self.stuck_ns):  # the last sample started the current run
            self._run = (float(accel[-1]), int(stamps[-1]))
        if 'accepted' in self.counters:  # every key is there: count the accepted alone
            self.counters['accepted'] += n
        else:
            self.counters.update({**dict.fromkeys(REASONS, 0), 'accepted': n, 'gap': 0})
        return Clean(stamps, accel, speed, np.zeros(n, bool), np.zeros(n, bool))

    def _stuck(self, stamps: np.ndarray, accel: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """True where an ok sample repeats the current run's value for longer than stuck_s."""
        stuck = np.zeros_like(ok)
        if not np.isfinite(self.stuck_ns) or not ok.any():
            return stuck
        idx = np.flatnonzero(ok)
        a, t = accel[idx], stamps[idx]
        value, start = self._run
        change = np.concatenate([[a[0] != value], a[1:] != a[:-1]])
        starts = np.where(change, t, np.iinfo(np.int64).min)
        starts[0] = t[0] if change[0] else start
        run_start = np.maximum.accumulate(starts)
        stuck[idx] = (t - run_start) > self.stuck_ns
        self._run = (float(a[-1]), int(run_start[-1]))
        return stuck

    def _classify(self, stamps: np.ndarray, accel: np.ndarray, speed: np.ndarray,
                  frame_ids: np.ndarray | None) -> Clean:
        """Classify samples of one stream (no backward time jump inside)."""
        finite = np.isfinite(accel) & np.isfinite(speed)
        ok = finite.copy()
        frames = frame_mask(frame_ids, self.frame_id)
        wrong = np.zeros_like(ok) if frames is None else ok & ~frames
        ok &= ~wrong
        sat = ok & (np.abs(accel) >= self.limit)  # NaN compares False
        ok &= ~sat
        stuck = self._stuck(stamps, accel, ok)
        ok &= ~stuck
        sel = slice(None) if ok.all() else np.flatnonzero(ok)  # usual case: no index copies
        kept = stamps[sel]
        last = self._last[0] if self._last is not None else np.iinfo(np.int64).min
        if kept.size == 0 or (kept[0] > last and np.all(kept[1:] > kept[:-1])):
            dup = ooo = np.zeros(0, bool)  # strictly increasing: no running maximum needed
        else:
            prev = np.maximum.accumulate(np.concatenate([[last], kept]))[:-1]
            dup, ooo = kept == prev, kept < prev
            sel = np.flatnonzero(ok)[~(dup | ooo)]
        accepted = stamps[sel]
        self.counters.update({'nan': int(np.sum(~finite)), 'wrong_frame': int(wrong.sum()),
                              'saturated': int(sat.sum()), 'stuck': int(stuck.sum()),
                              'duplicate': int(dup.sum()),
                              'out_of_order': int(ooo.sum()), 'accepted': accepted.size})
        index = np.arange(stamps.size)[sel]
        return self._gaps(accepted, accel[sel], speed[sel], index)

    def _gaps(self, stamps: np.ndarray, accel: np.ndarray, speed: np.ndarray,
              index: np.ndarray) -> Clean:
        """Mark gaps among accepted samples (chunk positions ``index``); bridge the short ones
        when the policy says so."""
        n = stamps.size
        reset = np.zeros(n, bool)
        if n == 0:
            return Clean(stamps, accel, speed, reset.copy(), reset, index)
        if self._last is None:
            prev_t, prev_a, prev_v = stamps[0], accel[0], speed[0]
        else:
            prev_t, prev_a, prev_v = self._last
        self._last = (int(stamps[-1]), float(accel[-1]), float(speed[-1]))
        all_t = np.concatenate([[prev_t], stamps])
        all_a, all_v = np.concatenate([[prev_a], accel]), np.concatenate([[prev_v], speed])
        dt = np.diff(all_t).astype(float)
        gaps = np.flatnonzero(dt > self.gap_ns)
        self.counters['gap'] += gaps.size
        if gaps.size == 0:
            return Clean(stamps, accel, speed, reset.copy(), reset, index)
        bridge = (dt[gaps] <= self.max_bridge_ns) if self.gap_policy == 'bridge' else \
            np.zeros(gaps.size, bool)
        reset[gaps[~bridge]] = True
        self.counters['reset'] += int((~bridge).sum())
        # synthetic samples on the nominal period inside each bridged gap, interpolated
        n_syn = np.where(bridge, np.rint(dt[gaps] / self.period_ns).astype(int) - 1, 0)
        n_syn = np.maximum(n_syn, 0)
        self.counters['bridged'] += int(n_syn.sum())
        which = np.repeat(gaps, n_syn)
        frac = (np.arange(n_syn.sum()) - np.repeat(np.cumsum(n_syn) - n_syn, n_syn) + 1) \
            / np.repeat(n_syn + 1, n_syn)
        syn_t = all_t[which] + np.rint(frac * dt[which]).astype(np.int64)
        syn_a = all_a[which] + frac * (all_a[which + 1] - all_a[which])
        syn_v = all_v[which] + frac * (all_v[which + 1] - all_v[which])
        # insert before real sample `which` (index into the chunk)
        pos = np.insert(np.arange(n), np.repeat(gaps, n_syn), -1)
        real = pos >= 0
        out_t = np.empty(pos.size, np.int64)
        out_a, out_v = np.empty(pos.size), np.empty(pos.size)
        out_t[real], out_a[real], out_v[real] = stamps, accel, speed
        out_t[~real], out_a[~real], out_v[~real] = syn_t, syn_a, syn_v
        out_reset = np.zeros(pos.size, bool)
        out_reset[real] = reset
        out_index = np.full(pos.size, -1)
        out_index[real] = index
        return Clean(out_t, out_a, out_v, ~real, out_reset, out_index)
