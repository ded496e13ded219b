"""GeoJSON (RFC 7946) of a run or a line, for GIS tools and the reports' maps.

One FeatureCollection in WGS84, coordinates [longitude, latitude] in degrees rounded to
``DIGITS`` decimals (about 1 cm). Every feature's properties say its ``kind``:

- ``trace``: where the run went (or the stretch of line a fleet covers), a LineString;
- ``section``: one per 200 m section, a LineString over its chainage, with at least
  ``start_km``, ``end_km``, ``sd_mm`` and ``class`` (``sd_class``: the SD against the alert range
  of the section's speed);
- ``defect``: a Point at the peak, with at least ``km``, ``depth_mm`` and ``level``.

Lines are sampled every ``STEP_M`` of chainage and simplified (Douglas-Peucker in the local
tangent plane) to within ``SIMPLIFY_M`` of the samples: a straight keeps its two ends, a 1 km
radius curve a vertex every 60 m or so; far below the GNSS noise and the 1 m that km-posts are
good to. Where positions are unknown (outside the GNSS fixes) a line is cut (MultiLineString);
a feature with no known position keeps its properties with a null geometry (RFC 7946 3.2).

Why no shapely: its GEOS build would come in for one simplification.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from railgsa_ros.geo import geodetic_to_enu

STEP_M = 5.0  # chainage step of the line samples, m
SIMPLIFY_M = 0.5  # largest distance of a dropped sample from the simplified line, m
DIGITS = 7
SD_CLASSES = ('below', 'in alert range', 'above alert range')

#: chainages (m) -> (lat, lon) deg, NaN where the position is unknown
Positions = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
Feature = dict[str, Any]


def sd_class(sd_mm: float | None, low_mm: float | None, high_mm: float | None) -> str | None:
    """'below', 'in alert range' or 'above alert range' (``SD_CLASSES``) of a section's SD
    against the alert range [low, high] (mm); None when either is unknown."""
    if sd_mm is None or low_mm is None or high_mm is None or \
            not all(math.isfinite(v) for v in (sd_mm, low_mm, high_mm)):
        return None
    return SD_CLASSES[(sd_mm > low_mm) + (sd_mm > high_mm)]


def simplify(east: np.ndarray, north: np.ndarray, tolerance_m: float) -> np.ndarray:
    """Which points (N,) bool a Douglas-Peucker simplification keeps: every dropped point lies
    within ``tolerance_m`` of the kept polyline (first and last always kept)."""
    p = np.column_stack([east, north]).astype(float)
    keep = np.zeros(len(p), bool)
    keep[[0, -1]] = True
    todo = [(0, len(p) - 1)]
    while todo:
        i, j = todo.pop()
        if j - i < 2:
            continue
        chord = p[j] - p[i]
        rel = p[i + 1:j] - p[i]
        length = math.hypot(*chord)
        dist = (np.abs(chord[0] * rel[:, 1] - chord[1] * rel[:, 0]) / length if length > 0
                else np.hypot(rel[:, 0], rel[:, 1]))
        k = int(np.argmax(dist))
        if dist[k] > tolerance_m:
            keep[i + 1 + k] = True
            todo += [(i, i + 1 + k), (i + 1 + k, j)]
    return keep


def _coordinates(lat: np.ndarray, lon: np.ndarray) -> list[list[float]]:
    return [[round(float(a), DIGITS), round(float(b), DIGITS)] for a, b in zip(lon, lat,
                                                                                 strict=True)]


def line_geometry(positions: Positions, start_m: float, end_m: float) -> dict | None:
    """The LineString of the chainage span [start, end] m (module docstring), a MultiLineString
    where positions are unknown inside it; None with fewer than two known points."""
    n = max(math.ceil((end_m - start_m) / STEP_M), 1) + 1
    lat, lon = positions(np.linspace(start_m, end_m, n))
    known = np.isfinite(lat) & np.isfinite(lon)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], known.astype(np.int8), [0]])))
    parts = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):  # runs of known positions
        if b - a < 2:
            continue
        enu = geodetic_to_enu(lat[a:b], lon[a:b], 0.0, lat[a], lon[a])
        keep = simplify(enu[:, 0], enu[:, 1], SIMPLIFY_M)
        parts.append(_coordinates(lat[a:b][keep], lon[a:b][keep]))
    if not parts:
        return None
    if len(parts) == 1:
        return {'type': 'LineString', 'coordinates': parts[0]}
    return {'type': 'MultiLineString', 'coordinates': parts}


def feature(kind: str, geometry: dict | None, properties: Mapping[str, Any]) -> Feature:
    """A Feature with ``kind`` first among its properties."""
    return {'type': 'Feature', 'geometry': geometry,
            'properties': {'kind': kind, **properties}}


def trace_feature(positions: Positions, start_m: float, end_m: float,
                  properties: Mapping[str, Any]) -> Feature:
    """The trace over chainages [start, end] m."""
    return feature('trace', line_geometry(positions, start_m, end_m), properties)


def section_features(positions: Positions, rows: list[dict[str, Any]], start_m: float,
                     end_m: float) -> list[Feature]:
    """One Feature per section row (keys start_m, length_m, sd_mm, sd_alert_low_mm,
    sd_alert_high_mm and any others), its line clipped to the chainages [start, end] m that
    were measured, with its ``class`` (``sd_class``)."""
    out = []
    for row in rows:
        lo = max(row['start_m'], start_m)
        hi = min(row['start_m'] + row['length_m'], end_m)
        geometry = line_geometry(positions, lo, hi) if hi > lo else None
        out.append(feature('section', geometry, {
            **row, 'class': sd_class(row['sd_mm'], row['sd_alert_low_mm'],
                                     row['sd_alert_high_mm'])}))
    return out


def point_feature(lat: float | None, lon: float | None, properties: Mapping[str, Any]
                  ) -> Feature:
    """A defect at (lat, lon) deg; a null geometry when either is unknown (None or NaN)."""
    known = lat is not None and lon is not None and math.isfinite(lat) and math.isfinite(lon)
    geometry = ({'type': 'Point', 'coordinates': _coordinates(np.array([lat]),
                                                               np.array([lon]))[0]}
                if known else None)
    return feature('defect', geometry, properties)


def write(path: Path, features: list[Feature]) -> Path:
    """``features`` as one FeatureCollection in ``path`` (UTF-8 JSON, one feature a line)."""
    lines = ',\n'.join(json.dumps(f, separators=(',', ':'), allow_nan=False) for f in features)
    path.write_text('{"type":"FeatureCollection","features":[\n' + lines + '\n]}\n',
                    encoding='utf-8')
    return path
