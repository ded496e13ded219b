"""A batch of bags into the database: workers invert (Dask), the client aligns and writes.

Each bag is one Dask task (``passes.analyse_pass``, retried by Dask on a lost worker); the
client takes the results in submission order (so the first bag of a new line defines its frame
whatever finishes first), aligns each against its line's reference and writes it: DuckDB has one
writer, the client. A task that raises is a failed pass: one line in the summary and in
``passes.message``; the rest of the batch goes on. A bag already stored, by path or by content
(``bag.digest``: a copy under another name), is skipped. After the batch the line is recomputed
(``condition.update_line``) in one transaction. A line whose condition is not computed from
the passes it holds (a process killed between storing a pass and the end of the line update) is
rebuilt from its stored passes by the next ingest, even when every bag of it is skipped.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import duckdb
import numpy as np

from railgsa_ros.bag.digest import bag_digest
from railgsa_ros.errors import RailGsaError
from railgsa_ros.fleet import db
from railgsa_ros.fleet.align import Alignment, Reference, on_line_grid, origin, xcorr_align
from railgsa_ros.fleet.condition import is_current, ok_passes, update_line
from railgsa_ros.fleet.gnss import align_fixes, geometry_json, line_from_json
from railgsa_ros.fleet.passes import PassFailure, PassOptions, PassResult, analyse_or_fail
from railgsa_ros.standards.en13848 import Limits, en13848_table
from railgsa_ros.standards.sections import section_sd

if TYPE_CHECKING:
    from dask.distributed import Client

    from railgsa_ros.geo import Line

HOST = '127.0.0.1'  # a LocalCluster listens on loopback only
RETRIES = 2  # Dask reruns a task whose worker died or that raised unexpectedly


@dataclass(frozen=True)
class Outcome:
    """What happened to one bag: pass id (None when skipped), status and a one-line message; or
    to the line (``bag`` 'line L track T', status 'repaired': ``_repair``)."""

    bag: str
    pass_id: int | None
    status: str
    message: str


@contextmanager
def dask_client(scheduler: str | None, workers: int) -> Iterator[Client]:
    """A distributed Client on ``scheduler``, or on a LocalCluster of ``workers`` processes with
    one thread each; scheduler, workers and the HTTP endpoint on 127.0.0.1 (a free port)."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    env = {'OPENBLAS_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1'}
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host=HOST,
                      dashboard_address=f'{HOST}:0', silence_logs=40, env=env) as cluster, \
            Client(cluster) as client:
        yield client


def _reference(con: duckdb.DuckDBPyConnection, line: str, track: str, dx: float
               ) -> Reference | None:
    """The line's fused profile, else its reference pass; None for a new line."""
    cols = db.fetch(con, 'SELECT cell, u_m FROM fused WHERE line = ? AND track = ? ORDER BY cell',
                    [line, track])
    valid = np.ones(cols['cell'].size, bool)
    if cols['cell'].size == 0:
        cols = db.fetch(con, """SELECT pr.cell, pr.u_m, pr.valid FROM profiles pr
                                JOIN lines l ON pr.pass_id = l.reference_pass
                                WHERE l.line = ? AND l.track = ? ORDER BY pr.cell""",
                        [line, track])
        if cols['cell'].size == 0:
            return None
        valid = cols['valid']
    first = int(cols['cell'][0])
    u = np.zeros(int(cols['cell'][-1]) - first + 1)
    ok = np.zeros(u.size, bool)
    u[cols['cell'] - first] = cols['u_m']
    ok[cols['cell'] - first] = valid
    return Reference(first, u, ok, dx)


def _pass_row(con: duckdb.DuckDBPyConnection, bag: str, options: PassOptions, status: str,
              message: str, result: PassResult | None = None,
              alignment: Alignment | None = None, digest: str | None = None) -> int:
    """Insert the passes row (``digest``: of the bag's content); returns its id."""
    (pid,) = con.execute("SELECT nextval('pass_ids')").fetchone() or (None,)
    o = options
    values = [pid, bag, o.line, o.track, o.direction, None, None, o.vehicle_id, None, None, None,
              None, None, None, None, None, None, None, status, message, datetime.now(), digest]
    if result is not None:
        speed = np.abs(result.speed_mps)
        values[5:16] = [db.timestamp(result.start_ns), db.timestamp(result.end_ns), o.vehicle_id,
                        float(speed.min()), float(speed.mean()), float(speed.max()),
                        result.samples, result.duration_s, result.rate_hz, result.cpu_s,
                        abs(alignment.scale) if alignment is not None else None]
    con.execute(f'INSERT INTO passes VALUES ({", ".join("?" * len(values))})', values)
    return int(pid)


