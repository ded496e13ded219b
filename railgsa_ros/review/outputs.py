"""Machine-readable results of a review, for maintenance systems: the defects and the 200 m
sections (CSV), the run trace, the sections and the defects as one GeoJSON FeatureCollection
(``gis``: the maps of GIS tools and of the report) and the summary that ``railgsa review
--json`` prints.

Every defect is an exceedance (``exceedances``) at its peak: km-post and chainage, WGS84
position (empty without GNSS), signed depth (the mean-to-peak value of the reconstruction),
the level and confidence, the limit, the exceedance probability (the fraction of the
surrogate's germ samples beyond the limit at the peak: the samples of the uncertainty band;
empty without a band), the alert limit and the probability of passing it, the band at the
peak, the speed and the time (UTC) of the IMU sample.
"""

from __future__ import annotations

import csv
from datetime import UTC, datetime
import math
from pathlib import Path
from typing import Any

import numpy as np

from railgsa_ros import gis
from railgsa_ros.review.exceedances import describe_counts
from railgsa_ros.review.results import Review

DEFECTS_CSV = 'defects.csv'
GEOJSON = 'review.geojson'
SECTIONS_CSV = 'sections.csv'
MM = 1e3


def _iso(stamp_ns: int) -> str:
    """ISO 8601 UTC time of a stamp, to the microsecond."""
    return datetime.fromtimestamp(stamp_ns / 1e9, UTC).isoformat(timespec='microseconds')


def _number(value: float, digits: int) -> float | None:
    """A rounded float, None for NaN (empty in CSV, null in JSON)."""
    return None if not math.isfinite(value) else round(float(value), digits)


def defect_rows(review: Review) -> list[dict[str, Any]]:
    """One dict per defect, in chainage order (the CSV columns, the GeoJSON properties)."""
    loc = review.location
    ref = loc.reference
    exc = sorted(review.exceedances, key=lambda e: e.peak_m)
    peaks = np.array([e.peak_m for e in exc])
    lat, lon = loc.lat_lon(peaks)
    km = ref.km(peaks)
    rows = []
    for i, e in enumerate(exc):
        rows.append({
            'line': ref.line, 'track': ref.track, 'direction': ref.direction,
            'km': _number(km[i], 4), 'chainage_m': _number(e.peak_m, 2),
            'lat': _number(lat[i], 7), 'lon': _number(lon[i], 7),
            'level': e.level, 'confidence': e.confidence,
            'depth_mm': _number(e.peak_u_m * MM, 3), 'limit_mm': _number(e.limit_m * MM, 1),
            'exceedance_probability': _number(e.probability, 4),
            'alert_limit_mm': _number(e.alert_limit_m * MM, 1),
            'alert_probability': _number(e.alert_probability, 4),
            'lower_mm': _number(e.lower_m * MM, 3), 'upper_mm': _number(e.upper_m * MM, 3),
            'start_km': _number(float(ref.km(e.start_m)), 4),
            'end_km': _number(float(ref.km(e.end_m)), 4),
            'speed_kmh': _number(e.speed_kmh, 1), 'time_utc': _iso(e.peak_stamp_ns),
            'stamp_ns': e.peak_stamp_ns})
    return rows


def section_rows(review: Review) -> list[dict[str, Any]]:
    """One dict per section with its SD (chainage order)."""
    s, ref = review.sections, review.location.reference
    sd_range = review.limits.sd_at(s.start_m + s.length_m / 2, s.speed_mps) * MM
    rows = []
    for i in range(len(s)):
        start, end = float(s.start_m[i]), float(s.start_m[i] + s.length_m)
        rows.append({
            'line': ref.line, 'track': ref.track, 'direction': ref.direction,
            'start_km': _number(float(ref.km(start)), 4),
            'end_km': _number(float(ref.km(end)), 4),
            'start_m': _number(start, 2), 'length_m': _number(s.length_m, 2),
            'sd_mm': _number(s.sd_m[i] * MM, 4), 'coverage': _number(s.coverage[i], 4),
            'speed_kmh': _number(s.speed_mps[i] * 3.6, 1),
            'sd_alert_low_mm': _number(sd_range[i, 0], 2),
            'sd_alert_high_mm': _number(sd_range[i, 1], 2)})
    return rows


def _write_csv(path: Path, rows: list[dict[str, Any]], header: list[str]) -> Path:
    with path.open('w', newline='', encoding='utf-8') as f:
        writer = csv.DictWriter(f, header, lineterminator='\n')
        writer.writeheader()
        writer.writerows({k: '' if v is None else v for k, v in r.items()} for r in rows)
    return path


