"""Review building blocks against hand-computed truth: EN 13848-5 table and speed classes,
exceedances of known dips, SD per section of known signals, stamp health, progress bar."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from railgsa_ros.review.exceedances import (
    count_by_level,
    describe_counts,
    find_exceedances,
    magnitudes,
)
from railgsa_ros.review.figures import envelope
from railgsa_ros.review.health import stamp_stats
from railgsa_ros.review.progress import Progress
from railgsa_ros.review.truth import Truth
from railgsa_ros.standards.en13848 import Limits, en13848_table
from railgsa_ros.standards.sections import section_sd
from railgsa_ros.track import cosine_dip

KMH = 1 / 3.6
MM = 1e-3
D1 = Limits(en13848_table(), 'd1')  # the standard's table, classed by the measuring speed


def _track(dips: list[tuple[float, float]], speed_kmh: float | np.ndarray
           ) -> tuple[np.ndarray, ...]:
    """Chainage every 5 cm over 1 km, u with 4 m cosine dips (start m, depth m), speed, stamps."""
    x = np.arange(0.0, 1000.0, 0.05)
    u = sum((cosine_dip(x, start, 4.0, depth) for start, depth in dips), np.zeros_like(x))
    return x, u, np.broadcast_to(speed_kmh * KMH, x.shape), np.arange(x.size, dtype=np.int64)


def test_dips_are_found_at_their_chainage_with_their_level() -> None:
    # 100 km/h, lower end: AL 8, IL 10, IAL 26 mm
    x, u, v, t = _track([(100, 9 * MM), (300, 12 * MM), (500, 30 * MM), (700, 7 * MM)], 100)
    found = find_exceedances(x, u, v, t, D1)
    assert [(e.level, e.confidence) for e in found] == [('AL', 'certain'), ('IL', 'certain'),
                                                        ('IAL', 'certain')]
    assert [e.peak_m for e in found] == pytest.approx([102, 302, 502], abs=0.05)
    assert [e.peak_u_m for e in found] == pytest.approx([-9 * MM, -12 * MM, -30 * MM], abs=1e-6)
    assert [e.limit_m for e in found] == pytest.approx([8 * MM, 10 * MM, 26 * MM])
    # the stretch beyond the limit is symmetric about the dip's centre and shorter than the dip
    for e in found:
        assert e.start_m < e.peak_m < e.end_m and e.end_m - e.start_m < 4.0
        assert e.peak_m - e.start_m == pytest.approx(e.end_m - e.peak_m, abs=0.06)
    counts = count_by_level(found)
    assert {k: sum(c.values()) for k, c in counts.items()} == {'AL': 1, 'IL': 1, 'IAL': 1}


def test_the_speed_class_sets_the_limit() -> None:
    speed = np.where(np.arange(20000) < 10000, 100.0, 150.0)  # 0-500 m: 100, then 150 km/h
    x, u, v, t = _track([(100, 7 * MM), (700, 7 * MM)], speed)
    found = find_exceedances(x, u, v, t, D1)  # AL 8 mm, then 6 mm
    assert len(found) == 1 and found[0].peak_m == pytest.approx(702, abs=0.05)
    assert found[0].speed_kmh == pytest.approx(150)


def test_the_band_sets_the_confidence() -> None:
    x, u, v, t = _track([(100, 12 * MM), (300, 15 * MM), (500, 7 * MM), (700, 11 * MM)], 100)
    half = np.where(x < 600, 2 * MM, 0.5 * MM) * (u != 0)
    found = find_exceedances(x, u, v, t, D1, u - half, u + half)
    got = [(round(e.peak_m), e.level, e.confidence) for e in found]
    # 12 +- 2: central IL, nearest edge 10 is not above IL 10 -> likely; 15 +- 2: certain IL;
    # 7 +- 2: only the far edge 9 passes AL -> possible; 11 +- 0.5: certain IL
    assert got == [(102, 'IL', 'likely'), (302, 'IL', 'certain'), (502, 'AL', 'possible'),
                   (702, 'IL', 'certain')]
    assert describe_counts(found) == {'IAL': '0', 'IL': '3 (2 certain, 1 likely)',
                                      'AL': '1 (1 possible)'}
    assert found[2].peak_u_m == pytest.approx(-7 * MM, abs=1e-6)
    assert (found[0].lower_m, found[0].upper_m) == pytest.approx((-14 * MM, -10 * MM), abs=1e-6)


def test_noise_at_the_limit_makes_one_exceedance_per_side() -> None:
    x, u, v, t = _track([(100, 9 * MM)], 100)
    rng = np.random.default_rng(0)
    u = u + 0.3 * MM * rng.standard_normal(u.size) * (u != 0)  # dithers across AL = 8 mm
    u[(x > 110) & (x < 112)] = 8.5 * MM  # a positive bump next to it: another exceedance
    found = find_exceedances(x, u, v, t, D1, merge_m=1.0)
    assert [np.sign(e.peak_u_m) for e in found] == [-1, 1]
    assert found[0].peak_m == pytest.approx(102, abs=0.3)
    assert 110 < found[1].peak_m < 112 and 110 < found[1].start_m < found[1].end_m < 112


def test_magnitudes_of_a_band_across_zero() -> None:
    near, far = magnitudes(np.array([1.0, -2.0, 3.0]), np.array([-1.0, -3.0, 2.0]),
                           np.array([2.0, -1.0, 5.0]))
    assert near.tolist() == [0.0, 1.0, 2.0] and far.tolist() == [2.0, 3.0, 5.0]


def test_section_sd_of_sines_with_a_gap() -> None:
    x = np.arange(0.0, 1000.0, 0.02)
    amp = np.where(x < 400, 1 * MM, 2 * MM)
    u = amp * np.sin(2 * np.pi * x / 10.0)  # 20 whole periods per 200 m section
    keep = ~((x > 450) & (x < 580))  # 130 m missing in section 2: 35 % covered
    speed = np.where(x < 500, 20.0, 30.0)
    s = section_sd(x[keep], u[keep], speed[keep])
    assert s.start_m.tolist() == [0, 200, 400, 600, 800]
    expected = np.array([1, 1, np.nan, 2, 2]) * MM / np.sqrt(2)
    assert s.sd_m == pytest.approx(expected, rel=1e-3, nan_ok=True)
    assert s.coverage == pytest.approx([1, 1, 0.35, 1, 1], abs=0.01)
    assert s.speed_mps[[0, 1, 3, 4]] == pytest.approx([20, 20, 30, 30])


def test_section_sd_leaves_out_short_sections_at_the_ends() -> None:
    x = np.arange(150.0, 1010.0, 0.05)  # 50 m of section 0 and 10 m of section 5: left out
    s = section_sd(x, np.sin(x))
    assert s.start_m.tolist() == [200, 400, 600, 800]
    assert section_sd(x[:1], x[:1]).start_m.size == 0


def test_stamp_stats_count_jitter_gaps_and_backward_steps() -> None:
    rng = np.random.default_rng(1)
    period = 1_000_000  # 1 kHz
    t = np.arange(20_000) * period + np.round(rng.normal(0, 20_000, 20_000)).astype(np.int64)
    t = np.delete(t, np.s_[5000:5099])  # a 100 ms gap
    s = stamp_stats(t)
    assert s.count == t.size and s.rate_hz == pytest.approx(1000, rel=1e-3)
    assert s.gaps == 1 and s.longest_gap_s == pytest.approx(0.1, abs=1e-4)
    assert s.lost_s == pytest.approx(0.099, abs=1e-4)
    assert s.backwards == 0
    # the steps carry the difference of two stamp errors: std sqrt(2) x 20 us
    assert s.jitter_std_s == pytest.approx(np.sqrt(2) * 20e-6, rel=0.05)
    t[8000], t[8001] = t[8001], t[8000]  # one sample out of order
    assert stamp_stats(t).backwards == 1
    one = stamp_stats(t[:1])
    assert one.count == 1 and np.isnan(one.rate_hz)


def test_progress_draws_only_when_forced_or_on_a_terminal() -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    quiet = io.StringIO()
    bar = Progress(10, 'x', quiet)
    bar.update(10)
    bar.close()
    assert quiet.getvalue() == ''
    for stream, enabled in ((io.StringIO(), True), (Tty(), None)):
        bar = Progress(10, 'stage', stream, enabled)
        bar.update(3)
        bar.update(4)  # throttled: within 0.1 s of the last draw
        bar.update(10, 'done')
        bar.close()
        text = stream.getvalue()
        assert text.count('\r') == 2 and text.endswith('100 %\n') and ' 30 %' in text
        assert '\rdone [' + '#' * 30 + ']' in text


def test_envelope_keeps_every_extreme_of_a_long_signal() -> None:
    x = np.arange(100_001) * 0.03
    y = np.sin(x) * 1e-3
    y[54_321] = 5e-3  # one sample spike: must survive the reduction
    y[77_777] = np.nan  # missing samples do not hide their block
    xe, lo, hi = envelope(x, y, bins=500)
    assert 490 <= xe.size <= 500 and np.all(np.diff(xe) > 0)
    assert np.nanmax(hi) == 5e-3 and np.nanmin(lo) == pytest.approx(np.nanmin(y))
    assert xe[np.nanargmax(hi)] == pytest.approx(x[54_321], abs=x[-1] / 500)
    short = envelope(x[:100], y[:100], bins=500)
    assert all(np.array_equal(a, b) for a, b in zip(short, (x[:100], y[:100], y[:100]),
                                                     strict=True))


def test_a_truth_bag_is_shifted_onto_the_run_chainage() -> None:
    stamps = np.arange(10, dtype=np.int64) * 10**8
    truth = Truth(Path('t'), 1000.0 + np.arange(10.0), np.zeros(10), stamps)
    moved = truth.aligned(run_stamp_ns=3 * 10**8 + 5 * 10**7, run_chainage_m=2.0)
    assert moved.chainage_m[0] == pytest.approx(-1.5)  # 1003.5 m of the truth is 2 m of the run
    csv = Truth(Path('t.csv'), np.arange(10.0), np.zeros(10))
    assert csv.aligned(0, 5.0) is csv  # a CSV already counts from the run start


def test_a_streamed_truth_bag_equals_the_whole_truth_at_the_cell_centres(tmp_path: Path) -> None:
    # The truth read in small batches, shifted and resampled cell by cell, against np.interp of
    # the whole aligned truth at the centres of the review's 0.25 m cells.
    from types import SimpleNamespace

    from railgsa_ros.bag import write_run
    from railgsa_ros.review.truth import load_truth, truth_on_grid

    n = 4000
    rng = np.random.default_rng(3)
    stamps = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 10**6
    chainage = 500.0 + np.cumsum(rng.uniform(0.01, 0.05, n))
    run = SimpleNamespace(stamps_ns=stamps, accel=np.zeros((n, 3)), speed_mps=np.ones(n),
                          chainage_m=chainage, truth_u_m=rng.normal(0, 1e-3, n))
    bag = write_run(tmp_path / 'truth', run)
    run_stamp, run_chainage = int(stamps[100]) + 400_000, 3.0
    streamed = truth_on_grid(bag, run_stamp, run_chainage, chunk=700)
    whole = load_truth(bag).aligned(run_stamp, run_chainage)
    cells = np.arange(np.ceil(whole.chainage_m[0] / 0.25 - 0.5),
                      np.floor(whole.chainage_m[-1] / 0.25 - 0.5) + 1)
    x = (cells + 0.5) * 0.25
    np.testing.assert_allclose(streamed.chainage_m, x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(streamed.u_m, np.interp(x, whole.chainage_m, whole.u_m),
                               rtol=0, atol=1e-15)
    assert streamed.stamps_ns is None
