"""``railgsa fleet report``: an HTML trend report of the database, with a map, a zoomable
profile (``svg_views``: inline SVG and script, works offline) and matplotlib figures.

Per line: the map of its trace (the stored line geometry over the stretch the passes cover),
its 200 m sections coloured by the SD class of their newest pass and its defects; the fused
profile with its +-2 SD band, the EN 13848-5 limits (AL, IL, IAL by the line speed when given,
else the fastest pass, as the defects are classed) and the followed defects; each defect's
depth over time with its error bars, the fitted trend with its 95 % band, every limit and the
projected date; the SD per 200 m section of every pass. Then the defects table (NEW flagged)
and the pass table (failed and unaligned passes with their message; bags relative to the
database's folder).
The same trace, sections and defects are in DIR/fleet.geojson (``gis``).
"""

from __future__ import annotations

from datetime import UTC, date, datetime
from html import escape
import math
import os
from pathlib import Path
import re
from typing import TYPE_CHECKING, Any

import duckdb
import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt
import numpy as np

from railgsa_ros import gis
from railgsa_ros.envelope import envelope
from railgsa_ros.fileio import atomic_output
from railgsa_ros.fleet import db
from railgsa_ros.fleet.condition import DAY_NS, reclass
from railgsa_ros.fleet.gnss import line_from_json
from railgsa_ros.fleet.trend import fit_trend
from railgsa_ros.standards.en13848 import LEVELS, Limits, LimitTable, en13848_table
from railgsa_ros.standards.line_speed import LineSpeed
from railgsa_ros.standards.sections import SECTION_M
from railgsa_ros.svg_views import CSS as SVG_CSS
from railgsa_ros.svg_views import MAP_LEGEND, SCRIPT, Mark, map_svg, profile_legend, profile_svg

if TYPE_CHECKING:
    from railgsa_ros.geo import Line

REPORT = 'report.html'
GEOJSON = 'fleet.geojson'
MM = 1e3
LEVEL_COLOURS = {'AL': '#e0a800', 'IL': '#e8590c', 'IAL': '#c92a2a'}


def _slug(line: str, track: str) -> str:
    """File-name-safe 'line_track'."""
    return re.sub(r'[^A-Za-z0-9._-]+', '-', f'{line}_{track}')


def fused_profile(con: duckdb.DuckDBPyConnection, line: str, track: str, dx: float,
                  limits: Limits) -> str:
    """The zoomable fused profile (mm over the line's km) with its +-2 SD band, the limits
    (``limits``: by the line speed, else the fastest pass over each stretch) and the defects;
    its legend below."""
    f = db.fetch(con, """SELECT f.cell, f.u_m, f.sd_m, v.speed_mps FROM fused f LEFT JOIN (
                             SELECT cell, max(abs(pr.speed_mps)) AS speed_mps
                             FROM profiles pr JOIN passes p USING (pass_id)
                             WHERE p.line = ? AND p.track = ? AND p.status = 'ok' AND pr.valid
                             GROUP BY cell) v USING (cell)
                         WHERE f.line = ? AND f.track = ? ORDER BY f.cell""",
                 [line, track, line, track])
    x = f['cell'] * dx
    # the strictest limits per bin (its fastest pass), as the defects are classed; NaN speed
    # (no pass there): no limit
    xl, _, fastest = envelope(x, np.asarray(f['speed_mps'], dtype=float))
    thresholds = limits.at(xl, fastest) * MM
    levels = [lv for j, lv in enumerate(LEVELS) if np.any(np.isfinite(thresholds[:, j]))]
    marks = [Mark(d['x_m'], d['depth_m'] * MM, d['level'] or 'none',
                  f'{d["level"] or "below AL"}{" NEW" if d["new"] else ""} at km '
                  f'{d["km"]:.4f}: {d["depth_m"] * MM:+.2f} mm', bool(d['new']))
             for d in line_defects(con, line, track, limits)]
    u, sd = f['u_m'] * MM, f['sd_m'] * MM
    return profile_svg(x, u, label=f'line {line} track {track}: fused profile',
                       band_mm=(u - 2 * sd, u + 2 * sd), marks=marks,
                       limits_mm={lv: (xl, thresholds[:, LEVELS.index(lv)]) for lv in levels}
                       ) + profile_legend('+-2 SD', levels)


