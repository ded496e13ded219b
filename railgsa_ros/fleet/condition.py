"""A line's condition from its stored passes: scatter, fused profile, defects and their trends.

Recomputed from the database after every batch (cheap next to the inversion): ``fuse`` gives
each pass's scatter sigma_p and gain g_p and the fused profile; every pass is searched for
defects (``defects.detect``) against the alert limit of the speed range at each cell: the
line's permitted speed there (``standards.line_speed``, ``--line-speed``), else the fastest
pass there (``fastest_speed``), so whether a defect is followed does not depend on how fast the
train that saw it ran. Every level is ``standards.en13848.classify``'s, as in the review;
detections are matched into defects; each defect is then measured in every pass covering it,
found there or not, so its depth series has no holes. The depth of pass p has the SD
sqrt(sigma_p^2 + (s_g d)^2), s_g the RMS gain of the line's passes (a vehicle or speed that
reads 2 % high reads a 6 mm defect 0.12 mm high). A defect is NEW when earlier passes covered
its position, did not find it, and saw less than NEW_RATIO of the depth of its first detection
there (a defect that grows past the detection threshold is not new); its trend then starts at
its first detection.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import duckdb
import numpy as np

from railgsa_ros.fleet import db
from railgsa_ros.fleet.align import Alignment
from railgsa_ros.fleet.defects import DETECT_FRACTION, Peak, detect, match, measure
from railgsa_ros.fleet.fuse import fuse_line, pass_scatter
from railgsa_ros.fleet.trend import crossing, fit_trend
from railgsa_ros.standards.en13848 import LEVELS, Limits, level_name

if TYPE_CHECKING:
    from railgsa_ros.geo import Line

DAY_NS = 86400 * 10**9
MAX_DAYS = 1e5  # projections beyond ~2240 are reported as none
NEW_RATIO = 0.5  # NEW: every earlier pass saw less than this share of the first detected depth


@dataclass(frozen=True)
class LinePass:
    """One 'ok' pass of a line: id, scatter (m), gain, alignment."""

    pass_id: int
    noise_m: float
    gain: float
    alignment: Alignment


def line_passes(con: duckdb.DuckDBPyConnection, line: str, track: str) -> list[LinePass]:
    """The line's aligned passes in time order."""
    rows = con.execute("""
        SELECT p.pass_id, p.noise_m, coalesce(p.gain, 'nan'),
               a.offset_m, a.scale, a.offset_sd_m, a.scale_sd, a.cov_offset_scale, a.method
        FROM passes p JOIN alignments a USING (pass_id)
        WHERE p.line = ? AND p.track = ? AND p.status = 'ok' ORDER BY p.start_time, p.pass_id
        """, [line, track]).fetchall()
    out = []
    for pid, noise, gain, off, scale, off_sd, scale_sd, cov, method in rows:
        c = np.array([[off_sd ** 2, cov], [cov, scale_sd ** 2]])
        out.append(LinePass(pid, float(noise), float(gain),
                            Alignment(off, scale, c, method)))
    return out


def fastest_speed(con: duckdb.DuckDBPyConnection, line: str, track: str
                  ) -> dict[str, np.ndarray]:
    """cell and speed_mps, the fastest |speed| (m/s) of the line's 'ok' passes over each valid
    cell, in cell order: without the line's permitted speed (EN 13848-5 classes by it), which
    no measuring train exceeds, the fastest pass is its best lower bound."""
    return db.fetch(con, """SELECT pr.cell, max(abs(pr.speed_mps)) AS speed_mps
                            FROM profiles pr JOIN passes pa USING (pass_id)
                            WHERE pa.line = ? AND pa.track = ? AND pa.status = 'ok' AND pr.valid
                            GROUP BY pr.cell ORDER BY pr.cell""", [line, track])


def pass_profile(con: duckdb.DuckDBPyConnection, pass_id: int) -> dict[str, np.ndarray]:
    """cell, u_m, valid, stamp_ns, speed_mps of one pass on its line grid, in cell order."""
    return db.fetch(con, 'SELECT cell, u_m, valid, stamp_ns, speed_mps FROM profiles '
                         'WHERE pass_id = ? ORDER BY cell', [pass_id])


def ok_passes(con: duckdb.DuckDBPyConnection, line: str, track: str) -> tuple[int, int]:
    """(count, largest id) of the line's 'ok' passes ((0, 0) for none): ids only grow and
    passes are never removed, so this pair changes with every pass stored."""
    count, last = con.execute("""SELECT count(*), coalesce(max(pass_id), 0) FROM passes
                                 WHERE line = ? AND track = ? AND status = 'ok'""",
                              [line, track]).fetchone() or (0, 0)
    return int(count), int(last)


def is_current(con: duckdb.DuckDBPyConnection, line: str, track: str) -> bool:
    """Whether the line's condition (fused profile, defects) was computed from the 'ok' passes
    it holds now: False when a pass was stored and the process died before (or during) the
    update, or the update predates ``line_updates``."""
    done = con.execute('SELECT passes, last_pass FROM line_updates WHERE line = ? AND track = ?',
                       [line, track]).fetchone()
    now = ok_passes(con, line, track)
    return now[0] == 0 or (done is not None and tuple(done) == now)


