"""geo: WGS84 conversions against closed forms, lines, and simulated GNSS noise statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from railgsa_ros.cli.main import main
from railgsa_ros.errors import ConfigError
from railgsa_ros.geo import (
    WGS84_A,
    WGS84_E2,
    GnssSim,
    GnssSpec,
    Line,
    default_line,
    ecef_to_geodetic,
    enu_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_enu,
)


def test_ecef_of_known_points_and_round_trip():
    b = WGS84_A * np.sqrt(1 - WGS84_E2)  # semi-minor axis
    np.testing.assert_allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [WGS84_A, 0, 0], atol=1e-9)
    np.testing.assert_allclose(geodetic_to_ecef(0.0, 90.0, 10.0), [0, WGS84_A + 10, 0],
                               atol=1e-8)
    np.testing.assert_allclose(geodetic_to_ecef(90.0, 0.0, 0.0), [0, 0, b], atol=1e-8)
    rng = np.random.default_rng(0)
    lat, lon, alt = rng.uniform(-80, 80, 500), rng.uniform(-179, 179, 500), \
        rng.uniform(-100, 3000, 500)
    back = ecef_to_geodetic(geodetic_to_ecef(lat, lon, alt))
    np.testing.assert_allclose(back[0], lat, atol=1e-10)
    np.testing.assert_allclose(back[1], lon, atol=1e-10)
    np.testing.assert_allclose(back[2], alt, atol=1e-6)


def test_enu_distances_match_meridian_and_parallel_radii():
    lat0 = 52.0
    phi = np.radians(lat0)
    meridian = WGS84_A * (1 - WGS84_E2) / (1 - WGS84_E2 * np.sin(phi) ** 2) ** 1.5
    normal = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(phi) ** 2)
    d = 1e-3  # degrees: about 111 m north, 69 m east
    north = geodetic_to_enu(lat0 + d, 10.0, 0.0, lat0, 10.0)
    east = geodetic_to_enu(lat0, 10.0 + d, 0.0, lat0, 10.0)
    assert north[1] == pytest.approx(meridian * np.radians(d), rel=1e-6)
    assert east[0] == pytest.approx(normal * np.cos(phi) * np.radians(d), rel=1e-6)
    assert abs(north[0]) < 1e-6 and abs(east[1]) < 1e-3
    enu = np.array([[120.0, -40.0, 2.0], [-3000.0, 2500.0, -1.0]])
    np.testing.assert_allclose(geodetic_to_enu(*enu_to_geodetic(enu, lat0, 10.0, 50.0),
                                               lat0, 10.0, 50.0), enu, atol=1e-8)


def test_line_position_and_locate_invert_each_other():
    line = default_line(25_000.0, start_m=3000.0)
    assert line.start_m == 3000.0 and line.length_m > 25_000.0
    s = np.linspace(3000.0, 28_000.0, 20_001)
    lat, lon = line.position(s)
    back, offset = line.locate(lat, lon)
    np.testing.assert_allclose(back, s, atol=1e-4)
    assert np.abs(offset).max() < 1e-4
    # consecutive points are 1.25 m apart on the ground (straights and curves alike)
    enu = geodetic_to_enu(lat[1:], lon[1:], 0.0, lat[:-1], lon[:-1])
    np.testing.assert_allclose(np.hypot(enu[:, 0], enu[:, 1]), 1.25, rtol=1e-5)
    # a point 5 m to the left of a northbound straight
    north = Line.generated(52.0, 10.0, 0.0, [(1000.0, 0.0)])
    lat5, lon5, _ = enu_to_geodetic(np.array([-5.0, 400.0, 0.0]), 52.0, 10.0)
    at, off = north.locate(lat5, lon5)
    assert at == pytest.approx(400.0, abs=1e-3) and off == pytest.approx(5.0, abs=1e-3)
    with pytest.raises(ConfigError, match='chainage'):
        line.position(np.array([2990.0]))


def test_generated_curve_turns_by_length_over_radius():
    radius = 1500.0
    quarter = Line.generated(52.0, 10.0, 0.0, [(0.5 * np.pi * radius, radius)])
    end = geodetic_to_enu(quarter.lat_deg[-1], quarter.lon_deg[-1], 0.0, 52.0, 10.0)
    # a right-hand quarter circle from heading north ends at (R, R); chords and the
    # convergence of the meridians over 1.5 km (about 2e-4 rad) leave decimetres
    np.testing.assert_allclose(end[:2], [radius, radius], atol=0.5)
    assert quarter.length_m == pytest.approx(0.5 * np.pi * radius, rel=1e-6)
    tail = geodetic_to_enu(quarter.lat_deg[-1], quarter.lon_deg[-1], 0.0,
                           quarter.lat_deg[-2], quarter.lon_deg[-2])
    # the last chord points along the arc's heading at its middle: half a chord's turn short
    half_turn = 0.5 * np.degrees(quarter.length_m / (quarter.lat_deg.size - 1) / radius)
    assert np.degrees(np.arctan2(tail[0], tail[1])) == pytest.approx(90.0 - half_turn, abs=0.02)
    with pytest.raises(ConfigError, match='two vertices'):
        Line(np.array([52.0]), np.array([10.0]))
    with pytest.raises(ConfigError, match='coincide'):
        Line(np.array([52.0, 52.0]), np.array([10.0, 10.0]))
    with pytest.raises(ConfigError, match='latitudes'):
        Line(np.array([52.0, 95.0]), np.array([10.0, 10.0]))


def test_gnss_sim_noise_statistics_and_rate():
    line = default_line(40_000.0)
    spec = GnssSpec(rate_hz=10.0, sigma_h_m=2.0, sigma_v_m=4.0)
    sim = GnssSim(line, spec, seed=3)
    t = np.arange(2_000_000) / 1000.0  # 2000 s of 1 kHz samples at 15 m/s, in 7 chunks
    stamps = np.int64(5 * 10**9) + np.round(t * 1e9).astype(np.int64)
    chainage = 15.0 * t
    fixes = [sim.take(stamps[lo:lo + 300_000], chainage[lo:lo + 300_000])
             for lo in range(0, t.size, 300_000)]
    lat = np.concatenate([f.lat_deg for f in fixes])
    lon = np.concatenate([f.lon_deg for f in fixes])
    alt = np.concatenate([f.alt_m for f in fixes])
    truth = np.concatenate([f.chainage_m for f in fixes])
    fix_t = np.concatenate([f.stamps_ns for f in fixes])
    assert lat.size == 20_000 and np.all(np.diff(fix_t) == 100_000_000)
    along, cross = line.locate(lat, lon)
    err = along - truth
    n = err.size
    # white noise: mean 0 within 4 standard errors, std within 4 standard errors (1/sqrt(2n))
    for e, sigma in ((err, 2.0), (cross, 2.0), (alt, 4.0)):
        assert abs(e.mean()) < 4 * sigma / np.sqrt(n)
        assert e.std() == pytest.approx(sigma, rel=4 / np.sqrt(2 * n))
    assert abs(np.corrcoef(err[1:], err[:-1])[0, 1]) < 4 / np.sqrt(n)
    np.testing.assert_array_equal(sim.covariance, [4, 0, 0, 0, 4, 0, 0, 0, 16])


def test_simulate_gnss_and_odometry_error_in_the_bag(tmp_path: Path):
    out = tmp_path / 'bag'
    assert main(['simulate', '--out', str(out), '--profile', 'paper', '--speed', '25',
                 '--duration', '40', '--rate', '200', '--sensor', 'ideal', '--gnss',
                 '--gnss-rate', '2', '--gnss-noise', '1.5', '--start-km', '1.2',
                 '--odom-scale-error', '0.004']) == 0
    fixes = []
    with AnyReader([out]) as reader:
        conns = [c for c in reader.connections if c.topic == '/gnss/fix']
        assert conns[0].msgtype == 'sensor_msgs/msg/NavSatFix'
        for conn, log_ns, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert stamp == log_ns and msg.status.status == 0
            assert msg.position_covariance_type == 2
            np.testing.assert_allclose(msg.position_covariance, [2.25, 0, 0, 0, 2.25, 0, 0, 0, 9])
            fixes.append((stamp, msg.latitude, msg.longitude))
    stamps, lat, lon = np.array(fixes).T
    assert len(fixes) == 80
    along, _ = default_line(2200.0).locate(lat, lon)
    expected = 1200.0 + 25.0 * (stamps - stamps[0]) / 1e9  # the true chainage at the fix
    assert np.sqrt(np.mean((along - expected) ** 2)) == pytest.approx(1.5, rel=0.4)


def test_correlated_gnss_noise_has_its_correlation_and_variance():
    line = default_line(30_000.0)
    spec = GnssSpec(rate_hz=2.0, sigma_h_m=3.0, sigma_v_m=5.0, correlation_s=5.0)
    sim = GnssSim(line, spec, seed=8)
    t = np.arange(0.0, 12_000.0, 0.01)  # 100 Hz samples at 2 m/s: 24000 fixes, 9 chunks
    stamps = np.int64(10**9) + np.round(t * 1e9).astype(np.int64)
    fixes = [sim.take(stamps[lo:lo + 140_000], 2.0 * t[lo:lo + 140_000])
             for lo in range(0, t.size, 140_000)]
    lat = np.concatenate([f.lat_deg for f in fixes])
    lon = np.concatenate([f.lon_deg for f in fixes])
    alt = np.concatenate([f.alt_m for f in fixes])
    along, cross = line.locate(lat, lon)
    err = along - np.concatenate([f.chainage_m for f in fixes])
    phi = np.exp(-1 / (2.0 * 5.0))  # lag-1 correlation at 2 Hz with 5 s correlation time
    n_eff = err.size * (1 - phi) / (1 + phi)  # effective independent samples of an AR(1)
    for e, sigma in ((err, 3.0), (cross, 3.0), (alt, 5.0)):
        assert np.corrcoef(e[1:], e[:-1])[0, 1] == pytest.approx(phi, abs=4 / np.sqrt(n_eff))
        assert e.std() == pytest.approx(sigma, rel=4 / np.sqrt(2 * n_eff))


def test_odometry_scale_far_from_one_is_warned_with_a_km_per_h_hint():
    """A wheel-diameter error (tenths of a percent) passes silently; km/h odometry (scale
    1 / 3.6) and a 20 % error are warned, only the first with the km/h hint."""
    import warnings

    from railgsa_ros.errors import InputWarning
    from railgsa_ros.location import warn_scale

    def said(scale: float) -> list[str]:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always')
            warn_scale(Path('bag'), scale)
        return [str(w.message) for w in caught if issubclass(w.category, InputWarning)]
    assert said(1.004) == [] and said(0.996) == []
    assert len(said(1 / 3.6)) == 1 and 'km/h' in said(1 / 3.6)[0]
    assert len(said(1.2)) == 1 and 'km/h' not in said(1.2)[0]
