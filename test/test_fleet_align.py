"""Alignment of a pass on its line by cross-correlation, against a known offset and scale."""

import numpy as np
import pytest

from railgsa_ros.fleet.align import Reference, on_line_grid, origin, xcorr_align
from railgsa_ros.fleet.gnss import gnss_alignment
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.track import german_psd, synthesize

DX = 0.25


@pytest.fixture(scope='module')
def line():
    """A 3 km D1-filtered German-low line on the 0.25 m grid (cell 0 at x = 0)."""
    x, u = synthesize(lambda w: german_psd(w, 'low'), 3000.0, DX, seed=11)
    return x, band_distance(u, DX, 'd1')


def _pass(line, offset, scale, length, noise, seed, direction=1):
    """Odometry grid of a pass starting at line position ``offset`` whose odometry reads
    ``scale`` m per line metre, with white noise (m)."""
    x, u = line
    rng = np.random.default_rng(seed)
    s = np.arange(0.0, length, DX)
    truth_x = offset + direction * s / scale
    return s, np.interp(truth_x, x, u) + noise * rng.standard_normal(s.size), np.ones(s.size, bool)


@pytest.mark.parametrize('offset, odo_scale, direction', [(237.3, 1.004, 1), (812.6, 0.993, 1),
                                                          (2410.0, 1.002, -1)])
def test_xcorr_recovers_offset_and_scale(line, offset, odo_scale, direction):
    x, u = line
    ref = Reference(0, u, np.ones(u.size, bool), DX)
    s, up, ok = _pass(line, offset, odo_scale, 1200.0, 2e-4, seed=1)
    if direction < 0:
        noise = 2e-4 * np.random.default_rng(2).standard_normal(s.size)
        up = np.interp(offset - s / odo_scale, x, u) + noise
    along = 'increasing' if direction > 0 else 'decreasing'
    found = xcorr_align(ref, s, up, ok, origin(0.0, along))
    assert found is not None
    sd = found.position_sd(s)
    err = found.position(s) - (offset + direction * s / odo_scale)
    assert np.max(np.abs(err)) < 0.05  # 5 cm over 1.2 km
    assert np.max(np.abs(err) / np.maximum(sd, 1e-6)) < 4  # within its stated uncertainty
    assert found.scale == pytest.approx(direction / odo_scale, abs=5e-5)
    assert found.windows >= 10 and found.correlation > 0.95


def test_unrelated_pass_is_not_aligned(line):
    _, u = line
    ref = Reference(0, u, np.ones(u.size, bool), DX)
    other = band_distance(synthesize(lambda w: german_psd(w, 'low'), 1500.0, DX, seed=99)[1],
                          DX, 'd1')
    s = np.arange(other.size) * DX
    assert xcorr_align(ref, s, other, np.ones(s.size, bool), origin(0.0, 'increasing')) is None


def test_on_line_grid_follows_the_alignment(line):
    x, u = line
    s, up, ok = _pass(line, 100.0, 1.0, 500.0, 0.0, seed=3)
    ok[400:420] = False
    cells, (ug,), valid = on_line_grid(s, (up,), ok, origin(100.0, 'increasing'), DX)
    assert cells[0] * DX == pytest.approx(100.0) and np.all(np.diff(cells) == 1)
    assert np.allclose(ug, np.interp(cells * DX, x, u), atol=1e-12)
    assert (~valid).sum() in (20, 21, 22)


def test_gnss_alignment_recovers_offset_and_scale_with_its_uncertainty():
    """2 m GNSS noise at 5 Hz over 1.2 km, a few multipath outliers: the fit and its stated SD
    agree with the truth over 300 noisy repeats."""
    rng = np.random.default_rng(4)
    s = np.linspace(0.0, 1200.0, 240)
    var = np.full(s.size, 4.0)
    errors = []
    for _ in range(300):
        x = 512.3 + 0.996 * s + 2.0 * rng.standard_normal(s.size)
        x[rng.choice(s.size, 3, replace=False)] += 40.0  # multipath
        found = gnss_alignment(s, x, var)
        errors.append(((found.offset_m - 512.3) / found.offset_sd_m,
                       (found.scale - 0.996) / found.scale_sd))
    z = np.array(errors)
    assert np.all(np.abs(z.mean(axis=0)) < 0.2) and np.all(np.abs(z.std(axis=0) - 1) < 0.15)
    assert gnss_alignment(s[:5], s[:5], var[:5]) is None  # too few fixes
