"""``railgsa fleet report``: an HTML trend report of the database with matplotlib figures.

Per line: the fused profile with its +-2 SD band and the followed defects; each defect's depth
over time with its error bars, the fitted trend with its 95 % band, the next EN 13848-5 limit
and the projected date; the SD per 200 m section of every pass. Then the defects table (NEW
flagged) and the pass table (failed and unaligned passes with their message).
"""

from __future__ import annotations

from datetime import date
from html import escape
from pathlib import Path
import re

import duckdb
import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt
import numpy as np

from railgsa_ros.fileio import atomic_output
from railgsa_ros.fleet import db
from railgsa_ros.fleet.condition import DAY_NS, reclass
from railgsa_ros.fleet.trend import fit_trend
from railgsa_ros.standards.en13848 import Limits, LimitTable, en13848_table
from railgsa_ros.standards.line_speed import LineSpeed

REPORT = 'report.html'
MM = 1e3


def _slug(line: str, track: str) -> str:
    """File-name-safe 'line_track'."""
    return re.sub(r'[^A-Za-z0-9._-]+', '-', f'{line}_{track}')


def plot_fused(path: Path, con: duckdb.DuckDBPyConnection, line: str, track: str,
               dx: float) -> Path:
    """Fused profile (mm) over km with its +-2 SD band and the defects marked."""
    f = db.fetch(con, 'SELECT cell, u_m, sd_m FROM fused WHERE line = ? AND track = ? '
                      'ORDER BY cell', [line, track])
    d = db.fetch(con, 'SELECT km, sign, depth_m, new FROM defects WHERE line = ? AND track = ?',
                 [line, track])
    km = f['cell'] * dx / 1000
    fig, ax = plt.subplots(figsize=(11, 3.6), layout='constrained')
    ax.fill_between(km, (f['u_m'] - 2 * f['sd_m']) * MM, (f['u_m'] + 2 * f['sd_m']) * MM,
                    color='tab:blue', alpha=0.3, lw=0, label='+-2 SD')
    ax.plot(km, f['u_m'] * MM, color='tab:blue', lw=0.6, label='fused profile')
    for k, s, dep, new in zip(d['km'], d['sign'], d['depth_m'], d['new'], strict=True):
        ax.plot(k, s * dep * MM, 'v' if s < 0 else '^', color='tab:red' if new else 'k', ms=7)
        ax.annotate('NEW' if new else f'{k:.3f}', (k, s * dep * MM), textcoords='offset points',
                    xytext=(4, -12 if s < 0 else 6), fontsize=8)
    ax.set(xlabel='km', ylabel='irregularity (mm)', title=f'line {line} track {track}: fused')
    ax.legend(loc='upper right', fontsize=8)
    ax.grid(alpha=0.3)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_trends(path: Path, con: duckdb.DuckDBPyConnection, line: str, track: str) -> Path:
    """One panel per defect: depth over time (error bars 1 SD), WLS trend with its 95 % band
    extended to the projected date, the next limit."""
    d = con.execute('SELECT defect_id, km, new, next_level, next_limit_m, projected, '
                    'first_seen FROM defects WHERE line = ? AND track = ? ORDER BY km',
                    [line, track]).fetchall()
    n = max(len(d), 1)
    fig, axes = plt.subplots(n, 1, figsize=(8, 2.6 * n), layout='constrained', squeeze=False)
    for ax, (did, km, new, nxt, limit, projected, first) in zip(axes[:, 0], d, strict=False):
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
        if limit is not None and np.isfinite(limit):
            ax.axhline(limit * MM, color='tab:red', ls='--', lw=1, label=f'{nxt}')
        if projected is not None:
            ax.axvline(np.datetime64(projected), color='tab:red', lw=0.8)
        ax.set(ylabel='depth (mm)', title=f'km {km:.4f}' + (' NEW' if new else ''))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc='upper left')
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
        km = (rows['start_m'][pick] + 100.0) / 1000
        ax.plot(km, rows['sd_m'][pick] * MM, 'o-', ms=3, lw=0.8,
                label=f'pass {pid} ({rows["day"][pick][0]})')
    if rows['start_m'].size:
        alert = limits.sd_at(rows['start_m'] + 100.0, rows['speed_mps'])[:, 0]
        order = np.argsort(rows['start_m'])
        ax.step((rows['start_m'][order] + 100.0) / 1000, alert[order] * MM, where='mid',
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


STYLE = ('body{font-family:sans-serif;margin:2em;max-width:1200px}table{border-collapse:collapse;'
         'font-size:12px;margin:1em 0}td,th{border:1px solid #ccc;padding:2px 6px}'
         'th{background:#eee}img{max-width:100%}')


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
    """Write DIR/report.html and its PNGs atomically, the defects classed by ``table`` (None:
    the standard's) and ``line_speed`` (None: by the measuring speed, the fastest pass);
    returns the report's path."""
    con = db.connect(db_path, read_only=True)
    try:
        lines = con.execute('SELECT line, track, dx_m, band FROM lines '
                            'ORDER BY line, track').fetchall()
        with atomic_output(out_dir, overwrite) as tmp:
            tmp.mkdir()
            parts = [f'<h1>Track condition: {escape(str(db_path))}</h1>']
            for line, track, dx, band in lines:
                limits = Limits(table or en13848_table(), band, line_speed)
                slug = _slug(line, track)
                fused = plot_fused(tmp / f'fused_{slug}.png', con, line, track, dx)
                trends = plot_trends(tmp / f'trends_{slug}.png', con, line, track)
                sections = plot_segments(tmp / f'sections_{slug}.png', con, line, track,
                                         limits)
                parts += [f'<h2>Line {escape(line)}, track {escape(track)}</h2>',
                          f'<img src="{fused.name}" alt="fused profile">',
                          '<h3>Defects (depth = mean-to-peak of the band-filtered profile; '
                          'rate by weighted least squares, SE from the per-pass SDs)</h3>',
                          f'<p>EN 13848-5 levels: {escape(limits.basis)}; limit table '
                          f'{escape(limits.table.name)}.</p>',
                          defects_table(con, line, track, limits),
                          f'<img src="{trends.name}" alt="defect trends">',
                          '<h3>Standard deviation per 200 m section</h3>',
                          f'<img src="{sections.name}" alt="200 m sections">']
            parts += ['<h2>Passes</h2>', _table(con, """
                SELECT p.pass_id, p.bag, p.start_time, p.vehicle, p.direction,
                       p.speed_mean_mps * 3.6 AS speed_kmh, p.duration_s, p.status, p.message,
                       a.method AS alignment, a.scale, a.position_sd_m, a.correlation,
                       p.noise_m * 1e3 AS scatter_mm, p.gain
                FROM passes p LEFT JOIN alignments a USING (pass_id) ORDER BY p.pass_id""")]
            html = (f'<!doctype html><html><head><meta charset="utf-8"><title>railgsa fleet'
                    f'</title><style>{STYLE}</style></head><body>{"".join(parts)}</body></html>')
            (tmp / REPORT).write_text(html, encoding='utf-8')
    finally:
        con.close()
    return Path(out_dir) / REPORT
