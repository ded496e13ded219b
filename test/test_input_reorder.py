"""The IMU re-order buffer against a brute-force reference (one sample at a time, a heap)."""

from __future__ import annotations

import heapq

import numpy as np
import pytest

from railgsa_ros.input.reorder import Reorder

MS = 1_000_000


def reference(stamps: list[int], window: int, cap: int, backward: int) -> list[int]:
    """Arrival indices in release order, one sample at a time: a late sample (more than
    ``window`` behind the newest stamp before it) passes at once; the others wait in a heap
    until the newest stamp is ``window`` ahead of them or ``cap`` later samples arrived. What
    one arrival releases goes out in stamp order."""
    out: list[int] = []
    heap: list[tuple[int, int]] = []
    newest = None
    for i, t in enumerate(stamps):
        if newest is not None and t < newest - backward:  # a new stream
            out += [j for _, j in sorted(heap)]
            heap, newest = [], None
        late = bool(newest is not None and t < newest - window)
        if not late:
            newest = t if newest is None else max(newest, t)
            heapq.heappush(heap, (t, i))
        due = [e for e in heap if e[0] <= newest - window or e[1] <= i - cap]
        for e in due:
            heap.remove(e)
        heapq.heapify(heap)
        out += [j for _, j in sorted(due + [(t, i)] * late)]  # one step: in stamp order
    return out + [j for _, j in sorted(heap)]


def run(buffer: Reorder, stamps: np.ndarray, sizes: list[int]) -> np.ndarray:
    """Arrival indices in release order, pushed in pieces of ``sizes`` (cycled)."""
    idx = np.arange(stamps.size, dtype=float)
    accel = np.stack([idx, idx, idx], axis=1)
    frames = np.full(stamps.size, 'imu', dtype=object)
    out, start, k = [], 0, 0
    while start < stamps.size:
        sl = slice(start, start + sizes[k % len(sizes)])
        out.append(buffer.push(stamps[sl], accel[sl], frames[sl], None)[1][:, 0])
        start, k = sl.stop, k + 1
    out.append(buffer.drain()[1][:, 0])
    return np.concatenate(out).astype(int)


def jittered(n: int, jitter_ms: float, seed: int) -> np.ndarray:
    """1 kHz stamps in the order of arrival with a receipt jitter up to ``jitter_ms``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.int64) * MS + 10**12
    return t[np.argsort(t + rng.uniform(0, jitter_ms * MS, n), kind='stable')]


@pytest.mark.parametrize('sizes', [[1], [3, 1, 7], [1000]])
def test_local_disorder_comes_out_sorted_whatever_the_batching(sizes: list[int]) -> None:
    stamps = jittered(3000, 8.0, 1)
    buffer = Reorder(0.01, 1.0, 100)
    out = run(buffer, stamps, sizes)
    assert np.array_equal(stamps[out], np.sort(stamps))
    assert buffer.counters['late'] == 0 and buffer.counters['reordered'] > 100
    assert 0 < buffer.largest_ns['reordered'] <= 10 * MS
    assert buffer.held == 0


@pytest.mark.parametrize('seed', range(6))
def test_equal_to_the_one_sample_reference(seed: int) -> None:
    """Jitter beyond the window, duplicates, a frozen clock (cap), a jump back (new stream)."""
    rng = np.random.default_rng(seed)
    t = list(jittered(800, 30.0, seed))
    t[100:140] = [t[100]] * 40  # frozen stamps: released by the cap
    t[300] = t[299]  # a duplicate
    t[500:] = [x - 5000 * MS for x in t[500:]]  # time back 5 s: a new stream
    stamps = np.array(t, np.int64)
    window, cap = int(rng.integers(0, 20)) * MS, int(rng.integers(5, 40))
    want = reference(t, window, cap, 1000 * MS)
    for sizes in ([1], [2, 5, 1], [64], [800]):
        got = run(Reorder(window / 1e9, 1.0, cap), stamps, sizes)
        assert got.tolist() == want, sizes


def test_late_samples_counted_with_their_disorder() -> None:
    t = np.arange(200, dtype=np.int64) * MS
    t[[50, 120]] -= [70 * MS, 90 * MS]  # a stamp 70 ms (90 ms) behind arrives: beyond 50 ms
    t[150] -= 20 * MS  # 20 ms behind: within the window
    buffer = Reorder(0.05, 1.0, 200)
    out = run(buffer, t, [4])
    assert sorted(out.tolist()) == list(range(200))  # nothing lost
    assert buffer.counters == {'late': 2, 'reordered': 1}
    assert buffer.largest_ns == {'late': 89 * MS, 'reordered': 19 * MS}  # behind the one before


def test_window_zero_is_the_arrival_order() -> None:
    stamps = jittered(500, 5.0, 2)
    buffer = Reorder(0.0, 1.0, 1)
    assert np.array_equal(run(buffer, stamps, [7]), np.arange(500))
    assert buffer.counters['late'] > 0 and buffer.held == 0


@pytest.mark.parametrize('sizes', [[1], [2, 5, 1], [3, 1], [64]])
def test_every_row_keeps_its_columns_with_and_without_covariance(sizes: list[int]) -> None:
    """Released rows carry their own accel, frame id and covariance whatever the batching (the
    live path writes pushes into a store behind the held window); a push without a
    covariance gives its rows zeros (unknown) when released with rows that have one."""
    n = 900
    stamps = jittered(n, 8.0, 3)
    idx = np.arange(n, dtype=float)
    accel = np.stack([idx, -idx, 2 * idx], axis=1)
    frames = np.array([f'imu{k % 7}' for k in range(n)], dtype=object)
    cov = np.tile(idx[:, None] + 1.0, (1, 9))
    buffer, had = Reorder(0.01, 1.0, 100), np.zeros(n, bool)
    released, start, k = [], 0, 0
    while start < n:
        sl = slice(start, start + sizes[k % len(sizes)])
        with_cov = (start // 50) % 3 != 0  # runs of pushes without a covariance
        had[sl] = with_cov
        released.append(buffer.push(stamps[sl], accel[sl], frames[sl],
                                    cov[sl] if with_cov else None))
        start, k = sl.stop, k + 1
    released.append(buffer.drain())
    for t, a, f, c in released:
        j = (stamps.size and a[:, 0]).astype(int)
        assert np.array_equal(t, stamps[j]) and np.array_equal(a, accel[j])
        assert np.array_equal(f, frames[j])
        want = np.where(had[j][:, None], cov[j], 0.0)
        assert np.array_equal(c, want) if c is not None else not want.any()
    assert sorted(np.concatenate([r[1][:, 0] for r in released]).astype(int)) == list(range(n))
