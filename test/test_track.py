"""Track spectra, synthesis, defects, CSV and paper profiles against independent truth."""

from functools import partial

import numpy as np
import pytest
from scipy.integrate import quad

from railgsa_ros.errors import ConfigError
from railgsa_ros.track import (
    BANDS,
    apply_defects,
    corrugation,
    cosine_dip,
    dipped_joint,
    dipped_weld,
    fra_psd,
    german_psd,
    load_csv,
    make_profile,
    paper_profile,
    parse_defects,
    save_csv,
    spectrum_for,
    squat,
    synthesize,
)


def band_integral(psd, band):
    """Variance (m^2) of a wavelength band (m): integral of the one-sided spectrum."""
    lo, hi = 2 * np.pi / band[1], 2 * np.pi / band[0]
    return quad(psd, lo, hi, limit=200)[0]


# rail_domain.md section 2, band RMS in mm computed there from the formulas (independent code).
TABLE_MM = {
    'german-low': (0.98, 1.65, 2.12),
    'german-high': (1.61, 2.70, 3.47),
    'fra-6': (1.43, 2.42, 3.28),
    'fra-5': (3.55, 6.03, 8.14),
    'fra-4': (5.69, 9.65, 13.1),
}


@pytest.mark.parametrize('spec', sorted(TABLE_MM))
def test_band_rms_matches_published_table(spec):
    rms = [np.sqrt(band_integral(spectrum_for(spec), BANDS[b])) * 1e3 for b in ('D1', 'D2', 'D3')]
    # the table is rounded to 3 significant digits (13.1 for FRA 4 D3, where quad gives 13.05)
    np.testing.assert_allclose(rms, TABLE_MM[spec], rtol=5e-3)


def test_spectra_shape_and_ordering():
    omega = np.array([0.01, 0.1, 1.0, 3.0])
    low, high = german_psd(omega, 'low'), german_psd(omega, 'high')
    np.testing.assert_allclose(high / low, 1.080e-6 / 4.032e-7)
    # one-sided slopes: flat below Omega_r, omega^-4 far above Omega_c; FRA omega^-2 at 0
    assert german_psd(1e-4) == pytest.approx(german_psd(1e-3), rel=3e-3)
    assert german_psd(100.0) / german_psd(200.0) == pytest.approx(16, rel=1e-3)
    assert fra_psd(1e-4, 6) / fra_psd(2e-4, 6) == pytest.approx(4, rel=1e-6)
    assert np.all(np.diff([fra_psd(1.0, c) for c in range(1, 7)]) < 0)  # class 6 is the best
    with pytest.raises(ConfigError, match='level'):
        german_psd(omega, 'medium')
    with pytest.raises(ConfigError, match='fra class'):
        fra_psd(omega, 7)


def band_variance(u, dx, band):
    """Variance of the part of u inside a wavelength band, by Parseval on its own FFT."""
    spec = np.fft.rfft(u - u.mean())
    k = np.fft.rfftfreq(u.size, dx)  # cycles/m
    sel = (k > 1 / band[1]) & (k <= 1 / band[0])
    return 2 * np.sum(np.abs(spec[sel]) ** 2) / u.size ** 2, int(sel.sum())


@pytest.mark.parametrize('spec', ['german-low', 'german-high', 'fra-5'])
def test_synthesised_band_variance_matches_spectrum_integral(spec):
    length, dx = 60_000.0, 0.5
    x, u = make_profile(spec, length, dx, seed=7)
    assert x[-1] == pytest.approx(length) and np.allclose(np.diff(x), dx)
    for name, band in BANDS.items():
        measured, n_freq = band_variance(u, dx, band)
        expected = band_integral(spectrum_for(spec), band)
        # each of the n_freq independent frequencies carries a chi^2_2-like share of the band
        # variance: relative standard error <= 1/sqrt(n_freq); allow 4 standard errors
        tol = 4 / np.sqrt(n_freq)
        assert measured == pytest.approx(expected, rel=tol), (name, n_freq)


