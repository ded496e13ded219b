"""Where a run is: line, track, direction and km-post of the chainage origin, and with GNSS the
WGS84 position of every chainage and the odometry scale corrected against GNSS distance.

Chainage (m) is what the pipeline integrates from the speed, 0 at the run's first IMU sample.
The km-post of a chainage is ``km_origin + chainage / 1000`` when the km-posts increase along
the run (``direction`` 'increasing'), ``km_origin - chainage / 1000`` when they decrease.

GNSS (sensor_msgs/NavSatFix, when the bag has the topic) is read in a first, light pass over the
odometry and the fixes only (``gnss_pass``):

- Fixes without a fix (status -1) or with non-finite positions are left out (counted).
- Each fix gets the odometry chainage of its stamp (the held odometry speed integrated over the
  odometry stamps, 0 at the run's first IMU stamp) and its position in the local tangent plane
  (east, north) at the first good fix (``geo.geodetic_to_enu``, exact through ECEF).
- **Track.** East and north are smoothed against the odometry chainage by cubic smoothing
  splines (``scipy.interpolate.make_smoothing_spline``) whose penalty makes the smoothing kernel
  about ``SMOOTH_M`` = 50 m wide (lam = SMOOTH_M^4 / mean spacing of the fixes; the GCV choice of
  the penalty costs 5 s per 10,000 fixes). Fixes at one chainage (standstill) are averaged.
- **Scale.** The along-track GNSS distance of each fix is the sum of the displacements between
  consecutive fixes projected on the smoothed track's unit tangent: noise does not add length
  (projections are zero-mean, unlike the lengths of noisy steps, which overstate the distance by
  about sigma^2 / step) and the sum telescopes, so its error stays at the fixes' noise instead of
  growing with the run. The scale is the slope of a straight line fitted to that distance
  against the odometry chainage (``numpy.polynomial``), refitted ``CLIP_ROUNDS`` times without
  the fixes whose residual exceeds ``CLIP`` robust (MAD) standard deviations (multipath jumps);
  its standard error is the least-squares one (GNSS errors are correlated over seconds, so it is
  optimistic by about the square root of the fixes per correlation time). A wheel-diameter
  error e gives a scale 1 / (1 + e).
- **Positions.** A chainage c (corrected, m) gets the track's position at the odometry chainage
  c / scale, converted back to WGS84. Outside the fixes' range: NaN.

The pipeline then runs with the odometry speed times the scale, so chainage, km-posts, 200 m
sections and defect positions are in ground metres.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
import warnings

import numpy as np
from numpy.polynomial import polynomial

from railgsa_ros.bag.messages import ODOMETRY, ODOMETRY_FIELDS
from railgsa_ros.bag.reader import NAV_SAT_FIX, GnssFixes, TopicData, iter_topics
from railgsa_ros.errors import ConfigError, InputWarning
from railgsa_ros.geo import enu_to_geodetic, geodetic_to_enu

DIRECTIONS = ('increasing', 'decreasing')
SMOOTH_M = 50.0  # width of the GNSS track smoothing, m of chainage
#: a GNSS odometry scale further than this from 1 is no wheel-diameter error (tenths of a
#: percent): odometry in other units, or the wrong wheel; the run is corrected, with a warning
SCALE_WARN = 0.05
CLIP = 4.0  # residuals beyond CLIP robust standard deviations are left out of the scale fit
CLIP_ROUNDS = 3


#: a smoothing spline: (x m, derivative order=0) -> values
Spline = Callable[..., np.ndarray]

@dataclass(frozen=True)
class Reference:
    """Line id, track id, direction of the km-posts along the run ('increasing' or
    'decreasing') and the km-post (km) of chainage 0."""

    line: str = ''
    track: str = ''
    direction: str = 'increasing'
    km_origin: float = 0.0

    def __post_init__(self) -> None:
        if self.direction not in DIRECTIONS:
            raise ConfigError(f'direction: expected one of {", ".join(DIRECTIONS)}, got '
                              f'{self.direction!r}')
        if not np.isfinite(self.km_origin):
            raise ConfigError(f'km_origin: expected a finite km-post, got {self.km_origin!r}')

    @property
    def _sign(self) -> float:
        """+1 where the km-posts increase along the run, -1 where they decrease."""
        return 1.0 if self.direction == 'increasing' else -1.0

    def km(self, chainage_m: np.ndarray | float) -> np.ndarray:
        """km-post (km) of chainages (m)."""
        return self.km_origin + self._sign * np.asarray(chainage_m, dtype=float) / 1e3

    def label(self, chainage_m: float) -> str:
        """'km 12.345 (345.0 m)': the km-post of a chainage (m), with the chainage."""
        return f'km {float(self.km(chainage_m)):.3f} ({chainage_m:.1f} m)'

    def chainage(self, km: np.ndarray | float) -> np.ndarray:
        """Chainage (m) of km-posts (km): the inverse of ``km``."""
        return self._sign * (np.asarray(km, dtype=float) - self.km_origin) * 1e3

    def values(self, chainage_m: float) -> dict[str, object]:
        """line, track, direction, km_origin and a chainage (m) with its km-post (km): what
        the live nodes report on /diagnostics for their newest output."""
        return {'line': self.line, 'track': self.track, 'direction': self.direction,
                'km_origin': self.km_origin, 'chainage_m': float(chainage_m),
                'km': float(self.km(chainage_m))}

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> Reference:
        """The reference of the location keys in ``values`` (node parameters or a params
        file's node section; missing keys take the defaults)."""
        return cls(**{k: values[k] for k in ('line', 'track', 'direction', 'km_origin')
                      if k in values})


@dataclass(frozen=True)
class OdometryScale:
    """Ground metres per odometry metre: value, standard error, the fixes used and left out, and
    a note on where it came from."""

    value: float = 1.0
    std: float = 0.0
    fixes: int = 0
    rejected: int = 0
    note: str = 'no GNSS'


@dataclass(frozen=True)
class Track:
    """East/north (m) in the tangent plane at ``origin`` (lat, lon deg) as smoothing splines of
    the odometry chainage over [start_m, end_m]; a chainage is the odometry chainage times
    ``scale``."""

    origin: tuple[float, float]
    scale: float
    start_m: float
    end_m: float
    east: Spline  # east (m) of the odometry chainage
    north: Spline  # north (m) of the odometry chainage

    def lat_lon(self, chainage_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(latitude, longitude) deg WGS84 of chainages (m); NaN outside the fixes."""
        c = np.asarray(chainage_m, dtype=float) / self.scale
        inside = (c >= self.start_m) & (c <= self.end_m)
        at = np.clip(c, self.start_m, self.end_m)
        east = np.where(inside, self.east(at), np.nan)
        north = np.where(inside, self.north(at), np.nan)
        return from_local(east, north, self.origin)


@dataclass(frozen=True)
class Location:
    """Everything about where a run is: reference, odometry scale, GNSS track (None without)."""

    reference: Reference = field(default_factory=Reference)
    scale: OdometryScale = field(default_factory=OdometryScale)
    track: Track | None = None

    def lat_lon(self, chainage_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(latitude, longitude) deg of chainages (m); NaN without GNSS."""
        if self.track is None:
            nan = np.full(np.shape(chainage_m), np.nan)
            return nan, nan.copy()
        return self.track.lat_lon(chainage_m)


def to_local(lat_deg: np.ndarray, lon_deg: np.ndarray,
             origin: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(east, north) m of WGS84 points (on the ellipsoid) in the tangent plane at ``origin``
    (``geo.geodetic_to_enu``)."""
    enu = geodetic_to_enu(np.asarray(lat_deg, float), np.asarray(lon_deg, float), 0.0, *origin)
    return enu[..., 0], enu[..., 1]


def from_local(east: np.ndarray, north: np.ndarray,
               origin: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(lat, lon) deg of tangent-plane points (m) at ``origin`` (``geo.enu_to_geodetic``)."""
    east = np.asarray(east, float)
    lat, lon, _ = enu_to_geodetic(np.stack([east, np.asarray(north, float),
                                            np.zeros_like(east)], -1), *origin)
    return lat, lon


class OdometryDistance:
    """Odometry chainage (m) at stamps: the held odometry speed (newest sample at or before)
    integrated over the odometry stamps, streamed in log-time order. Query stamps wait until
    the odometry has passed them (or the end): ask before adding the odometry that passes
    them (a stamp before the odometry added so far is extrapolated back from its newest
    sample)."""

    def __init__(self) -> None:
        self._t: int | None = None  # last odometry stamp, its speed and chainage there
        self._v = 0.0
        self._c = 0.0
        self._queries: list[tuple[np.ndarray, np.ndarray]] = []  # (stamps, row ids) waiting
        self.stamps: list[np.ndarray] = []
        self.values: list[np.ndarray] = []
        self.ids: list[np.ndarray] = []

    def add(self, stamps_ns: np.ndarray, speed_mps: np.ndarray) -> None:
        """Odometry samples (sorted by stamp here)."""
        order = np.argsort(stamps_ns, kind='stable')
        t, v = np.asarray(stamps_ns)[order], np.asarray(speed_mps, float)[order]
        ok = np.isfinite(v) & (True if self._t is None else t >= self._t)
        t, v = t[ok], v[ok]
        if t.size == 0:
            return
        if self._t is None:
            self._t, self._v = int(t[0]), float(v[0])
        t_all = np.concatenate([[self._t], t])
        v_all = np.concatenate([[self._v], v])
        c_all = self._c + np.concatenate([[0.0], np.cumsum(v_all[:-1] * np.diff(t_all) * 1e-9)])
        self._answer(t_all, v_all, c_all, final=False)
        self._t, self._v, self._c = int(t_all[-1]), float(v_all[-1]), float(c_all[-1])

    @property
    def started(self) -> bool:
        """Whether any odometry came."""
        return self._t is not None

    def ask(self, stamps_ns: np.ndarray, ids: np.ndarray) -> None:
        """Stamps (ns) whose chainage is wanted, with ids to find them in ``result``."""
        self._queries.append((np.asarray(stamps_ns, np.int64), np.asarray(ids)))

    def _answer(self, t: np.ndarray, v: np.ndarray, c: np.ndarray, final: bool) -> None:
        waiting = []
        for stamps, ids in self._queries:
            done = np.ones(stamps.size, bool) if final else stamps <= t[-1]
            k = np.clip(np.searchsorted(t, stamps[done], side='right') - 1, 0, None)
            self.stamps.append(stamps[done])
            self.values.append(c[k] + v[k] * (stamps[done] - t[k]) * 1e-9)
            self.ids.append(ids[done])
            if not done.all():
                waiting.append((stamps[~done], ids[~done]))
        self._queries = waiting

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """(ids, chainage m) of every stamp asked, after the last odometry."""
        if self._t is not None:
            self._answer(np.array([self._t]), np.array([self._v]), np.array([self._c]), True)
        if not self.ids:
            return np.zeros(0, np.int64), np.zeros(0)
        return np.concatenate(self.ids), np.concatenate(self.values)


def _smooth(odom_m: np.ndarray, east: np.ndarray, north: np.ndarray
            ) -> tuple[np.ndarray, Spline, Spline] | None:
    """(chainages, east spline, north spline) of the fixes (see the module); None with fewer
    than 5 distinct chainages or a span shorter than SMOOTH_M."""
    from scipy.interpolate import make_smoothing_spline

    x, inverse = np.unique(odom_m, return_inverse=True)
    if x.size < 5 or x[-1] - x[0] < SMOOTH_M:
        return None
    counts = np.bincount(inverse).astype(float)
    lam = SMOOTH_M ** 4 / ((x[-1] - x[0]) / (x.size - 1))
    e, n = (make_smoothing_spline(x, np.bincount(inverse, v) / counts, w=counts, lam=lam)
            for v in (east, north))
    return x, e, n


def estimate_scale(odom_m: np.ndarray, east: np.ndarray, north: np.ndarray,
                   splines: tuple[np.ndarray, Spline, Spline], rejected: int = 0
                   ) -> OdometryScale:
    """Ground metres per odometry metre from fixes at odometry chainages (see the module)."""
    _, e_spline, n_spline = splines
    order = np.argsort(odom_m, kind='stable')
    c, e, n = odom_m[order], east[order], north[order]
    mid = (c[1:] + c[:-1]) / 2
    tangent = np.column_stack([e_spline(mid, 1), n_spline(mid, 1)])
    tangent /= np.maximum(np.hypot(*tangent.T), 1e-12)[:, None]
    along = np.concatenate([[0.0], np.cumsum(np.diff(e) * tangent[:, 0]
                                             + np.diff(n) * tangent[:, 1])])
    keep = np.ones(c.size, bool)
    for _ in range(CLIP_ROUNDS):  # a line, then again without the residuals beyond CLIP MADs
        r = along - polynomial.polyval(c, polynomial.polyfit(c[keep], along[keep], 1))
        mad = np.median(np.abs(r[keep] - np.median(r[keep])))
        keep = np.abs(r - np.median(r[keep])) <= CLIP * 1.4826 * max(mad, 1e-6)
    fit = polynomial.polyfit(c[keep], along[keep], 1)
    r = along[keep] - polynomial.polyval(c[keep], fit)
    spread = np.sum((c[keep] - c[keep].mean()) ** 2)
    std = float(np.sqrt(np.sum(r ** 2) / max(keep.sum() - 2, 1) / spread))
    return OdometryScale(float(fit[1]), std, int(keep.sum()), rejected + int(np.sum(~keep)),
                         f'GNSS along-track distance regressed on odometry chainage over '
                         f'{np.ptp(c):.0f} m')


def warn_scale(bag: Path, scale: float) -> None:
    """An InputWarning when the GNSS odometry scale is further than SCALE_WARN from 1."""
    if abs(scale - 1.0) > SCALE_WARN:
        hint = ' (odometry in km/h?)' if abs(scale * 3.6 - 1.0) < SCALE_WARN else ''
        warnings.warn(InputWarning(f'{bag}: GNSS says the odometry scale is {scale:.4f}, not a '
                                   f'wheel-diameter error{hint}: corrected, check the '
                                   'odometry'), stacklevel=2)


def gnss_pass(bag: Path, odom_topic: str, gnss_topic: str, start_ns: int,
              reference: Reference) -> Location:
    """Read the odometry and the fixes of a bag (no IMU) and locate the run; a Location
    without track (scale 1) when the bag has no usable fix or no odometry."""
    odometry = OdometryDistance()
    # every stamp is asked before the odometry that passes it is added: ``add`` answers it
    # from the samples around it (asked after, it was answered from the batch's last sample,
    # extrapolated back with the speed there: wrong wherever the speed changed)
    odometry.ask(np.array([start_ns]), np.array([-1]))
    fixes: list[GnssFixes] = []
    seen = 0
    for batch in iter_topics(bag, {odom_topic: ODOMETRY.msgtype, gnss_topic: NAV_SAT_FIX}):
        gnss = batch.get(gnss_topic)
        if isinstance(gnss, GnssFixes) and len(gnss):
            odometry.ask(gnss.stamps_ns, seen + np.arange(len(gnss)))
            fixes.append(gnss)
            seen += len(gnss)
        odom = batch.get(odom_topic)
        if isinstance(odom, TopicData):
            odometry.add(odom.stamps_ns, odom.values[:, ODOMETRY_FIELDS['twist.twist.linear']
                                                     .start])
    ids, chainage = odometry.result()
    fix = GnssFixes.concat(fixes)
    if len(fix) == 0 or not odometry.started:
        note = 'no GNSS fixes' if len(fix) == 0 else 'no odometry to correct'
        return Location(reference, OdometryScale(note=note))
    odom_m = np.empty(len(fix))
    odom_m[ids[ids >= 0]] = chainage[ids >= 0] - chainage[ids == -1][0]
    good = (fix.status >= 0) & np.isfinite(fix.latitude_deg) & np.isfinite(fix.longitude_deg)
    rejected = int(np.sum(~good))
    if rejected:
        warnings.warn(InputWarning(f'{bag}: {rejected} of {len(fix)} GNSS fixes left out (no '
                                   'fix or a non-finite position)'), stacklevel=2)
    if not good.any():
        return Location(reference, OdometryScale(rejected=rejected, note='no GNSS fix'))
    origin = (float(fix.latitude_deg[good][0]), float(fix.longitude_deg[good][0]))
    east, north = to_local(fix.latitude_deg[good], fix.longitude_deg[good], origin)
    splines = _smooth(odom_m[good], east, north)
    if splines is None:
        return Location(reference, OdometryScale(fixes=int(good.sum()), rejected=rejected,
                                                 note=f'GNSS fixes over less than {SMOOTH_M:g} m'))
    scale = estimate_scale(odom_m[good], east, north, splines, rejected)
    warn_scale(bag, scale.value)
    x, e_spline, n_spline = splines
    return Location(reference, scale, Track(origin, scale.value, float(x[0]), float(x[-1]),
                                            e_spline, n_spline))