def _align(ref: Reference | None, result: PassResult, geometry: Line | None,
           frame: str | None, frame_cov: np.ndarray | None) -> Alignment | None:
    """GNSS (when the pass has fixes, the line a geometry and a GNSS frame), refined by
    cross-correlation against the reference (searched around the GNSS position, or over the
    whole reference without it; ``frame_cov``, the covariance of the reference pass's own
    alignment, is added); the GNSS alignment alone when the profiles do not match."""
    o = result.options
    gnss = None
    if geometry is not None and len(result.fixes) and frame in (None, 'gnss'):
        ok = result.valid  # invalid cells (dropouts, too slow) carry the pass start as stamp
        gnss = align_fixes(result.fixes, result.stamps_ns[ok], result.s_m[ok], geometry)
    prior = gnss or origin(1000.0 * o.km_origin, o.direction)
    if ref is None:
        return prior
    search = None if gnss is None else float(4 * gnss.position_sd(result.s_m).max() + 10.0)
    found = xcorr_align(ref, result.s_m, result.u_m, result.valid, prior, search)
    if found is None or frame_cov is None:
        return found or gnss
    # placed in the frame of the line's reference pass: its own uncertainty comes along
    return replace(found, cov=found.cov + frame_cov)


def store_pass(con: duckdb.DuckDBPyConnection, result: PassResult,
               geometry: Line | None = None, digest: str | None = None) -> Outcome:
    """Align one pass against its line, write its rows (``digest``: of the bag's content);
    status 'ok' or 'unaligned'."""
    o, dx = result.options, result.options.dx_m
    ref = _reference(con, o.line, o.track, dx)
    row = con.execute("""SELECT l.frame, a.offset_sd_m, a.scale_sd, a.cov_offset_scale
                         FROM lines l JOIN alignments a ON a.pass_id = l.reference_pass
                         WHERE l.line = ? AND l.track = ?""", [o.line, o.track]).fetchone()
    frame_cov = None
    if row is not None and row[0] == 'gnss':
        frame_cov = np.array([[row[1] ** 2, row[3]], [row[3], row[2] ** 2]])
    alignment = _align(ref, result, geometry, row[0] if row else None, frame_cov)
    if alignment is None:
        pid = _pass_row(con, result.bag, o, 'unaligned',
                        "no stretch matches the line's profile (correlation below 0.6)", result,
                        digest=digest)
        return Outcome(result.bag, pid, 'unaligned', 'not aligned: no match with the line')
    pid = _pass_row(con, result.bag, o, 'ok', '', result, alignment, digest)
    if ref is None:
        con.execute('INSERT INTO lines VALUES (?, ?, ?, ?, ?, ?, ?)',
                    [o.line, o.track, dx, o.config.inversion.band, pid,
                     'gnss' if alignment.method == 'gnss' else 'odometry',
                     None if geometry is None else geometry_json(geometry)])
    cells, (u, stamps, speed), valid = on_line_grid(
        result.s_m, (result.u_m, result.stamps_ns, result.speed_mps), result.valid, alignment, dx)
    db.insert_columns(con, 'profiles', {
        'pass_id': np.full(cells.size, pid, np.int32), 'cell': cells, 'u_m': u, 'valid': valid,
        'stamp_ns': stamps.astype(np.int64), 'speed_mps': speed})
    x = cells * dx
    sd = alignment.position_sd(result.s_m)
    con.execute('INSERT INTO alignments VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)',
                [pid, alignment.method, alignment.offset_m, alignment.scale,
                 alignment.offset_sd_m, alignment.scale_sd, float(alignment.cov[0, 1]),
                 alignment.correlation, alignment.windows, float(x[0]), float(x[-1]),
                 float(sd.max())])
    sec = section_sd(x[valid], u[valid], speed[valid])
    db.insert_columns(con, 'segments', {
        'pass_id': np.full(len(sec), pid, np.int32), 'start_m': sec.start_m, 'sd_m': sec.sd_m,
        'coverage': sec.coverage, 'speed_mps': sec.speed_mps})
    return Outcome(result.bag, pid, 'ok', f'{alignment.method}, scale {alignment.scale:.5f}, '
                                          f'+-{sd.max():.2f} m')


def _one_line(exc: BaseException) -> str:
    """Type and first line of an unexpected exception."""
    text = str(exc).strip()
    return f'{type(exc).__name__}: {text.splitlines()[0]}' if text else type(exc).__name__


