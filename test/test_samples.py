"""samples.join / split / pieces: the one concatenation and cut of per-sample records."""

from __future__ import annotations

import numpy as np

from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.samples import join, pieces, split
from railgsa_ros.uncertainty import Band


def bank_output(start: int, k: int, p: int = 3) -> Output:
    """A (P, K) bank output with distinct values per sample."""
    t = np.arange(start, start + k)
    return Output(t.astype(np.int64), t * 0.5, np.vstack([t * (i + 1.0) for i in range(p)]),
                  (t % 3).astype(np.uint8), t * 0.1)


def test_join_then_split_gives_the_parts_back_along_the_sample_axis() -> None:
    parts = [bank_output(0, 4), bank_output(4, 0), bank_output(4, 7)]
    whole = join(parts, bank_output(0, 0))
    np.testing.assert_array_equal(whole.u_m, np.hstack([p.u_m for p in parts]))
    np.testing.assert_array_equal(whole.stamps_ns, np.arange(11))
    head, tail = split(whole, 4)
    for got, want in ((head, parts[0]), (tail, parts[2])):
        for name in ('stamps_ns', 'chainage_m', 'u_m', 'quality', 'speed_mps'):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))


def test_a_missing_column_stays_missing_and_no_samples_give_the_empty_record() -> None:
    band = Band(np.arange(2), np.zeros(2), np.zeros(2), np.ones(2), np.full(2, 2.0))
    joined = Band.concat([band, band])
    assert len(joined) == 4 and joined.quality is None
    assert len(Band.concat([])) == 0 and Band.concat([]).quality.dtype == np.uint8
    assert Output.concat([], channels=5).u_m.shape == (5, 0)


def test_pieces_cover_every_sample_once() -> None:
    covered = np.concatenate([np.arange(20)[sl] for sl in pieces(20, 6)])
    np.testing.assert_array_equal(covered, np.arange(20))
    assert pieces(0) == []
