"""Read the condition database back: the defects of a line between two km-posts, as rows."""

from __future__ import annotations

import csv
from datetime import date, datetime
import io
import json
import math

import duckdb

from railgsa_ros.errors import InputError
from railgsa_ros.fleet.condition import reclass
from railgsa_ros.standards.en13848 import Limits, LimitTable, en13848_table
from railgsa_ros.standards.line_speed import LineSpeed

COLUMNS = ('line', 'track', 'defect_id', 'km', 'x_sd_m', 'sign', 'depth_m', 'depth_sd_m',
           'rate_mm_per_year', 'rate_se_mm_per_year', 'speed_kmh', 'level', 'next_level',
           'next_limit_m', 'projected', 'projected_early', 'projected_late', 'new',
           'first_seen', 'last_seen', 'passes', 'lat', 'lon')


def line_span_km(con: duckdb.DuckDBPyConnection, line: str, track: str | None = None
                 ) -> tuple[float, float]:
    """(first, last) km-post the fused profile of ``line`` (``track`` if given) covers;
    InputError naming the known lines (or tracks) when the database has no such line."""
    known = [r[0] for r in con.execute('SELECT DISTINCT line FROM lines ORDER BY line').fetchall()]
    if line not in known:
        raise InputError(f'line {line!r} is not in the database; known lines: '
                         f'{", ".join(map(repr, known)) or "none"}')
    tracks = [r[0] for r in con.execute('SELECT track FROM lines WHERE line = ? ORDER BY track',
                                        [line]).fetchall()]
    if track is not None and track not in tracks:
        raise InputError(f'line {line!r} has no track {track!r}; its tracks: '
                         f'{", ".join(map(repr, tracks))}')
    lo, hi = con.execute("""SELECT min(f.cell * l.dx_m), max(f.cell * l.dx_m) FROM fused f
                            JOIN lines l USING (line, track)
                            WHERE line = $line AND ($track IS NULL OR track = $track)""",
                         {'line': line, 'track': track}).fetchone() or (None, None)
    return (float('nan'), float('nan')) if lo is None else (lo / 1000.0, hi / 1000.0)


def line_limits(con: duckdb.DuckDBPyConnection, line: str, track: str | None,
                table: LimitTable | None, line_speed: LineSpeed | None) -> Limits | None:
    """The limits of ``table`` (None: the standard's) and ``line_speed`` in the band of the
    line (of its first track when ``track`` is None); None for a line the database lacks."""
    row = con.execute('SELECT band FROM lines WHERE line = ? AND (? IS NULL OR track = ?) '
                      'ORDER BY track', [line, track, track]).fetchone()
    return None if row is None else Limits(table or en13848_table(), row[0], line_speed)


def defects_between(con: duckdb.DuckDBPyConnection, line: str, from_km: float, to_km: float,
                    track: str | None = None, limits: Limits | None = None) -> list[dict]:
    """The followed defects of ``line`` (and ``track`` if given) with from_km <= km <= to_km,
    in km order: one dict per defect with COLUMNS, classed by ``limits`` when given
    (``condition.reclass``; None: as stored by the ingest). InputError for a line or track the
    database does not hold, or a km range that misses the line's (``line_span_km``)."""
    lo, hi = sorted((from_km, to_km))
    first, last = line_span_km(con, line, track)
    if not (math.isfinite(lo) and math.isfinite(hi)) or not lo <= last or not hi >= first:
        raise InputError(f'km {lo:g}-{hi:g} lies outside line {line!r}, which covers km '
                         f'{first:.3f}-{last:.3f}')
    sql = (f'SELECT {", ".join(COLUMNS)} FROM defects WHERE line = ? AND km BETWEEN ? AND ?'
           + (' AND track = ?' if track is not None else '') + ' ORDER BY km, track')
    params = [line, lo, hi] + ([track] if track is not None else [])
    rows = [dict(zip(COLUMNS, row, strict=True)) for row in con.execute(sql, params).fetchall()]
    if limits is None:
        return rows
    return [{**reclass(r, limits), 'class_basis': limits.basis} for r in rows]


def _plain(value: object) -> object:
    """JSON/CSV value: ISO dates, None for NaN."""
    if isinstance(value, (date, datetime)):
        return value.isoformat()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def to_json(rows: list[dict]) -> str:
    """Rows as a JSON array."""
    return json.dumps([{k: _plain(v) for k, v in r.items()} for r in rows], indent=1)


def to_csv(rows: list[dict]) -> str:
    """Rows as CSV with a header (empty fields for missing values)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    columns = list(rows[0]) if rows else list(COLUMNS)
    writer.writerow(columns)
    for r in rows:
        writer.writerow(['' if _plain(r[c]) is None else _plain(r[c]) for c in columns])
    return out.getvalue()