def _geometry(con: duckdb.DuckDBPyConnection, options: PassOptions,
              given: Line | None) -> Line | None:
    """The line geometry: the one given (stored for the line if it has none yet), else the
    stored one, else None."""
    key = [options.line, options.track]
    row = con.execute('SELECT geometry FROM lines WHERE line = ? AND track = ?', key).fetchone()
    if given is not None:
        if row is not None and row[0] is None:
            con.execute('UPDATE lines SET geometry = ? WHERE line = ? AND track = ?',
                        [geometry_json(given), *key])
        return given
    return line_from_json(row[0]) if row and row[0] else None


def _new_bags(con: duckdb.DuckDBPyConnection, names: Sequence[str]
              ) -> tuple[list[Outcome], dict[str, str | None]]:
    """(skipped, to do) of resolved bag paths: a bag is skipped when an 'ok' pass has its path
    or its content (``bag.digest``: a copy under another path or name, also of another bag of
    the batch); the others map to their digest (None when unreadable: the worker reports
    why)."""
    done = {bag for (bag,) in con.execute(
        "SELECT bag FROM passes WHERE status = 'ok'").fetchall()}
    seen = {digest: f'pass {pid} ({bag})' for digest, pid, bag in con.execute(
        "SELECT digest, min(pass_id), arg_min(bag, pass_id) FROM passes "
        "WHERE status = 'ok' AND digest IS NOT NULL GROUP BY digest").fetchall()}
    skipped, todo = [], {}
    for bag in names:
        if bag in done:
            skipped.append(Outcome(bag, None, 'skipped', 'already in the database'))
        elif bag not in todo:
            digest = _digest(bag)
            if digest in seen:
                skipped.append(Outcome(bag, None, 'skipped', f'same content as {seen[digest]}: '
                                                             'a copy, not ingested again'))
                continue
            todo[bag] = digest
            if digest is not None:
                seen[digest] = f'{bag} of this batch'
    return skipped, todo


def _digest(bag: str) -> str | None:
    """The bag's content digest; None when it cannot be read."""
    try:
        return bag_digest(bag)
    except RailGsaError:
        return None


def ingest(bags: Sequence[str | Path], db_path: str | Path, options: PassOptions,
           scheduler: str | None = None, workers: int = 2,
           report: Callable[[Outcome], None] | None = None,
           geometry: Line | None = None) -> list[Outcome]:
    """Ingest ``bags`` (module docstring); ``report(outcome)`` as each bag is done;
    ``geometry``: the line's ``geo.Line`` for GNSS anchoring (else the one stored)."""
    con = db.connect(db_path)
    try:
        geometry = _geometry(con, options, geometry)
        outcomes, todo = _new_bags(con, [str(Path(b).resolve()) for b in bags])
        if not todo:
            repaired = _repair(con, options, geometry)
            return outcomes + ([repaired] if repaired is not None else [])
        with dask_client(scheduler, workers) as client:
            futures = client.map(analyse_or_fail, list(todo), options=options, pure=False,
                                 retries=RETRIES)
            for bag, future in zip(todo, futures, strict=True):
                try:
                    result = future.result()
                except Exception as exc:  # failed after Dask's retries: recorded, batch goes on
                    result = PassFailure(bag, _one_line(exc))
                if isinstance(result, PassFailure):
                    pid = _pass_row(con, bag, options, 'failed', result.message,
                                    digest=todo[bag])
                    outcome = Outcome(bag, pid, 'failed', result.message)
                else:
                    with db.transaction(con):
                        outcome = store_pass(con, result, geometry, todo[bag])
                future.release()
                outcomes.append(outcome)
                if report is not None:
                    report(outcome)
        _update(con, options, geometry)
    finally:
        con.close()
    return outcomes


def _update(con: duckdb.DuckDBPyConnection, options: PassOptions, geometry: Line | None) -> None:
    """Recompute the line of ``options`` in one transaction."""
    with db.transaction(con):
        update_line(con, options.line, options.track, options.dx_m,
                    Limits(options.limits or en13848_table(), options.config.inversion.band,
                           options.line_speed), geometry,
                    options.detect_fraction)


def _repair(con: duckdb.DuckDBPyConnection, options: PassOptions,
            geometry: Line | None) -> Outcome | None:
    """Rebuild the line of ``options`` when its condition is not computed from the passes it
    holds (``condition.is_current``); the outcome saying so, None when it was current."""
    if is_current(con, options.line, options.track):
        return None
    _update(con, options, geometry)
    name = f'line {options.line} track {options.track}'
    return Outcome(name, None, 'repaired', f'{name}: its last update did not finish; fused '
                   f'profile and defects rebuilt from its '
                   f'{ok_passes(con, options.line, options.track)[0]} stored passes')
