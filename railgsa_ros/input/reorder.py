"""Re-order IMU samples by header stamp within a bounded window, streaming.

Recorders stamp the log time on receipt, so a driver that publishes in bursts or from several
threads gives a bag (or a live stream) whose header stamps are locally out of order by a few ms.
:class:`Reorder` holds each sample until a stamp ``window_s`` newer has arrived (or ``cap`` later
samples have), then releases the held samples in stamp order (ties in arrival order). A sample
whose stamp is more than ``window_s`` older than the newest stamp before it is *late*: it is
passed on at once, in its arrival position, where the sanitiser rejects it as ``out_of_order``;
``counters`` say how many were re-ordered and how many were late, and by how much.

The release of each sample is decided per sample in arrival order (the newest stamp so far, its
arrival index), so the output sequence does not depend on how the input was batched: a replay in
pushes of 1-10 samples gives what an offline run in pieces of 65536 gives. Without late samples
the output is in stamp order. A stamp going back by more than ``backward_ns`` (a looped bag) is a
new stream: everything held is released before it. Latency: ``window_s`` of stamp time; memory:
the samples of one window, at most ``cap``.
"""

from __future__ import annotations

from collections import Counter
import itertools

import numpy as np

from railgsa_ros.input.findings import OK, WARN
from railgsa_ros.input.sanitize import SMALL

#: stamps (T,) int64 ns, accel (T, 3) (a coach's stage: (T, 4) with the pitch rate), frame ids
#: (T,) str or object, covariance (T, 9) or None
Columns = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]
#: Columns and the arrival indices (T,) int64
Store = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]
_NONE = np.iinfo(np.int64).min
STORE_ROOM = 4  #: a new backing store holds this many times the samples it starts with