def _level(limits: Limits, depth_m: float, x_m: float, speed_mps: float
           ) -> tuple[str, str, float]:
    """(level reached or '', next level or '', next limit (m) or NaN) of a depth at line
    position x (m), measured at speed (m/s): the next level is the next one the table has."""
    at = (np.array([depth_m]), np.array([x_m]), np.array([speed_mps]))
    level = int(limits.classify(*at)[0])
    row = limits.at(*at[1:])[0]
    above = [j for j in range(level, len(LEVELS)) if np.isfinite(row[j])]
    if not above:
        return level_name(level), '', float('nan')
    return level_name(level), LEVELS[above[0]], float(row[above[0]])


def reclass(row: dict, limits: Limits) -> dict:
    """A defects row (km, depth_m, speed_kmh, level, next_level, next_limit_m, projected*)
    classed by ``limits`` (as ``fleet report`` and ``query`` apply a table and line speed to a
    stored line): the projected dates are kept where the next limit did not change, else
    None (they need the trend: ``fleet ingest`` with the same table computes them)."""
    level, nxt, limit = _level(limits, row['depth_m'], 1000.0 * row['km'],
                               row['speed_kmh'] / 3.6)
    out = {**row, 'level': level, 'next_level': nxt, 'next_limit_m': limit}
    stored = row.get('next_limit_m')
    stored = float('nan') if stored is None else float(stored)
    if nxt != row.get('next_level') or not np.isclose(stored, limit, rtol=1e-12, atol=0.0,
                                                      equal_nan=True):
        out.update({k: None for k in ('projected', 'projected_early', 'projected_late')
                    if k in row})
    return out


def update_line(con: duckdb.DuckDBPyConnection, line: str, track: str, dx: float,
                limits: Limits, geometry: Line | None = None,
                fraction: float = DETECT_FRACTION) -> None:
    """Recompute the line's scatter, fused profile, detections and defects (module docstring)
    and record the passes they come from (``line_updates``); with a ``geo.Line`` in the line's
    frame, the defects get their WGS84 position; defects are detected from ``fraction`` of the
    alert limit. Run it in one transaction (``db.transaction``)."""
    pass_scatter(con, line, track)
    fuse_line(con, line, track)
    passes = line_passes(con, line, track)
    gains = np.array([p.gain for p in passes])
    s_g = float(np.sqrt(np.mean(gains[np.isfinite(gains)] ** 2))) if np.isfinite(gains).any() \
        else 0.0
    fastest = fastest_speed(con, line, track)
    found: list[tuple[int, Peak]] = []  # (pass index, peak) in time order
    for i, p in enumerate(passes if fastest['cell'].size else []):  # none: no valid cell
        prof = pass_profile(con, p.pass_id)
        # every valid cell of an 'ok' pass is in ``fastest``; invalid cells are not searched
        at = np.searchsorted(fastest['cell'], prof['cell']).clip(0, fastest['cell'].size - 1)
        found += [(i, pk) for pk in detect(prof['cell'], prof['u_m'], prof['valid'],
                                           fastest['speed_mps'][at], dx, limits, fraction)]
    x_found = np.array([pk.x_m for _, pk in found])
    sign_found = np.array([np.sign(pk.signed_m) for _, pk in found])
    ids = match(x_found, sign_found)
    n_def = int(ids.max()) + 1 if ids.size else 0
    x_def = np.array([x_found[ids == d].mean() for d in range(n_def)])
    sign_def = np.array([sign_found[ids == d][0] for d in range(n_def)])
    detected = {(i, int(j)) for (i, _), j in zip(found, ids, strict=True)}
    rows: dict[str, list] = {k: [] for k in ('pass', 'defect', 'x', 'x_sd', 'depth', 'depth_sd',
                                             'signed', 'speed', 'stamp', 'detected')}
    for i, p in enumerate(passes):
        prof = pass_profile(con, p.pass_id)
        for d in range(n_def):
            pk = measure(prof['cell'], prof['u_m'], prof['valid'], dx, x_def[d], sign_def[d])
            if pk is None:
                continue
            s = (pk.x_m - p.alignment.offset_m) / p.alignment.scale
            for key, value in (('pass', p.pass_id), ('defect', d), ('x', pk.x_m),
                               ('x_sd', float(p.alignment.position_sd(s))),
                               ('depth', pk.depth_m),
                               ('depth_sd', float(np.hypot(p.noise_m, s_g * pk.depth_m))),
                               ('signed', pk.signed_m), ('speed', prof['speed_mps'][pk.index]),
                               ('stamp', prof['stamp_ns'][pk.index]),
                               ('detected', (i, d) in detected)):
                rows[key].append(value)
    frame = con.execute('SELECT frame FROM lines WHERE line = ? AND track = ?',
                        [line, track]).fetchone()
    where = geometry if frame is not None and frame[0] == 'gnss' else None
    _store(con, line, track, rows, x_def, sign_def, limits, where)
    con.execute('INSERT OR REPLACE INTO line_updates VALUES (?, ?, ?, ?)',
                [line, track, *ok_passes(con, line, track)])


