"""GNSS anchoring of a pass: NavSatFix fixes on the line's geometry give offset and scale.

Each fix is projected on the line (``geo.Line.locate``: chainage along the polyline) and paired
with the pass's odometry chainage at the fix's stamp. A weighted straight-line fit
x_gnss = offset + scale * s (weights 1 / horizontal variance of the fix) gives the alignment and
its covariance; fixes more than ``REJECT_SD`` standard deviations off the fit, or farther than
``MAX_CROSS_M`` from the line, are left out (multipath, another track), and the covariance is
scaled up by the reduced chi-square when the fixes scatter more than their covariance says.
With GNSS the line's frame is the geometry's chainage, not the first pass's odometry.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from railgsa_ros.bag.reader import GnssFixes
from railgsa_ros.errors import ConfigError, InputError
from railgsa_ros.fleet.align import Alignment

if TYPE_CHECKING:
    from railgsa_ros.geo import Line

GNSS_TOPIC = '/gnss/fix'
DEFAULT_VAR_M2 = 25.0  # horizontal variance when a fix gives none (5 m: a plain receiver)
MIN_FIXES = 10
REJECT_SD = 3.5
MAX_CROSS_M = 30.0


def horizontal_variance(fixes: GnssFixes) -> np.ndarray:
    """Horizontal variance (m^2) of each fix: the mean of the east and north covariance entries
    when the message reports a covariance, DEFAULT_VAR_M2 when it does not, inf for no fix
    (status < 0) or a non-finite position."""
    cov = fixes.covariance
    east_north = 0.5 * (cov[:, 0] + cov[:, 4])
    known = (fixes.covariance_type > 0) & np.isfinite(east_north) & (east_north > 0)
    good = (fixes.status >= 0) & np.isfinite(fixes.latitude_deg) & \
        np.isfinite(fixes.longitude_deg)
    return np.where(good, np.where(known, east_north, DEFAULT_VAR_M2), np.inf)


def load_geometry(path: str | Path, start_m: float | None = None,
                  line_id: str = 'line') -> Line:
    """A ``geo.Line`` from a GeoJSON LineString (a bare geometry, a Feature or the first
    Feature of a FeatureCollection; coordinates lon, lat) or a CSV with a header lat,lon; the
    chainage at its first vertex is ``start_m``, else the Feature's ``start_m`` property, else
    0. InputError naming the file when unreadable."""
    from railgsa_ros.geo import Line

    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
        if path.suffix.lower() in ('.json', '.geojson'):
            doc = json.loads(text)
            if doc.get('type') == 'FeatureCollection':
                doc = doc['features'][0]
            if doc.get('type') == 'Feature':
                if start_m is None:
                    start_m = float((doc.get('properties') or {}).get('start_m', 0.0))
                doc = doc['geometry']
            if doc.get('type') != 'LineString':
                raise ValueError('expected a LineString')
            lon, lat = np.asarray(doc['coordinates'], dtype=float)[:, :2].T
        else:
            table = np.genfromtxt(path, delimiter=',', names=True)
            lat, lon = np.atleast_1d(table['lat']), np.atleast_1d(table['lon'])
        return Line(lat, lon, 0.0 if start_m is None else start_m, line_id)
    except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError,
            ConfigError) as exc:
        raise InputError(f'{path}: not a line geometry ({exc})'.splitlines()[0]) from None


def geometry_json(line: Line) -> str:
    """A line geometry as JSON text (vertices in degrees, chainage of the first one, id)."""
    return json.dumps({'lat': line.lat_deg.tolist(), 'lon': line.lon_deg.tolist(),
                       'start_m': line.start_m, 'line_id': line.line_id})


def line_from_json(text: str) -> Line:
    """The ``geo.Line`` of ``geometry_json``."""
    from railgsa_ros.geo import Line

    doc = json.loads(text)
    return Line(np.array(doc['lat']), np.array(doc['lon']), doc['start_m'], doc['line_id'])


def gnss_alignment(s_fix: np.ndarray, x_fix: np.ndarray, var_m2: np.ndarray
                   ) -> Alignment | None:
    """Weighted line x = offset + scale * s through the fixes (module docstring); None with
    fewer than MIN_FIXES usable fixes."""
    keep = np.isfinite(s_fix) & np.isfinite(x_fix) & np.isfinite(var_m2) & (var_m2 > 0)
    for _ in range(5):
        if keep.sum() < MIN_FIXES:
            return None
        w = 1.0 / var_m2[keep]
        design = np.column_stack([np.ones(keep.sum()), s_fix[keep]])
        cov = np.linalg.inv(design.T @ (w[:, None] * design))
        coef = cov @ (design.T @ (w * x_fix[keep]))
        with np.errstate(invalid='ignore'):
            resid = (x_fix - coef[0] - coef[1] * s_fix) / np.sqrt(var_m2)
        again = keep & (np.abs(resid) < REJECT_SD)
        if np.array_equal(again, keep):
            break
        keep = again
    chi2 = float(np.sum(resid[keep] ** 2) / max(keep.sum() - 2, 1))
    return Alignment(float(coef[0]), float(coef[1]), cov * max(1.0, chi2), 'gnss',
                     windows=int(keep.sum()))


def align_fixes(fixes: GnssFixes, stamps_ns: np.ndarray, s_m: np.ndarray, line: Line
                ) -> Alignment | None:
    """The GNSS alignment of a pass: its cells' stamps (N,) and odometry chainage (N,), the
    fixes with a position inside the pass's time span projected on ``line``."""
    var = horizontal_variance(fixes)
    inside = (fixes.stamps_ns >= stamps_ns[0]) & (fixes.stamps_ns <= stamps_ns[-1]) & \
        np.isfinite(var)
    if inside.sum() < MIN_FIXES:
        return None
    s_fix = np.interp(fixes.stamps_ns[inside].astype(float), stamps_ns.astype(float), s_m)
    x_fix, cross = line.locate(fixes.latitude_deg[inside], fixes.longitude_deg[inside])
    var = np.where(np.abs(cross) <= MAX_CROSS_M, var[inside], np.inf)
    return gnss_alignment(s_fix, x_fix, var)