def test_synthesis_is_seeded_band_limited_and_not_periodic_on_the_track():
    psd = partial(german_psd, level='low')
    _, u1 = synthesize(psd, 3000.0, 0.1, seed=3, wavelength_range=(5.0, 50.0))
    _, u2 = synthesize(psd, 3000.0, 0.1, seed=3, wavelength_range=(5.0, 50.0))
    _, u3 = synthesize(psd, 3000.0, 0.1, seed=4, wavelength_range=(5.0, 50.0))
    np.testing.assert_array_equal(u1, u2)
    assert not np.allclose(u1, u3)
    # no energy outside the wavelength range (period > track: allow spectral leakage only)
    total, _ = band_variance(u1, 0.1, (0.2, 1e6))
    outside = total - band_variance(u1, 0.1, (4.0, 60.0))[0]
    assert outside < 0.01 * total
    # the track does not repeat: its two halves are uncorrelated
    half = u1.size // 2
    assert abs(np.corrcoef(u1[:half], u1[half:2 * half])[0, 1]) < 0.2
    with pytest.raises(ConfigError, match='wavelength_range'):
        synthesize(psd, 100.0, 0.5, wavelength_range=(0.5, 10.0))


def test_cosine_dip_depth_length_and_shape():
    x = np.linspace(0, 20, 20001)
    d = cosine_dip(x, 5.0, 6.0, 8e-3)
    assert d.min() == pytest.approx(-8e-3)
    assert x[np.argmin(d)] == pytest.approx(8.0)
    support = x[d < 0]
    assert support[0] == pytest.approx(5.0, abs=2e-3) and support[-1] == pytest.approx(11.0,
                                                                                       abs=2e-3)
    # analytic area of a cosine dip: -depth * length / 2
    assert np.trapezoid(d, x) == pytest.approx(-8e-3 * 6.0 / 2, rel=1e-6)


@pytest.mark.parametrize(('func', 'length', 'depth'), [
    (dipped_joint, 1.0, 3e-3), (dipped_weld, 1.0, 3e-4), (squat, 0.03, 2e-4)])
def test_named_dips_have_documented_defaults(func, length, depth):
    x = np.linspace(99, 102, 300001)
    d = func(x, 100.0)
    assert d.min() == pytest.approx(-depth, rel=1e-6)
    assert np.ptp(x[d < 0]) == pytest.approx(length, abs=3e-5)  # grid step 1e-5


def test_corrugation_patch():
    x = np.linspace(0, 30, 300001)
    c = corrugation(x, 5.0, 20.0, 0.05, 5e-5)
    assert c.max() == pytest.approx(5e-5, rel=1e-4) and c.min() == pytest.approx(-5e-5, rel=1e-4)
    nz = x[np.abs(c) > 1e-9]
    assert nz[0] >= 5.0 and nz[-1] == pytest.approx(25.0, abs=1e-3)
    spec = np.abs(np.fft.rfft(c))
    assert 1 / np.fft.rfftfreq(x.size, x[1] - x[0])[np.argmax(spec)] == pytest.approx(0.05,
                                                                                       rel=2e-3)


def test_parse_and_apply_defects_spec():
    spec = 'dip@500:len=6:depth=8e-3,joint@800,weld@900,corrugation@1200:len=20:wl=0.05:amp=5e-5'
    defects = parse_defects(spec)
    assert [d.kind for d in defects] == ['dip', 'joint', 'weld', 'corrugation']
    assert defects[0].depth == 8e-3 and defects[0].length == 6.0 and defects[0].start == 500.0
    assert defects[1].depth == 3e-3 and defects[2].depth == 3e-4
    assert defects[3].wavelength == 0.05 and defects[3].amplitude == 5e-5
    x = np.arange(0, 1300, 0.005)
    u = apply_defects(x, np.zeros_like(x), spec)
    expected = (cosine_dip(x, 500, 6, 8e-3) + dipped_joint(x, 800) + dipped_weld(x, 900)
                + corrugation(x, 1200, 20, 0.05, 5e-5))
    np.testing.assert_array_equal(u, expected)
    assert parse_defects('') == [] and parse_defects(None) == []
    assert parse_defects(' squat @ 10 ')[0].length == 0.03