DEFECT_COLUMNS = ['line', 'track', 'direction', 'km', 'chainage_m', 'lat', 'lon', 'level',
                  'confidence', 'depth_mm', 'limit_mm', 'exceedance_probability',
                  'alert_limit_mm', 'alert_probability', 'lower_mm', 'upper_mm', 'start_km',
                  'end_km', 'speed_kmh', 'time_utc', 'stamp_ns']
SECTION_COLUMNS = ['line', 'track', 'direction', 'start_km', 'end_km', 'start_m', 'length_m',
                   'sd_mm', 'coverage', 'speed_kmh', 'sd_alert_low_mm', 'sd_alert_high_mm']


FILES = {'defects_csv': DEFECTS_CSV, 'sections_csv': SECTIONS_CSV, 'geojson': GEOJSON}


def features(review: Review, defects: list[dict[str, Any]], sections: list[dict[str, Any]]
             ) -> list[gis.Feature]:
    """The run's trace, its sections and its defects (rows of ``defect_rows`` and
    ``section_rows``) as GeoJSON features (``gis``); null geometries without GNSS."""
    loc, run = review.location, review.run
    ref = loc.reference
    (t0, start), (t1, end) = run.first, run.last
    trace = gis.trace_feature(loc.lat_lon, start, end, {
        'line': ref.line, 'track': ref.track, 'direction': ref.direction,
        'start_km': _number(float(ref.km(start)), 4), 'end_km': _number(float(ref.km(end)), 4),
        'bag': review.options.bag.name, 'start_utc': _iso(t0), 'end_utc': _iso(t1)})
    return [trace, *gis.section_features(loc.lat_lon, sections, start, end),
            *(gis.point_feature(d['lat'], d['lon'],
                                {k: v for k, v in d.items() if k not in ('lat', 'lon')})
              for d in defects)]


def write_outputs(review: Review, folder: Path) -> list[gis.Feature]:
    """defects.csv, sections.csv and review.geojson (``FILES``) into ``folder``; returns the
    GeoJSON features."""
    defects, sections = defect_rows(review), section_rows(review)
    _write_csv(folder / DEFECTS_CSV, defects, DEFECT_COLUMNS)
    _write_csv(folder / SECTIONS_CSV, sections, SECTION_COLUMNS)
    found = features(review, defects, sections)
    gis.write(folder / GEOJSON, found)
    return found


def summary(review: Review, report: Path) -> dict[str, Any]:
    """The ``--json`` summary: run, location, counts, worst defect, sections, files written."""
    run, loc = review.run, review.location
    worst = max(review.exceedances, key=lambda e: (e.severity, abs(e.peak_u_m)), default=None)
    worst_row = None
    if worst is not None:
        worst_row = next(d for d in defect_rows(review) if d['stamp_ns'] == worst.peak_stamp_ns)
    sd = review.sections.sd_m
    total = sum(review.timings.values())
    return {
        'bag': str(review.options.bag),
        'files': {'report': str(report), **{k: str(report.parent / v) for k, v in FILES.items()}},
        'duration_s': _number(review.duration_s, 3), 'length_km': _number(run.length_m / 1e3, 4),
        'samples': run.emitted,
        'location': {'line': loc.reference.line, 'track': loc.reference.track,
                     'direction': loc.reference.direction,
                     'km_origin': loc.reference.km_origin,
                     'start_km': _number(float(loc.reference.km(run.first[1])), 4),
                     'end_km': _number(float(loc.reference.km(run.last[1])), 4),
                     'gnss': loc.track is not None,
                     'odometry_scale': _number(loc.scale.value, 6),
                     'odometry_scale_std': _number(loc.scale.std, 6),
                     'odometry_scale_note': loc.scale.note},
        'exceedances': {level: {c: n for c, n in counts.items()}
                        for level, counts in _counts(review).items()},
        'exceedances_text': describe_counts(review.exceedances),
        'limits': {'table': review.limits.table.name, 'band': review.limits.band,
                   'basis': review.limits.basis},
        'worst_defect': worst_row,
        'sections': {'count': int(np.sum(np.isfinite(sd))),
                     'max_sd_mm': _number(float(np.nanmax(sd)) * MM, 4)
                     if np.any(np.isfinite(sd)) else None},
        'findings': {f.key: {'level': ('OK', 'WARN', 'ERROR')[f.level], 'message': f.message}
                     for f in run.findings},
        'review_s': _number(total, 2),
        'real_time_factor': _number(review.duration_s / total, 1) if total > 0 else None,
    }


def _counts(review: Review) -> dict[str, dict[str, int]]:
    from railgsa_ros.review.exceedances import CONFIDENCES, count_by_level

    return {level: {c: int(counts[c]) for c in CONFIDENCES}
            for level, counts in count_by_level(review.exceedances).items()}
