"""Where a chainage is on the Earth: railway lines in WGS84 and simulated GNSS fixes.

A ``Line`` is a polyline of WGS84 vertices; the chainage (m) runs along it from its first vertex
(chainage ``start_m`` there). Each segment is straight in the local tangent plane (ENU, east-north-
up) of its first vertex, where its length is measured, and points on it are converted exactly
(WGS84 ellipsoid, through ECEF) to latitude and longitude. So the only approximation is the
tangent plane over one segment: a point s metres from its vertex is off by about s^3 / (2 R^2)
horizontally (R = 6371 km): 1.2 mm for a 1 km segment, 1.2 cm for 10 km. ``Line.generated``
builds vertices from an origin, a heading and sections of constant curvature, with chords short
enough for a sagitta below 1 cm (``CHORD_SAGITTA_M``).

``GnssSim`` turns a simulated run (stamps, chainage) into ``sensor_msgs/msg/NavSatFix`` fixes at
a slower rate, with east/north/up noise of given standard deviations (white, or first-order
Gauss-Markov with a correlation time) and that covariance (diagonal known). Angles in degrees,
lengths in metres.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

import numpy as np
from scipy import signal
from scipy.spatial import cKDTree

from railgsa_ros.errors import ConfigError
from railgsa_ros.ticks import TickSampler

WGS84_A = 6378137.0  # semi-major axis, m
WGS84_F = 1 / 298.257223563
WGS84_E2 = WGS84_F * (2 - WGS84_F)  # first eccentricity squared
CHORD_SAGITTA_M = 0.01  # generated curves: chord length sqrt(8 R s) for this sagitta s
MAX_CHORD_M = 1000.0  # generated straights: a vertex at least every km


def geodetic_to_ecef(lat_deg: np.ndarray | float, lon_deg: np.ndarray | float,
                     alt_m: np.ndarray | float = 0.0
                     ) -> np.ndarray:
    """WGS84 latitude, longitude (deg) and ellipsoidal height (m) -> ECEF (..., 3), m."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(n + alt_m) * np.cos(lat) * np.cos(lon),
                     (n + alt_m) * np.cos(lat) * np.sin(lon),
                     (n * (1 - WGS84_E2) + alt_m) * np.sin(lat)], axis=-1)