@pytest.mark.parametrize(('spec', 'token'), [
    ('dip@500', 'dip@500'),
    ('joint@800,bump@3', 'bump@3'),
    ('joint@x', 'joint@x'),
    ('joint@5:foo=1', 'joint@5:foo=1'),
    ('weld@5:depth', 'weld@5:depth'),
    ('joint@5:depth=8', 'joint@5:depth=8'),
    ('squat@5:len=-1', 'squat@5:len=-1'),
    ('corrugation@1:wl=2:len=1', 'corrugation@1:wl=2:len=1'),
    ('joint', 'joint'),
])
def test_bad_defect_spec_names_the_token(spec, token):
    with pytest.raises(ConfigError, match='defects') as err:
        parse_defects(spec)
    assert repr(token) in str(err.value)


def test_csv_round_trip(tmp_path):
    x, u = make_profile('german-high', 500.0, 0.25, seed=1)
    path = tmp_path / 'p.csv'
    save_csv(path, x, u)
    x2, u2 = load_csv(path)
    np.testing.assert_array_equal(x2, x)
    np.testing.assert_array_equal(u2, u)
    xf, uf = make_profile(f'file:{path}', 300.0, 0.1)
    np.testing.assert_allclose(uf, np.interp(xf, x, u), rtol=0, atol=1e-15)
    with pytest.raises(ConfigError, match='covers'):
        make_profile(f'file:{path}', 600.0, 0.1)


@pytest.mark.parametrize(('text', 'where'), [
    ('x,u\n0,0\n1,0\n', ':1:'),
    ('x_m,u_m\n0,0\n1,abc\n2,0\n', ':3:'),
    ('x_m,u_m\n0,0\n1\n', ':3:'),
    ('x_m,u_m\n0,0\n2,0\n\n1,0\n', ':5:'),
    ('x_m,u_m\n0,0\n1,nan\n', ':3:'),
    ('x_m,u_m\n0,0\n', ':2:'),
    ('', ':1:'),
])
def test_csv_errors_name_file_and_line(tmp_path, text, where):
    path = tmp_path / 'bad.csv'
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_csv(path)
    assert f'{path}{where}' in str(err.value)


def test_csv_unreadable(tmp_path):
    with pytest.raises(ConfigError, match=r'missing\.csv'):
        load_csv(tmp_path / 'missing.csv')
    with pytest.raises(ConfigError, match=r'missing\.csv'):
        make_profile(f'file:{tmp_path / "missing.csv"}', 10.0, 0.1)


def test_paper_profile():
    x = np.arange(0, 200.0, 0.01)
    u = paper_profile(x)
    assert x[np.argmax(np.abs(u))] == pytest.approx(70.0)
    assert 2e-3 < np.abs(u).max() < 1e-2
    # zero mean and a running area that returns to zero (what the K = 1000 inversion needs)
    area = np.cumsum(u) * 0.01
    assert abs(area[-1]) < 1e-12 and abs(u.mean()) < 1e-12
    # D1 content: most of the energy lies in 3-25 m
    in_d1, _ = band_variance(u, 0.01, BANDS['D1'])
    total, _ = band_variance(u, 0.01, (0.02, 1e6))
    assert in_d1 > 0.8 * total
    np.testing.assert_array_equal(make_profile('paper', 150.0, 0.5)[1],
                                  paper_profile(np.arange(301) * 0.5))


@pytest.mark.parametrize('spec', ['german', 'fra-7', 'file', 'ore'])
def test_unknown_profile_spec(spec):
    with pytest.raises(ConfigError, match='profile'):
        make_profile(spec, 100.0, 0.5)