def plot_trends(path: Path, con: duckdb.DuckDBPyConnection, line: str, track: str,
                limits: Limits) -> Path:
    """One panel per defect: depth over time (error bars 1 SD), WLS trend with its 95 % band
    extended to the projected date (of the next limit), every limit at the defect's speed."""
    d = con.execute('SELECT defect_id, km, new, speed_kmh, projected, first_seen FROM defects '
                    'WHERE line = ? AND track = ? ORDER BY km', [line, track]).fetchall()
    n = max(len(d), 1)
    fig, axes = plt.subplots(n, 1, figsize=(8, 2.6 * n), layout='constrained', squeeze=False)
    for ax, (did, km, new, speed_kmh, projected, first) in zip(axes[:, 0], d, strict=False):
        obs = db.fetch(con, 'SELECT epoch_ns(time) AS t, depth_m, depth_sd_m, detected '
                            'FROM detections WHERE line = ? AND track = ? AND defect_id = ? '
                            'ORDER BY time', [line, track, did])
        t = obs['t'].astype(float) / DAY_NS
        use = t >= (epoch_days(first) if new else -np.inf)
        ax.errorbar(_dates(t), obs['depth_m'] * MM, yerr=obs['depth_sd_m'] * MM, fmt='o',
                    color='k', ms=4, capsize=2, label='per pass (1 SD)')
        trend = fit_trend(t[use], obs['depth_m'][use], obs['depth_sd_m'][use])
        if trend is not None:
            end = t[-1] + max(0.25 * (t[-1] - t[0]), 30.0)
            if projected is not None:
                end = max(end, epoch_days(projected) + 10)
            tt = np.linspace(t[use][0], min(end, t[-1] + 3650), 200)
            mid, sd = trend.at(tt)
            ax.plot(_dates(tt), mid * MM, color='tab:blue', label='trend (WLS)')
            ax.fill_between(_dates(tt), (mid - 1.96 * sd) * MM, (mid + 1.96 * sd) * MM,
                            color='tab:blue', alpha=0.2, lw=0, label='95 %')
        for level, limit in zip(LEVELS, limits.at(np.array([1e3 * km]),
                                                  np.array([speed_kmh / 3.6]))[0], strict=True):
            if np.isfinite(limit):
                ax.axhline(limit * MM, color=LEVEL_COLOURS[level], ls='--', lw=1,
                           label=f'{level} {limit * MM:g} mm')
        if projected is not None:
            ax.axvline(np.datetime64(projected), color='tab:red', lw=0.8)
        ax.set(ylabel='depth (mm)', title=f'km {km:.4f}' + (' NEW' if new else ''))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc='upper left', ncol=2)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_segments(path: Path, con: duckdb.DuckDBPyConnection, line: str, track: str,
                  limits: Limits) -> Path:
    """SD of the band-filtered profile per 200 m section, one line per pass (by date), with the
    lower end of the SD alert range of each section (``limits``: at its centre's km-post and
    its pass's speed)."""
    rows = db.fetch(con, """SELECT s.pass_id, s.start_m, s.sd_m, s.speed_mps,
                                  strftime(p.start_time, '%Y-%m-%d') AS day
                           FROM segments s JOIN passes p USING (pass_id)
                           WHERE p.line = ? AND p.track = ? AND p.status = 'ok'
                           ORDER BY p.start_time, s.start_m""", [line, track])
    fig, ax = plt.subplots(figsize=(11, 3.2), layout='constrained')
    for pid in dict.fromkeys(rows['pass_id'].tolist()):
        pick = rows['pass_id'] == pid
        km = (rows['start_m'][pick] + SECTION_M / 2) / 1000
        ax.plot(km, rows['sd_m'][pick] * MM, 'o-', ms=3, lw=0.8,
                label=f'pass {pid} ({rows["day"][pick][0]})')
    if rows['start_m'].size:
        alert = limits.sd_at(rows['start_m'] + SECTION_M / 2, rows['speed_mps'])[:, 0]
        order = np.argsort(rows['start_m'])
        ax.step((rows['start_m'][order] + SECTION_M / 2) / 1000, alert[order] * MM, where='mid',
                color='tab:red', ls='--', lw=1, label='SD alert (lower end)')
    ax.set(xlabel='km (section centre)', ylabel='SD per 200 m (mm)', ylim=(0, None),
           title=f'line {line} track {track}: 200 m sections')
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=3)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def epoch_days(value: date) -> float:
    """Days since the epoch of a date or datetime."""
    return float(np.datetime64(value, 'ns').astype(np.int64)) / DAY_NS