def ecef_to_geodetic(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF (..., 3) m -> (lat deg, lon deg, height m); fixed-point latitude iteration (below
    1e-9 m near the surface after 5 steps)."""
    x, y, z = np.moveaxis(np.asarray(xyz, dtype=float), -1, 0)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1 - WGS84_E2))
    for _ in range(5):
        n = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
        alt = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1 - WGS84_E2 * n / (n + alt)))
    n = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    alt = p / np.cos(lat) - n
    return np.degrees(lat), np.degrees(np.arctan2(y, x)), alt


def _enu_rotation(lat_deg: np.ndarray | float, lon_deg: np.ndarray | float) -> np.ndarray:
    """Rows east, north, up of the local frame at (lat, lon) in ECEF: (..., 3, 3)."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, sp, cp = np.sin(lon), np.cos(lon), np.sin(lat), np.cos(lat)
    zero = np.zeros_like(sl)
    return np.stack([np.stack([-sl, cl, zero], -1),
                     np.stack([-sp * cl, -sp * sl, cp], -1),
                     np.stack([cp * cl, cp * sl, sp], -1)], -2)


def geodetic_to_enu(lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray | float,
                    lat0_deg: np.ndarray | float, lon0_deg: np.ndarray | float,
                    alt0_m: np.ndarray | float = 0.0) -> np.ndarray:
    """Points -> east, north, up (..., 3) m in the tangent plane at (lat0, lon0, alt0);
    exact (through ECEF). Origins broadcast against the points."""
    d = geodetic_to_ecef(lat_deg, lon_deg, alt_m) - geodetic_to_ecef(lat0_deg, lon0_deg, alt0_m)
    return np.einsum('...ij,...j->...i', _enu_rotation(lat0_deg, lon0_deg), d)


def enu_to_geodetic(enu: np.ndarray, lat0_deg: np.ndarray | float, lon0_deg: np.ndarray | float,
                    alt0_m: np.ndarray | float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """East, north, up (..., 3) m in the tangent plane at (lat0, lon0, alt0) -> (lat deg, lon
    deg, height m); exact (through ECEF)."""
    rot = _enu_rotation(lat0_deg, lon0_deg)
    xyz = geodetic_to_ecef(lat0_deg, lon0_deg, alt0_m) + np.einsum('...ji,...j->...i', rot,
                                                                    np.asarray(enu, float))
    return ecef_to_geodetic(xyz)


@dataclass(frozen=True)
class Line:
    """A railway line: WGS84 vertices (deg), chainage ``start_m`` at the first one.

    ``line_id`` names it in outputs. Vertices need not be evenly spaced; consecutive vertices
    must differ. Chainage (m) <-> position with ``position`` and ``locate``.
    """

    lat_deg: np.ndarray
    lon_deg: np.ndarray
    start_m: float = 0.0
    line_id: str = 'line'
    _step: np.ndarray = field(init=False, repr=False, compare=False)  # (N-1, 2) east, north m
    _length: np.ndarray = field(init=False, repr=False, compare=False)  # (N-1,) segment m
    _cum: np.ndarray = field(init=False, repr=False, compare=False)  # (N,) along the line, m

    def __post_init__(self) -> None:
        lat = np.asarray(self.lat_deg, dtype=float)
        lon = np.asarray(self.lon_deg, dtype=float)
        if lat.ndim != 1 or lat.shape != lon.shape or lat.size < 2:
            raise ConfigError('line: needs at least two vertices (lat, lon in degrees)')
        if not (np.all(np.isfinite(lat)) and np.all(np.isfinite(lon))
                and np.all(np.abs(lat) <= 90) and np.all(np.abs(lon) <= 180)):
            raise ConfigError('line: latitudes must be in [-90, 90] and longitudes in '
                              '[-180, 180] degrees')
        step = geodetic_to_enu(lat[1:], lon[1:], 0.0, lat[:-1], lon[:-1])[:, :2]
        length = np.hypot(step[:, 0], step[:, 1])
        if np.any(length <= 0):
            raise ConfigError('line: two consecutive vertices coincide')
        object.__setattr__(self, 'lat_deg', lat)
        object.__setattr__(self, 'lon_deg', lon)
        object.__setattr__(self, '_step', step)
        object.__setattr__(self, '_length', length)
        object.__setattr__(self, '_cum', np.concatenate([[0.0], np.cumsum(length)]))

    @property
    def length_m(self) -> float:
        """Length along the polyline, m."""
        return float(self._cum[-1])

    @property
    def end_m(self) -> float:
        """Chainage at the last vertex, m."""
        return self.start_m + self.length_m

    def position(self, chainage_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lat, lon) in degrees at chainages (m) on the line; ConfigError outside it."""
        s = np.asarray(chainage_m, dtype=float) - self.start_m
        if s.size and (s.min() < -1e-6 or s.max() > self.length_m + 1e-6):
            raise ConfigError(f'line {self.line_id}: chainage {self.start_m:g}-{self.end_m:g} m, '
                              f'asked for {s.min() + self.start_m:g}-{s.max() + self.start_m:g} m')
        seg = np.clip(np.searchsorted(self._cum, s, side='right') - 1, 0, self._length.size - 1)
        frac = (s - self._cum[seg]) / self._length[seg]
        enu = np.zeros((*s.shape, 3))
        enu[..., :2] = frac[..., None] * self._step[seg]
        lat, lon, _ = enu_to_geodetic(enu, self.lat_deg[seg], self.lon_deg[seg])
        return lat, lon

    def locate(self, lat_deg: np.ndarray, lon_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(chainage m, signed cross-track offset m, + left) of the nearest point on the line.

        Candidates: the two segments at the nearest vertex (a KD-tree in the tangent plane of
        the first vertex); each is then measured in its own vertex's tangent plane.
        """
        lat = np.asarray(lat_deg, dtype=float)
        lon = np.asarray(lon_deg, dtype=float)
        coarse = geodetic_to_enu(self.lat_deg, self.lon_deg, 0.0, self.lat_deg[0],
                                 self.lon_deg[0])[:, :2]
        query = geodetic_to_enu(lat, lon, 0.0, self.lat_deg[0], self.lon_deg[0])[..., :2]
        _, nearest = cKDTree(coarse).query(query)
        best_s = np.full(lat.shape, np.nan)
        best_off = np.full(lat.shape, np.inf)
        for shift in (-1, 0):  # the segments before and after the nearest vertex
            seg = np.clip(nearest + shift, 0, self._length.size - 1)
            local = geodetic_to_enu(lat, lon, 0.0, self.lat_deg[seg], self.lon_deg[seg])[..., :2]
            direction = self._step[seg] / self._length[seg][..., None]
            along = np.clip(np.sum(local * direction, -1), 0.0, self._length[seg])
            cross = direction[..., 0] * local[..., 1] - direction[..., 1] * local[..., 0]
            gap = np.hypot(*np.moveaxis(local - along[..., None] * direction, -1, 0))
            better = gap < np.abs(best_off)
            best_s = np.where(better, self._cum[seg] + along, best_s)
            best_off = np.where(better, np.where(cross < 0, -gap, gap), best_off)
        return best_s + self.start_m, best_off

    @classmethod
    def generated(cls, lat0_deg: float, lon0_deg: float, heading_deg: float,
                  sections: list[tuple[float, float]], start_m: float = 0.0,
                  line_id: str = 'line') -> Line:
        """A line from an origin, an initial heading (deg clockwise from north) and sections
        (length m, radius m; radius 0 = straight, > 0 curves right, < 0 left).

        Curves are chords of sagitta <= CHORD_SAGITTA_M; each chord is laid out in the tangent
        plane of its first vertex, so a long line keeps its lengths and curvature on the
        ellipsoid.
        """
        lat, lon = [float(lat0_deg)], [float(lon0_deg)]
        heading = math.radians(heading_deg)
        for length, radius in sections:
            if not (length > 0 and math.isfinite(length) and math.isfinite(radius)):
                raise ConfigError(f'line: section length {length!r} m, radius {radius!r} m')
            chord = MAX_CHORD_M if radius == 0 else min(
                MAX_CHORD_M, math.sqrt(8 * abs(radius) * CHORD_SAGITTA_M))
            n = max(1, math.ceil(length / chord))
            turn = 0.0 if radius == 0 else (length / n) / radius
            for _ in range(n):
                # chords point along the arc's mid heading; each is as long as its arc (a
                # relative difference turn^2 / 24 < 1e-5), so the chainage is the arc length
                mid = heading + 0.5 * turn
                east, north = (length / n) * math.sin(mid), (length / n) * math.cos(mid)
                la, lo, _ = enu_to_geodetic(np.array([east, north, 0.0]), lat[-1], lon[-1])
                lat.append(float(la))
                lon.append(float(lo))
                heading += turn
        return cls(np.array(lat), np.array(lon), start_m, line_id)


# A default line for simulations: 52.0 N 10.0 E heading 60 deg, then a repeating 10 km pattern of
# straights and curves of 1.2-3 km radius (both hands).
DEFAULT_ORIGIN = (52.0, 10.0)
DEFAULT_HEADING_DEG = 60.0
DEFAULT_PATTERN = ((3000.0, 0.0), (1500.0, 2000.0), (2500.0, 0.0), (1000.0, -1200.0),
                   (2000.0, 0.0))


def default_line(length_m: float, start_m: float = 0.0, line_id: str = 'sim-1') -> Line:
    """The default simulated line, long enough for ``length_m`` from ``start_m``; a longer one
    extends a shorter one (the same pattern), so all passes see the same geometry."""
    period = sum(length for length, _ in DEFAULT_PATTERN)
    repeats = max(1, math.ceil((length_m + 1.0) / period))  # chords lose < 1 mm per km
    return Line.generated(*DEFAULT_ORIGIN, DEFAULT_HEADING_DEG, list(DEFAULT_PATTERN) * repeats,
                          start_m, line_id)


@dataclass(frozen=True)
class GnssSpec:
    """Simulated GNSS receiver: fix rate (Hz), noise std east/north and up (m), and the noise's
    correlation time (s; 0 = white, > 0 = first-order Gauss-Markov, as multipath makes it)."""

    rate_hz: float = 5.0
    sigma_h_m: float = 2.0
    sigma_v_m: float = 4.0
    correlation_s: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= 100):
            raise ConfigError(f'gnss rate: expected 0-100 Hz, got {self.rate_hz!r}')
        for name in ('sigma_h_m', 'sigma_v_m', 'correlation_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f'gnss {name}: must be a finite number >= 0, got {value!r}')


@dataclass(frozen=True)
class GnssFixes:
    """Fixes: stamps (int64 ns), lat, lon (deg), altitude (m), true chainage (m) per fix."""

    stamps_ns: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    chainage_m: np.ndarray


class GnssSim:
    """GNSS fixes of a run along ``line``, chunk by chunk (ticks and noise carry over)."""

    def __init__(self, line: Line, spec: GnssSpec = GnssSpec(),
                 seed: int | Sequence[int] | None = 0) -> None:
        self.line = line
        self.spec = spec
        self.ticks = TickSampler(spec.rate_hz)
        self.rng = np.random.default_rng(seed)
        # AR(1) per axis at the fix rate: x[k] = phi x[k-1] + sqrt(1 - phi^2) w[k], stationary
        self.phi = math.exp(-1.0 / (spec.rate_hz * spec.correlation_s)) \
            if spec.correlation_s > 0 else 0.0
        self._last = self.rng.standard_normal(3)  # the state before the first fix

    @property
    def covariance(self) -> np.ndarray:
        """NavSatFix position_covariance (ENU, row-major), m^2."""
        return np.diag([self.spec.sigma_h_m ** 2, self.spec.sigma_h_m ** 2,
                        self.spec.sigma_v_m ** 2]).ravel()

    def take(self, stamps_ns: np.ndarray, chainage_m: np.ndarray) -> GnssFixes:
        """Fixes for the next chunk of IMU samples (stamps ns, true chainage m)."""
        pick = self.ticks.take(stamps_ns)
        chainage = np.asarray(chainage_m, dtype=float)[pick]
        lat, lon = self.line.position(chainage)
        sigma = np.array([self.spec.sigma_h_m, self.spec.sigma_h_m, self.spec.sigma_v_m])
        unit = self.rng.standard_normal((pick.size, 3))
        if self.phi and pick.size:
            unit, _ = signal.lfilter([math.sqrt(1 - self.phi ** 2)], [1.0, -self.phi], unit,
                                     axis=0, zi=self.phi * self._last[None, :])
            self._last = unit[-1]
        lat, lon, alt = enu_to_geodetic(unit * sigma, lat, lon)
        return GnssFixes(np.asarray(stamps_ns, np.int64)[pick], lat, lon, alt, chainage)
