"""Input sanitiser: every reason classified and counted, gaps reset or bridged, never raises."""

import numpy as np
import pytest

from railgsa_ros.input.sanitize import InputSanitizer, frame_mask

MS = 1_000_000


def stamps(n, start=0):
    return (np.arange(n, dtype=np.int64) + start) * MS


def test_clean_stream_passes_unchanged():
    san = InputSanitizer(1000.0)
    t = stamps(100)
    a = np.linspace(9.0, 10.0, 100)
    out = san.process(t, a, 20.0)
    assert np.array_equal(out.stamps_ns, t) and np.array_equal(out.accel, a)
    assert not out.synthetic.any() and not out.reset_before.any()
    assert san.counters['accepted'] == 100


def test_each_rejection_reason_is_counted():
    san = InputSanitizer(1000.0, saturation_mps2=19.6, saturation_margin_mps2=0.1,
                         frame_id='imu_link')
    t = stamps(10)
    t[4] = t[3]  # duplicate
    t[6] = t[2]  # out of order
    a = np.full(10, 9.8)
    a[1] = np.nan
    a[2] = np.inf
    a[8] = -19.55  # within the margin of the range
    speed = np.full(10, 20.0)
    speed[9] = np.nan
    ids = np.array(['imu_link'] * 10)
    ids[7] = 'base_link'
    out = san.process(t, a, speed, ids)
    c = san.counters
    assert (c['nan'], c['duplicate'], c['out_of_order'], c['saturated'], c['wrong_frame']) == \
        (3, 1, 1, 1, 1)
    assert list(out.stamps_ns // MS) == [0, 3, 5]
    assert np.all(np.isfinite(out.accel))


def test_order_is_checked_across_chunks():
    san = InputSanitizer(1000.0)
    san.process(stamps(5), np.ones(5), 1.0)
    out = san.process(stamps(3, start=3), np.ones(3), 1.0)
    assert list(out.stamps_ns // MS) == [5]
    assert san.counters['duplicate'] == 1 and san.counters['out_of_order'] == 1


def test_gap_reset_marks_the_first_sample_after_it():
    san = InputSanitizer(1000.0, gap_factor=3.0, gap_policy='reset')
    t = np.r_[stamps(10), stamps(10, start=50)]
    out = san.process(t, np.ones(20), 1.0)
    assert np.flatnonzero(out.reset_before).tolist() == [10]
    assert san.counters['gap'] == 1 and san.counters['reset'] == 1


def test_bridge_interpolates_short_gaps_and_resets_long_ones():
    san = InputSanitizer(1000.0, gap_policy='bridge', max_bridge_s=0.02)
    t = np.r_[stamps(5), stamps(5, start=15), stamps(5, start=100)]
    a = np.r_[np.zeros(5), np.full(5, 10.0), np.zeros(5)]
    out = san.process(t, a, 1.0)
    syn = out.synthetic
    assert syn.sum() == 10  # stamps 5..14 ms inserted
    assert np.array_equal(out.stamps_ns[:20] // MS, np.arange(20))
    assert np.allclose(out.accel[5:15], np.arange(1, 11) * 10.0 / 11)  # 0 at 4 ms, 10 at 15 ms
    assert np.flatnonzero(out.reset_before).tolist() == [20]
    assert san.counters['bridged'] == 10 and san.counters['reset'] == 1


def test_empty_and_all_bad_chunks_do_not_raise():
    san = InputSanitizer(1000.0)
    out = san.process(np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
    assert out.accel.size == 0
    out = san.process(stamps(4), np.full(4, np.nan), 1.0)
    assert out.accel.size == 0 and san.counters['nan'] == 4


def test_frame_mask_helper():
    assert frame_mask(None, 'imu_link') is None
    assert frame_mask(np.array(['a', 'b']), '') is None
    assert frame_mask(np.array(['imu_link', 'x']), 'imu_link').tolist() == [True, False]


@pytest.mark.parametrize('stuck_s', [0.0, 0.01])
def test_clean_chunk_fast_path_matches_the_full_classification(stuck_s):
    """Chunks that are clean, or clean but for one edge (a stamp equal to the last one, a step
    at or just past the gap limit, a backward jump, NaN, saturation, an extreme stamp, a wrong
    frame, a value run continued from the last chunk, a stuck stretch; with and without frame
    ids), give the same samples, state and counters with the fast path as with the full
    classification, and clean chunks take the fast path (with stuck detection on: those
    without a repeated value)."""
    rng = np.random.default_rng(3)
    chunks = []
    start = 0
    for edge in range(12):
        t = stamps(50, start)
        ids = None if edge % 3 == 0 else np.full(50, 'imu_link')
        a = 9.8 + 0.01 * rng.standard_normal(50)
        speed = 20.0 if edge % 2 else np.full(50, 20.0)
        if edge == 1:
            t -= MS  # first stamp equals the last accepted one
        elif edge == 2:
            t[10:] += 2 * MS  # a step of exactly gap_factor periods: no gap
        elif edge == 3:
            t[10:] += 2 * MS + 1  # one nanosecond more: a gap
        elif edge == 4:
            t -= 10**10  # backward jump: a time reset
        elif edge == 5:
            a[7] = np.nan
        elif edge == 6:
            a[9] = -19.55  # beyond the saturation limit of 19.5
        elif edge == 7:
            t[-1] = np.iinfo(np.int64).max  # a step wrapping around in int64
        elif edge == 8:
            ids[5] = 'base_link'
        elif edge == 10:
            a[:3] = chunks[-1][1][-1]  # the last chunk's final value goes on for 3 samples
        elif edge == 11:
            a[:] = 9.8  # 50 ms of one value: stuck after 10 ms when detection is on
        chunks.append((t, a, speed, ids))
        start = int(t[-1] // MS) + 1 if edge != 7 else int(t[-2] // MS) + 2
    settings = {'saturation_mps2': 19.6, 'saturation_margin_mps2': 0.1,
                'frame_id': 'imu_link', 'stuck_s': stuck_s}
    fast, full = InputSanitizer(1000.0, **settings), InputSanitizer(1000.0, **settings)
    full._all_clean = lambda *args: False
    slow = []
    classify = fast._classify
    fast._classify = lambda *args: slow.append(1) or classify(*args)
    took_fast = []
    for t, a, speed, ids in chunks:
        calls = len(slow)
        got, want = fast.process(t, a, speed, ids), full.process(t, a, speed, ids)
        took_fast.append(len(slow) == calls)
        for field in ('stamps_ns', 'accel', 'speed', 'synthetic', 'reset_before'):
            assert np.array_equal(getattr(got, field), getattr(want, field)), field
        assert (fast._last, fast._newest, fast._run) == (full._last, full._newest, full._run)
    assert fast.counters == full.counters and fast.counters['wrong_frame'] == 1
    assert fast.counters['stuck'] == (39 if stuck_s else 0)  # 11-49 ms into the run
    clean = [0, 2, 9] if stuck_s else [0, 2, 9, 10, 11]  # with ids (2, 10, 11) or without
    assert np.flatnonzero(took_fast).tolist() == clean