class Reorder:
    """IMU samples (stamps ns, accel (T, 3), frame ids (T,), covariance (T, 9) or None) in
    arrival order in, in stamp order out. ``window_s`` (s, 0 = off: the arrival order),
    ``backward_reset_s`` (s, > window_s), ``cap``: the most samples held (a frozen stamp).

    ``counters``: ``reordered`` (samples that arrived after a newer stamp, within the window),
    ``late`` (beyond it); ``largest_ns``: the largest disorder of each kind (ns)."""

    def __init__(self, window_s: float, backward_reset_s: float, cap: int) -> None:
        self.configure(window_s, backward_reset_s, cap)
        self.counters: Counter[str] = Counter()
        self.largest_ns = {'reordered': 0, 'late': 0}
        self._newest = _NONE  # newest stamp seen in this stream
        self._arrived = 0  # samples pushed so far
        self._held: Columns | None = None
        self._held_idx = np.zeros(0, np.int64)  # their arrival indices
        # backing arrays (stamps, accel, frames, covariance, arrival) whose rows lo:hi are the
        # held samples (views), None while the held ones are not views of it
        self._store: Store | None = None
        self._span = (0, 0)

    def configure(self, window_s: float, backward_reset_s: float, cap: int) -> None:
        """New window (s), backward jump (s) and cap (samples); held samples are kept."""
        self.window_s = window_s
        self.window_ns = round(window_s * 1e9)
        self.backward_ns = round(backward_reset_s * 1e9)
        self.cap = max(int(cap), 1)

    @property
    def held(self) -> int:
        """Samples waiting for their release."""
        return int(self._held_idx.size)

    def verdict(self) -> tuple[int, str]:
        """The 'order' finding's level and message: IMU stamps out of arrival order,
        re-ordered or late (``reorder_window_s``)."""
        counts, largest, window = self.counters, self.largest_ns, self.window_s
        if counts['late']:
            return WARN, (
                f'{counts["late"]} IMU samples arrived more than reorder_window_s '
                f'({window * 1e3:g} ms) after a newer stamp (by up to '
                f'{largest["late"] / 1e6:.4g} ms): not re-ordered, rejected as out_of_order; '
                'check the driver clock, or raise reorder_window_s above that')
        return OK, (
            f'{counts["reordered"]} IMU samples re-ordered by header stamp (by up to '
            f'{largest["reordered"] / 1e6:.4g} ms, within reorder_window_s '
            f'{window * 1e3:g} ms)')

    def push(self, stamps: np.ndarray, accel: np.ndarray, frames: np.ndarray,
             cov: np.ndarray | None) -> Columns:
        """Samples in arrival order; returns those released now, in release order."""
        if stamps.size <= SMALL:
            fast = self._in_order(stamps, accel, frames, cov)
            if fast is not None:
                return fast
        out, start = [], 0
        while start < stamps.size:  # one stream per backward jump beyond backward_ns
            base = stamps[start] if self._newest == _NONE else self._newest
            newest = np.maximum(np.maximum.accumulate(stamps[start:]), base)
            before = np.concatenate([[base], newest[:-1]])
            jumps = np.flatnonzero(stamps[start:] < before - self.backward_ns)
            end = stamps.size if jumps.size == 0 else start + int(jumps[0])
            if end > start:
                sl = slice(start, end)
                out.append(self._segment((stamps[sl], accel[sl], frames[sl],
                                          None if cov is None else cov[sl]),
                                         newest[:end - start], before[:end - start]))
            if end < stamps.size:  # a new stream: release everything held before it
                out.append(self.drain())
            start = end
        return _join(out, (stamps, accel, frames, cov))

    def drain(self) -> Columns:
        """Release every held sample (end of input or of a stream); the next starts afresh."""
        held = self._held
        self._held, self._held_idx, self._newest = None, np.zeros(0, np.int64), _NONE
        self._store = None
        if held is None:
            return _empty()
        return held

    def _in_order(self, stamps: np.ndarray, accel: np.ndarray, frames: np.ndarray,
                  cov: np.ndarray | None) -> Columns | None:
        """What ``_segment`` returns for a live push of a few samples in stamp order after the
        newest one, none held for ``cap`` arrivals (no disorder to count), in Python ints;
        None for any other push."""
        t = stamps.tolist()
        if not t or self._newest == _NONE or t[0] < self._newest or any(
                b < a for a, b in itertools.pairwise(t)):
            return None
        held, hidx, n = self._held, self._held_idx, len(t)
        last = self._arrived + n - 1
        if held is not None and int(hidx.min()) <= last - self.cap:
            return None
        threshold = t[-1] - self.window_ns
        fresh = sum(x <= threshold for x in t)  # new samples released (then every held one)
        idx = np.arange(self._arrived, last + 1, dtype=np.int64)
        self._arrived, self._newest = last + 1, t[-1]
        cols = (stamps, accel, frames, cov)
        if held is None:
            return self._keep(cols, idx, None, fresh)
        if fresh:
            return self._keep(_concat([held, cols]), np.concatenate([hidx, idx]), None,
                              hidx.size + fresh)
        count = int(np.searchsorted(held[0], threshold, side='right'))
        released = _take(held, slice(0, count))
        self._append(count, cols, idx)
        return released

    def _append(self, count: int, cols: Columns, idx: np.ndarray) -> None:
        """Hold ``held[count:]`` then ``cols`` (arrival indices ``idx``): the new rows written
        into the backing store's spare room where they fit (a live push: no copy of the held
        window, which the join of arrays made on every push), else into a new store with room
        for STORE_ROOM windows of such pushes."""
        held = self._held
        assert held is not None
        n = idx.size
        lo, hi = self._span
        store = self._store
        with_cov = held[3] is not None or cols[3] is not None  # as _concat joins them
        if store is None or with_cov != (store[3] is not None) or hi + n > store[0].size:
            kept = (*_take(held, slice(count, None)), self._held_idx[count:])
            room = STORE_ROOM * (kept[0].size + n)
            store = (np.empty(room, np.int64), np.empty((room, cols[1].shape[1])),
                     np.empty(room, object),
                     np.empty((room, 9)) if with_cov else None, np.empty(room, np.int64))
            lo, hi = 0, kept[0].size
            _write(store, kept, 0)
            self._store = store
        else:
            lo += count
        _write(store, (*cols, idx), hi)
        hi += n
        self._span = (lo, hi)
        t, a, f, c, i = store
        self._held = (t[lo:hi], a[lo:hi], f[lo:hi], None if c is None else c[lo:hi])
        self._held_idx = i[lo:hi]

    def _note(self, behind: np.ndarray, late: np.ndarray) -> None:
        """Count the disorder ``behind`` (ns, newest before minus own stamp) by kind."""
        for kind, mask in (('late', late), ('reordered', (behind > 0) & ~late)):
            if mask.any():
                self.counters[kind] += int(mask.sum())
                self.largest_ns[kind] = max(self.largest_ns[kind], int(behind[mask].max()))

    def _segment(self, cols: Columns, newest: np.ndarray, before: np.ndarray) -> Columns:
        """Samples of one stream (``newest``: the newest stamp up to each, ``before``: before
        each)."""
        t = cols[0]
        n = t.size
        behind = before - t
        late = behind > self.window_ns
        self._note(behind, late)
        self._newest = int(newest[-1])
        idx = self._arrived + np.arange(n, dtype=np.int64)
        self._arrived += n
        held, hidx = self._held, self._held_idx
        allc = cols if held is None else _concat([held, cols])
        all_t, all_idx = allc[0], np.concatenate([hidx, idx])
        threshold = newest - self.window_ns  # a held sample at or below it is released
        last = int(idx[-1])
        if not late.any() and all_idx.min() > last - self.cap:  # no late sample, none held for
            # cap arrivals: the output is in stamp order
            order = None if (np.all(t[1:] >= t[:-1]) and (
                held is None or t[0] >= held[0][-1])) else np.argsort(all_t, kind='stable')
            st = all_t if order is None else all_t[order]
            count = int(np.searchsorted(st, threshold[-1], side='right'))
            return self._keep(allc, all_idx, order, count)
        # general case: the step at which each sample is released, then (step, stamp, arrival)
        pos = np.maximum(all_idx - idx[0], 0)  # arrival step in this segment (held: 0)
        step = np.maximum(pos, np.searchsorted(threshold, all_t, side='left'))
        step = np.where(np.concatenate([np.zeros(hidx.size, bool), late]), pos, step)
        step = np.minimum(step, all_idx + self.cap - idx[0])  # release by age
        step = np.where(step < n, step, n)
        order = np.lexsort((all_idx, all_t, step))
        return self._keep(allc, all_idx, order, int(np.count_nonzero(step < n)))

    def _keep(self, cols: Columns, idx: np.ndarray, order: np.ndarray | None,
              count: int) -> Columns:
        """Release the first ``count`` samples of ``cols`` in ``order``; hold the rest."""
        if order is not None:
            cols = _take(cols, order)
            idx = idx[order]
        self._store = None
        if count == idx.size:
            self._held, self._held_idx = None, np.zeros(0, np.int64)
            return cols
        self._held = _take(cols, slice(count, None))
        self._held_idx = idx[count:]
        return _take(cols, slice(0, count))