def _dates(t_days: np.ndarray) -> np.ndarray:
    """datetime64 values of times in days since the epoch."""
    return (np.asarray(t_days) * DAY_NS).astype(np.int64).astype('datetime64[ns]')


def _table(con: duckdb.DuckDBPyConnection, sql: str, params: list | None = None) -> str:
    """An HTML table of a query's result."""
    cur = con.execute(sql, params or [])
    head = ''.join(f'<th>{escape(c[0])}</th>' for c in cur.description)
    body = ''.join('<tr>' + ''.join(f'<td>{escape(_cell(v))}</td>' for v in row) + '</tr>'
                   for row in cur.fetchall())
    return f'<table><tr>{head}</tr>{body}</table>'


def _cell(value: object) -> str:
    """Table text: 4 significant digits for floats, '' for NULL."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return ''
    if isinstance(value, bool):
        return 'NEW' if value else ''
    if isinstance(value, float):
        return f'{value:.4g}'
    return str(value)


def _positions(geometry: Line | None) -> gis.Positions:
    """(lat, lon) deg of line chainages (m) on ``geometry``; NaN off it or without one."""
    def positions(x_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lat, lon = np.full(x_m.shape, np.nan), np.full(x_m.shape, np.nan)
        if geometry is not None:
            on = (x_m >= geometry.start_m) & (x_m <= geometry.end_m)
            if on.any():
                lat[on], lon[on] = geometry.position(x_m[on])
        return lat, lon
    return positions


def _plain(row: dict[str, Any]) -> dict[str, Any]:
    """JSON values: dates as ISO text, None for NaN, lengths in mm (``_m`` columns become
    ``_mm``), floats rounded to 4 digits after the point (0.1 um, 0.1 mm of km)."""
    out: dict[str, Any] = {}
    for key, value in row.items():
        if isinstance(value, datetime):  # DuckDB TIMESTAMP: naive UTC
            value = value.replace(tzinfo=UTC).isoformat()
        elif isinstance(value, date):
            value = value.isoformat()
        elif isinstance(value, float):
            if key.endswith('_m'):
                key, value = key[:-2] + '_mm', value * MM
            value = round(value, 4) if math.isfinite(value) else None
        out[key] = value
    return out


def line_defects(con: duckdb.DuckDBPyConnection, line: str, track: str, limits: Limits
                 ) -> list[dict[str, Any]]:
    """The line's defects in km order, classed by ``limits`` (``condition.reclass``, as the
    defects table), with their signed ``depth_m``."""
    cur = con.execute("""SELECT defect_id, x_m, km, sign, depth_m, depth_sd_m, rate_mm_per_year,
                                rate_se_mm_per_year, speed_kmh, level, next_level,
                                next_limit_m, projected, projected_early, projected_late, new,
                                first_seen, last_seen, passes, lat, lon
                         FROM defects WHERE line = ? AND track = ? ORDER BY km""",
                      [line, track])
    names = [c[0] for c in cur.description]
    rows = [reclass(dict(zip(names, r, strict=True)), limits) for r in cur.fetchall()]
    return [{**{k: v for k, v in r.items() if k != 'sign'}, 'depth_m': r['sign'] * r['depth_m']}
            for r in rows]


def line_features(con: duckdb.DuckDBPyConnection, line: str, track: str, dx: float,
                  limits: Limits, geometry: Line | None) -> list[gis.Feature]:
    """The line's trace (its geometry over the fused profile's extent), its 200 m sections (the
    newest pass with an SD there) and its defects as GeoJSON features (``gis``); null
    geometries without a line geometry."""
    first, last = con.execute('SELECT min(cell), max(cell) FROM fused WHERE line = ? AND '
                              'track = ?', [line, track]).fetchone() or (None, None)
    if first is None:
        return []
    key = {'line': line, 'track': track}
    start, end = first * dx, last * dx
    positions = _positions(geometry)
    trace = gis.trace_feature(positions, start, end, {**key, 'start_km': round(start / 1e3, 4),
                                                      'end_km': round(end / 1e3, 4)})
    sec = db.fetch(con, """SELECT s.start_m, s.sd_m, s.coverage, s.speed_mps, s.pass_id,
                                  strftime(p.start_time, '%Y-%m-%d') AS pass_date
                           FROM segments s JOIN passes p USING (pass_id)
                           WHERE p.line = ? AND p.track = ? AND p.status = 'ok'
                                 AND isfinite(s.sd_m)
                           QUALIFY row_number() OVER (PARTITION BY s.start_m
                                                      ORDER BY p.start_time DESC) = 1
                           ORDER BY s.start_m""", [line, track])
    sd_range = limits.sd_at(sec['start_m'] + SECTION_M / 2, sec['speed_mps'])
    rows = [{**key, 'start_km': round(x / 1e3, 4), 'end_km': round((x + SECTION_M) / 1e3, 4),
             'start_m': float(x), 'length_m': SECTION_M,
             **_plain({'sd_m': float(sd), 'sd_alert_low_m': float(lo),
                       'sd_alert_high_m': float(hi)}),
             'coverage': round(float(c), 4), 'speed_kmh': round(float(v) * 3.6, 1),
             'pass_id': int(pid), 'pass_date': day}
            for x, sd, c, v, pid, day, (lo, hi) in zip(
                sec['start_m'], sec['sd_m'], sec['coverage'], sec['speed_mps'], sec['pass_id'],
                sec['pass_date'], sd_range, strict=True)]
    defects = [{k: v for k, v in d.items() if k != 'x_m'}
               for d in line_defects(con, line, track, limits)]
    return [trace, *gis.section_features(positions, rows, start, end),
            *(gis.point_feature(d.pop('lat'), d.pop('lon'), {**key, **_plain(d)})
              for d in defects)]


STYLE = ('body{font-family:sans-serif;margin:2em;max-width:1200px}table{border-collapse:collapse;'
         'font-size:12px;margin:1em 0}td,th{border:1px solid #ccc;padding:2px 6px}'
         'th{background:#eee}img{max-width:100%}.note{font-size:.85em;color:#495057}')


DEFECT_COLUMNS = ('defect_id', 'km', 'new', 'passes', 'depth_m', 'depth_sd_m', 'rate_mm_per_year',
                  'rate_se_mm_per_year', 'speed_kmh', 'level', 'next_level', 'next_limit_m',
                  'projected', 'projected_early', 'projected_late', 'first_seen')


def defects_table(con: duckdb.DuckDBPyConnection, line: str, track: str, limits: Limits) -> str:
    """The line's defects as an HTML table (lengths in mm), classed by ``limits``
    (``condition.reclass``)."""
    cur = con.execute(f'SELECT {", ".join(DEFECT_COLUMNS)} FROM defects WHERE line = ? AND '
                      'track = ? ORDER BY km', [line, track])
    rows = [reclass(dict(zip(DEFECT_COLUMNS, r, strict=True)), limits) for r in cur.fetchall()]
    heads = [c.replace('_m', '_mm') if c.endswith('_m') else c for c in DEFECT_COLUMNS]
    head = ''.join(f'<th>{escape(c)}</th>' for c in heads)
    body = ''.join('<tr>' + ''.join(
        f'<td>{escape(_cell(r[c] * MM if c.endswith("_m") and r[c] is not None else r[c]))}'
        '</td>' for c in DEFECT_COLUMNS) + '</tr>' for r in rows)
    return f'<table><tr>{head}</tr>{body}</table>'


def write_report(db_path: str | Path, out_dir: str | Path, overwrite: bool = False,
                 table: LimitTable | None = None, line_speed: LineSpeed | None = None) -> Path:
    """Write DIR/report.html, its PNGs and DIR/fleet.geojson atomically, the defects classed by
    ``table`` (None: the standard's) and ``line_speed`` (None: by the measuring speed, the
    fastest pass); returns the report's path."""
    con = db.connect(db_path, read_only=True)
    try:
        lines = con.execute('SELECT line, track, dx_m, band, geometry FROM lines '
                            'ORDER BY line, track').fetchall()
        with atomic_output(out_dir, overwrite) as tmp:
            tmp.mkdir()
            parts = [f'<h1>Track condition: {escape(Path(db_path).name)}</h1>']
            features: list[gis.Feature] = []
            for line, track, dx, band, geometry in lines:
                limits = Limits(table or en13848_table(), band, line_speed)
                slug = _slug(line, track)
                found = line_features(con, line, track, dx, limits,
                                      line_from_json(geometry) if geometry else None)
                features += found
                drawn = map_svg(found, f'map of line {line} track {track}')
                trends = plot_trends(tmp / f'trends_{slug}.png', con, line, track, limits)
                sections = plot_segments(tmp / f'sections_{slug}.png', con, line, track,
                                         limits)
                parts += [f'<h2>Line {escape(line)}, track {escape(track)}</h2>',
                          drawn + MAP_LEGEND if drawn else
                          '<p>No line geometry stored: no map.</p>',
                          '<p class=note>200 m sections coloured by the SD of their newest pass '
                          'against the EN 13848-5 alert range of its speed; defects coloured by '
                          'level, NEW ones ringed (hover for values).</p>',
                          fused_profile(con, line, track, dx, limits),
                          '<h3>Defects (depth = mean-to-peak of the band-filtered profile; '
                          'rate by weighted least squares, SE from the per-pass SDs)</h3>',
                          f'<p>EN 13848-5 levels: {escape(limits.basis)}; limit table '
                          f'{escape(limits.table.name)}.</p>',
                          defects_table(con, line, track, limits),
                          f'<img src="{trends.name}" alt="defect trends">',
                          '<h3>Standard deviation per 200 m section</h3>',
                          f'<img src="{sections.name}" alt="200 m sections">']
            # bags relative to the database's folder, else by name: no machine's paths
            root = str(Path(db_path).resolve().parent) + os.sep
            parts += ['<h2>Passes</h2>', _table(con, """
                SELECT p.pass_id, CASE WHEN starts_with(p.bag, ?) THEN substr(p.bag, ?)
                                       ELSE parse_filename(p.bag) END AS bag,
                       p.start_time, p.vehicle, p.direction,
                       p.speed_mean_mps * 3.6 AS speed_kmh, p.duration_s, p.status, p.message,
                       a.method AS alignment, a.scale, a.position_sd_m, a.correlation,
                       p.noise_m * 1e3 AS scatter_mm, p.gain
                FROM passes p LEFT JOIN alignments a USING (pass_id) ORDER BY p.pass_id""",
                [root, len(root) + 1])]
            gis.write(tmp / GEOJSON, features)
            html = (f'<!doctype html><html><head><meta charset="utf-8"><title>railgsa fleet'
                    f'</title><style>{STYLE}{SVG_CSS}</style></head><body>{"".join(parts)}'
                    f'<script>{SCRIPT}</script></body></html>')
            (tmp / REPORT).write_text(html, encoding='utf-8')
    finally:
        con.close()
    return Path(out_dir) / REPORT
