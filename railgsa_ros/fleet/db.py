"""The track condition database (DuckDB, one file): schema, connection, small helpers.

One writer at a time (DuckDB is single-writer): the ingest client writes, Dask workers never
touch the file. Tables (docs/fleet.md has the columns and units):

- ``passes``: one row per bag (status ``ok``, ``unaligned`` or ``failed`` with its message,
  the digest of its content: ``bag.digest``);
- ``alignments``: offset, scale and their covariance, method and correlation per pass;
- ``lines``: one row per (line, track): grid step, band, reference pass, frame ('gnss': the
  chainage of the line geometry; 'odometry': the first pass's odometry) and geometry (JSON);
- ``profiles``: each pass on its line's common grid (cell * dx_m = line chainage, m);
- ``fused``: the fused profile per line with its standard deviation and pass count;
- ``segments``: SD of the band-filtered profile per 200 m section per pass;
- ``detections``: defects found in each pass (or measured there for a defect found elsewhere);
- ``defects``: one row per defect followed over passes, with its trend and projected limit date;
- ``line_updates``: per line, the 'ok' passes (count, last id) its condition was last computed
  from: a line whose passes differ was cut short by a crash and is rebuilt (``ingest``).

Each pass and each line update is one transaction: a process killed in the middle leaves the
database as it was before that step.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

import duckdb
import numpy as np

from railgsa_ros.errors import InputError

SCHEMA = """
CREATE SEQUENCE IF NOT EXISTS pass_ids START 1;
CREATE TABLE IF NOT EXISTS passes (
    pass_id INTEGER PRIMARY KEY, bag VARCHAR, line VARCHAR, track VARCHAR, direction VARCHAR,
    start_time TIMESTAMP, end_time TIMESTAMP, vehicle VARCHAR, speed_min_mps DOUBLE,
    speed_mean_mps DOUBLE, speed_max_mps DOUBLE, samples BIGINT, duration_s DOUBLE,
    rate_hz DOUBLE, cpu_s DOUBLE, odometry_scale DOUBLE, noise_m DOUBLE, gain DOUBLE,
    status VARCHAR, message VARCHAR, ingested_at TIMESTAMP);
CREATE TABLE IF NOT EXISTS alignments (
    pass_id INTEGER PRIMARY KEY, method VARCHAR, offset_m DOUBLE, scale DOUBLE,
    offset_sd_m DOUBLE, scale_sd DOUBLE, cov_offset_scale DOUBLE, correlation DOUBLE,
    windows INTEGER, start_m DOUBLE, end_m DOUBLE, position_sd_m DOUBLE);
CREATE TABLE IF NOT EXISTS lines (
    line VARCHAR, track VARCHAR, dx_m DOUBLE, band VARCHAR, reference_pass INTEGER,
    frame VARCHAR, geometry VARCHAR, PRIMARY KEY (line, track));
CREATE TABLE IF NOT EXISTS profiles (
    pass_id INTEGER, cell BIGINT, u_m DOUBLE, valid BOOLEAN, stamp_ns BIGINT, speed_mps DOUBLE);
CREATE TABLE IF NOT EXISTS fused (
    line VARCHAR, track VARCHAR, cell BIGINT, u_m DOUBLE, sd_m DOUBLE, passes INTEGER);
CREATE TABLE IF NOT EXISTS segments (
    pass_id INTEGER, start_m DOUBLE, sd_m DOUBLE, coverage DOUBLE, speed_mps DOUBLE);
CREATE TABLE IF NOT EXISTS detections (
    pass_id INTEGER, line VARCHAR, track VARCHAR, defect_id INTEGER, x_m DOUBLE, x_sd_m DOUBLE,
    depth_m DOUBLE, depth_sd_m DOUBLE, signed_m DOUBLE, speed_kmh DOUBLE, time TIMESTAMP,
    level VARCHAR, detected BOOLEAN);
CREATE TABLE IF NOT EXISTS defects (
    line VARCHAR, track VARCHAR, defect_id INTEGER, x_m DOUBLE, km DOUBLE, x_sd_m DOUBLE,
    sign INTEGER, first_seen TIMESTAMP, last_seen TIMESTAMP, passes INTEGER, new BOOLEAN,
    depth_m DOUBLE, depth_sd_m DOUBLE, rate_mm_per_year DOUBLE, rate_se_mm_per_year DOUBLE,
    speed_kmh DOUBLE, level VARCHAR, next_level VARCHAR, next_limit_m DOUBLE,
    projected DATE, projected_early DATE, projected_late DATE, lat DOUBLE, lon DOUBLE);
ALTER TABLE passes ADD COLUMN IF NOT EXISTS digest VARCHAR;
CREATE TABLE IF NOT EXISTS line_updates (
    line VARCHAR, track VARCHAR, passes INTEGER, last_pass INTEGER, PRIMARY KEY (line, track));
"""


def connect(path: str | Path, read_only: bool = False) -> duckdb.DuckDBPyConnection:
    """Open (and, for writing, create) the database; InputError naming the file otherwise."""
    path = Path(path)
    if read_only and not path.exists():
        raise InputError(f'{path}: no such database (run railgsa fleet ingest first)')
    try:
        con = duckdb.connect(str(path), read_only=read_only)
    except (duckdb.IOException, duckdb.Error) as exc:
        raise InputError(f'{path}: cannot open the database: {exc}'.splitlines()[0]) from None
    if not read_only:
        con.execute(SCHEMA)
    return con


@contextmanager
def transaction(con: duckdb.DuckDBPyConnection) -> Iterator[None]:
    """The block as one transaction: committed at its end, rolled back on an exception (and by
    DuckDB's recovery when the process dies inside it)."""
    con.begin()
    try:
        yield
    except BaseException:
        con.rollback()
        raise
    con.commit()


@contextmanager
def damage_named(path: str | Path) -> Iterator[None]:
    """DuckDB errors inside the block as one InputError naming the database: a corrupt block
    (checksum), an I/O error; errors in our own SQL (``duckdb.ProgrammingError``) pass."""
    try:
        yield
    except duckdb.ProgrammingError:
        raise
    except duckdb.Error as exc:
        text = ' '.join(str(exc).split())
        raise InputError(f'{path}: damaged database ({text[:160]}); restore it from a backup or '
                         're-ingest its bags into a new file') from None


def timestamp(stamp_ns: float) -> datetime:
    """UTC time (naive, as DuckDB TIMESTAMP) of a stamp in ns."""
    return datetime.fromtimestamp(float(stamp_ns) * 1e-9, UTC).replace(tzinfo=None)


def insert_columns(con: duckdb.DuckDBPyConnection, table: str,
                   columns: dict[str, np.ndarray]) -> None:
    """Append equal-length numpy columns (named as the table's columns) to ``table``."""
    con.register('_rows', columns)
    try:
        names = ', '.join(columns)
        con.execute(f'INSERT INTO {table} ({names}) SELECT {names} FROM _rows')
    finally:
        con.unregister('_rows')


def fetch(con: duckdb.DuckDBPyConnection, sql: str, params: list | None = None
          ) -> dict[str, np.ndarray]:
    """Columns of a query as numpy arrays."""
    return con.execute(sql, params or []).fetchnumpy()
