"""Fusion of passes (``fleet.fuse``) and defect detection (``fleet.condition``) against a known
truth: per-pass scatter, gains, fused SD, the speed class a defect is detected at.

Synthetic passes on one line grid: u_p = (1 + g_p) f + e_p with a known profile f (SD 1 mm,
correlated over metres), known gains g_p and white noise e_p of known SD sigma_p, written into
a fresh database and fused by the fleet's own SQL.
"""

from __future__ import annotations

import numpy as np
import pytest

from railgsa_ros.fleet import db
from railgsa_ros.fleet.condition import DAY_NS, update_line
from railgsa_ros.fleet.fuse import fuse_line, pass_noise, pass_scatter
from railgsa_ros.standards.en13848 import Limits, en13848_table

CELLS = 4000  # 1 km at 0.25 m


def _line(tmp_path, sigmas, gains, seed=0, speeds=None, f=None):
    """A database holding one line of passes as in the module docstring (pass p at speeds[p]
    m/s, a day after the one before, aligned by identity; f: a given profile), fused;
    (connection, f)."""
    rng = np.random.default_rng(seed)
    if f is None:
        f = np.convolve(rng.standard_normal(CELLS + 40), np.hanning(40), 'valid')[:CELLS]
        f *= 1e-3 / f.std()
    con = db.connect(tmp_path / 'fuse.duckdb')
    con.execute("INSERT INTO lines VALUES ('L', '1', 0.25, 'd1', 1, 'odometry', NULL)")
    for pid, (sigma, gain) in enumerate(zip(sigmas, gains, strict=True), start=1):
        stamp = DAY_NS * (19000 + pid)
        con.execute("INSERT INTO passes (pass_id, line, track, status, start_time) "
                    "VALUES (?, 'L', '1', 'ok', ?)", [pid, db.timestamp(stamp)])
        con.execute('INSERT INTO alignments (pass_id, method, offset_m, scale, offset_sd_m, '
                    "scale_sd, cov_offset_scale) VALUES (?, 'origin', 0, 1, 0, 0, 0)", [pid])
        db.insert_columns(con, 'profiles', {
            'pass_id': np.full(CELLS, pid, np.int32), 'cell': np.arange(CELLS),
            'u_m': (1 + gain) * f + sigma * rng.standard_normal(CELLS),
            'valid': np.ones(CELLS, bool), 'stamp_ns': np.full(CELLS, stamp, np.int64),
            'speed_mps': np.full(CELLS, 25.0 if speeds is None else speeds[pid - 1])})
    pass_scatter(con, 'L', '1')
    fuse_line(con, 'L', '1')
    return con, f


def test_each_pass_scatter_and_gain_are_measured(tmp_path):
    """sigma_p within 5 % (MAD of 4000 cells: about 1.3 % SE) although each is measured against
    the mean of the others, which has noise of its own. g_p is relative to the others' weighted
    mean gain m_p, and a regression on that noisy mean reads low by its noise share
    s_loo^2 / (var f + s_loo^2) (1.2 % here). The mean is weighted by the previous round's
    estimates, not the true 1 / sigma^2, which moves m_p by a fraction of the gains' spread:
    0.008 allowed."""
    sigmas = np.array([0.1, 0.2, 0.3, 0.15]) * 1e-3
    gains = np.array([0.0, 0.02, -0.03, 0.01])
    con, f = _line(tmp_path, sigmas, gains)
    noise, gain = np.array(con.execute('SELECT noise_m, gain FROM passes ORDER BY pass_id')
                           .fetchall()).T
    np.testing.assert_allclose(noise, sigmas, rtol=0.05)
    w = 1 / sigmas ** 2
    others = w.sum() - w
    mean_gain = (np.sum(w * (1 + gains)) - w * (1 + gains)) / others
    attenuation = f.var() / (f.var() + 1 / others / mean_gain ** 2)
    np.testing.assert_allclose(gain, (1 + gains) / mean_gain * attenuation - 1, atol=0.008)


@pytest.mark.parametrize('n', [2, 4, 8])
def test_fused_sd_shrinks_as_one_over_sqrt_n(tmp_path, n):
    """n passes of 0.2 mm noise: the fused SD is 0.2 mm / sqrt(n) (median over the cells: the
    Birge ratio there is 1) within 10 %, and it covers the fused profile's true error (95 %
    interval holding 93-99 % of the cells: the Birge ratio can only widen it)."""
    sigma = 0.2e-3
    con, f = _line(tmp_path, [sigma] * n, [0.0] * n, seed=n)
    fused = con.execute("SELECT u_m, sd_m, passes FROM fused WHERE line = 'L' ORDER BY cell"
                        ).fetchnumpy()
    assert np.all(fused['passes'] == n)
    assert np.median(fused['sd_m']) == pytest.approx(sigma / np.sqrt(n), rel=0.10)
    inside = np.mean(np.abs(fused['u_m'] - f) <= 1.96 * fused['sd_m'])
    assert 0.93 <= inside <= 0.99


def test_two_passes_share_the_variance_of_their_difference():
    """Two passes see only var(u_1 - u_2) = s_1 + s_2: each gets half, whatever the weights."""
    v = np.array([0.08e-6, 0.08e-6])
    np.testing.assert_allclose(pass_noise([1.0, 5.0], [0.01, -0.01], v),
                               np.sqrt(v / 2), rtol=0.02)


def test_a_defect_is_detected_at_the_line_speed_class(tmp_path):
    """A 5 mm dip on a quiet track seen by a 108 km/h train as 3.9 mm (a low-reading vehicle)
    and by a 65 km/h one as 4.6 mm: neither reaches half the alert limit of its own speed class
    (4 mm, 6 mm), but the place's class is the line's (the fastest pass): 4 mm. Followed, and
    measured in both passes."""
    x = np.arange(CELLS) * 0.25
    f = 0.2e-3 * np.sin(2 * np.pi * x / 17.0) - 5e-3 * np.exp(-0.5 * ((x - 500.0) / 1.5) ** 2)
    con, _ = _line(tmp_path, [1e-5, 1e-5], [-0.22, -0.08], speeds=[30.0, 18.0], f=f)
    update_line(con, 'L', '1', 0.25, Limits(en13848_table(), 'd1'))
    rows = con.execute('SELECT x_m, passes, sign FROM defects').fetchall()
    assert len(rows) == 1
    x_m, passes, sign = rows[0]
    assert abs(x_m - 500.0) < 0.25 and passes == 2 and sign == -1
    found = con.execute('SELECT pass_id, detected FROM detections ORDER BY pass_id').fetchall()
    assert found == [(1, False), (2, True)]