def _store(con: duckdb.DuckDBPyConnection, line: str, track: str, rows: dict[str, list],
           x_def: np.ndarray, sign_def: np.ndarray, limits: Limits,
           geometry: Line | None) -> None:
    """Write the line's detections and defects (replacing the previous ones); WGS84
    positions from ``geometry`` (None: NULL)."""
    key = [line, track]
    con.execute('DELETE FROM detections WHERE line = ? AND track = ?', key)
    con.execute('DELETE FROM defects WHERE line = ? AND track = ?', key)
    r = {k: np.asarray(v) for k, v in rows.items()}
    if r['pass'].size == 0:
        return
    speed_kmh = np.abs(r['speed'].astype(float)) * 3.6
    levels = [level_name(k) for k in limits.classify(r['depth'], r['x'], r['speed'])]
    db.insert_columns(con, 'detections', {
        'pass_id': r['pass'].astype(np.int32), 'line': np.full(r['pass'].size, line),
        'track': np.full(r['pass'].size, track), 'defect_id': r['defect'].astype(np.int32),
        'x_m': r['x'], 'x_sd_m': r['x_sd'], 'depth_m': r['depth'], 'depth_sd_m': r['depth_sd'],
        'signed_m': r['signed'], 'speed_kmh': speed_kmh,
        'time': np.array([db.timestamp(t) for t in r['stamp']], dtype='datetime64[us]'),
        'level': np.array(levels), 'detected': r['detected'].astype(bool)})
    lat, lon = np.full(x_def.size, np.nan), np.full(x_def.size, np.nan)
    if geometry is not None:
        inside = (x_def >= geometry.start_m) & (x_def <= geometry.end_m)
        if inside.any():
            lat[inside], lon[inside] = geometry.position(x_def[inside])
    for d in range(x_def.size):
        _store_defect(con, line, track, d, x_def[d], sign_def[d],
                      {k: v[r['defect'] == d] for k, v in r.items()}, limits,
                      (float(lat[d]), float(lon[d])))


def _store_defect(con: duckdb.DuckDBPyConnection, line: str, track: str, d: int, x: float,
                  sign: float, obs: dict[str, np.ndarray], limits: Limits,
                  lat_lon: tuple[float, float]) -> None:
    """One defect's trend row from its observations (in time order), at (lat, lon) deg."""
    first = int(np.flatnonzero(obs['detected'])[0])
    # earlier passes covered it and saw much less: a jump, not a defect that grew past the
    # detection threshold
    new = first > 0 and bool(np.max(obs['depth'][:first]) < NEW_RATIO * obs['depth'][first])
    use = slice(first, None) if new else slice(None)
    t_days = obs['stamp'][use].astype(float) / DAY_NS
    trend = fit_trend(t_days, obs['depth'][use], obs['depth_sd'][use])
    speed = float(np.max(np.abs(obs['speed'][use])))
    now = float(t_days[-1])
    depth, depth_sd = (float(obs['depth'][use][-1]), float(obs['depth_sd'][use][-1]))
    rate = rate_se = float('nan')
    dates: tuple[object, ...] = (None, None, None)
    if trend is not None:
        fitted, fitted_sd = trend.at(now)
        depth, depth_sd = float(fitted), float(fitted_sd)
        rate, rate_se = trend.rate_m_per_day, trend.rate_se
    level, nxt, limit = _level(limits, depth, x, speed)
    if trend is not None and np.isfinite(limit):
        dates = tuple(_date(t) for t in crossing(trend, limit, now))
    w = 1.0 / obs['x_sd'][use] ** 2 if np.all(obs['x_sd'][use] > 0) else None
    seen = obs['x'][use]
    # at least the standard error of the passes' scatter: the frame-defining pass has an SD of
    # 0 (it is the frame), which made every defect's 0 without GNSS
    scatter = float(np.std(seen, ddof=1) / np.sqrt(seen.size)) if seen.size > 1 else 0.0
    x_sd = max(float(np.sqrt(1.0 / w.sum())) if w is not None else 0.0, scatter)
    per_year = 365.25e3  # m/day -> mm/year
    con.execute(f'INSERT INTO defects VALUES ({", ".join("?" * 24)})',
                [line, track, d, x, x / 1000.0, x_sd, int(sign),
                 db.timestamp(obs['stamp'][first]), db.timestamp(obs['stamp'][-1]),
                 int(t_days.size), new, depth, depth_sd, rate * per_year, rate_se * per_year,
                 speed * 3.6, level, nxt, limit, *dates,
                 *(v if np.isfinite(v) else None for v in lat_lon)])


def _date(t_days: float) -> object:
    """A DATE for a time in days since the epoch; None when infinite, NaN or beyond MAX_DAYS."""
    if not np.isfinite(t_days) or abs(t_days) > MAX_DAYS:
        return None
    return db.timestamp(t_days * DAY_NS).date()