def _write(store: Store, rows: Store, at: int) -> None:
    """Write ``rows`` into ``store`` from row ``at``; rows without a covariance where the
    store has one get zeros (unknown, as ``_concat`` fills them)."""
    end = at + rows[0].shape[0]
    for dst, src in zip(store, rows, strict=True):
        if dst is not None:
            dst[at:end] = 0.0 if src is None else src


def _take(cols: Columns, sel: np.ndarray | slice) -> Columns:
    stamps, accel, frames, cov = cols
    return stamps[sel], accel[sel], frames[sel], None if cov is None else cov[sel]


def _empty() -> Columns:
    return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, dtype=object), None


def _concat(parts: list[Columns]) -> Columns:
    """Join released pieces; a covariance missing in some pieces is unknown there (zeros)."""
    parts = [p for p in parts if p[0].size]
    if not parts:
        return _empty()
    if len(parts) == 1:
        return parts[0]
    with_cov = any(p[3] is not None for p in parts)
    cov = np.concatenate([p[3] if p[3] is not None else np.zeros((p[0].size, 9))
                          for p in parts]) if with_cov else None
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            np.concatenate([p[2] for p in parts]), cov)


def _join(parts: list[Columns], given: Columns) -> Columns:
    """``_concat`` of the released parts; an empty release keeps the input's types."""
    out = _concat(parts)
    return out if out[0].size else _take(given, slice(0, 0))
