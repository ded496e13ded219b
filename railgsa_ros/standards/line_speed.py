"""The line's permitted speed per km range, which sets the EN 13848-5 speed range of a place.

Given by the infrastructure manager as YAML (``ranges: [{from_km, to_km, speed_kmh}, ...]``,
config/line_speed_example.yaml) or CSV (header from_km,to_km,speed_kmh). A range covers
from_km <= km < to_km, the last one also its to_km; ranges are sorted by km and must neither
overlap nor leave a gap (a place without a permitted speed would have no class). Outside the
ranges the speed is NaN: no limits apply there, which the review and the fleet report.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from railgsa_ros.config import load_yaml
from railgsa_ros.errors import ConfigError

COLUMNS = ('from_km', 'to_km', 'speed_kmh')
TOLERANCE_KM = 1e-9  # ends that meet to within a micrometre meet


@dataclass(frozen=True)
class LineSpeed:
    """Contiguous km ranges [from_km (R,), to_km (R,)) in rising km with the permitted speed
    (R,) km/h of each, and the name of the file they came from."""

    from_km: np.ndarray
    to_km: np.ndarray
    speed_kmh: np.ndarray
    name: str = ''

    def at(self, km: np.ndarray) -> np.ndarray:
        """Permitted speed (K,) km/h at km-posts (K,); NaN outside the ranges."""
        k = np.asarray(km, dtype=float)
        idx = np.searchsorted(self.from_km, k, side='right') - 1
        inside = (idx >= 0) & (k <= self.to_km[-1]) & np.isfinite(k)
        return np.where(inside, self.speed_kmh[idx.clip(0)], np.nan)

    @property
    def span_km(self) -> tuple[float, float]:
        """(first, last) km-post the ranges cover."""
        return float(self.from_km[0]), float(self.to_km[-1])


def line_speed(rows: list[tuple[float, float, float]], name: str = '') -> LineSpeed:
    """A LineSpeed of (from_km, to_km, speed_kmh) rows in any order; ConfigError (prefixed
    ``name``) for an empty list, a range not from < to, a speed not positive, a gap or an
    overlap."""
    where = f'{name}: ' if name else ''
    if not rows:
        raise ConfigError(f'{where}no km range')
    table = np.array(sorted(rows), dtype=float)
    lo, hi, speed = table.T
    for a, b, v in table:
        if not (np.isfinite(a) and np.isfinite(b) and a < b):
            raise ConfigError(f'{where}range km {a:g}-{b:g}: expected from_km < to_km')
        if not (np.isfinite(v) and v > 0):
            raise ConfigError(f'{where}range km {a:g}-{b:g}: speed_kmh must be positive, '
                              f'got {v:g}')
    for k in range(1, lo.size):
        if lo[k] < hi[k - 1] - TOLERANCE_KM:
            raise ConfigError(f'{where}ranges km {lo[k - 1]:g}-{hi[k - 1]:g} and '
                              f'{lo[k]:g}-{hi[k]:g} overlap')
        if lo[k] > hi[k - 1] + TOLERANCE_KM:
            raise ConfigError(f'{where}gap between km {hi[k - 1]:g} and {lo[k]:g}: no '
                              'permitted speed there')
    return LineSpeed(lo, hi, speed, name)


def load_line_speed(path: str | Path) -> LineSpeed:
    """The line speed of a YAML (``ranges``) or CSV (``COLUMNS``) file; ConfigError naming the
    file and the field."""
    path = Path(path)
    if path.suffix.lower() == '.csv':
        return line_speed(_csv_rows(path), str(path))
    doc = load_yaml(path)
    ranges = doc.get('ranges') if isinstance(doc, dict) else None
    if not isinstance(ranges, list):
        raise ConfigError(f'{path}: expected a mapping with ranges: a list of '
                          f'{{{", ".join(COLUMNS)}}}')
    rows = []
    for i, entry in enumerate(ranges):
        if not isinstance(entry, dict) or set(entry) != set(COLUMNS):
            raise ConfigError(f'{path}: ranges[{i}]: expected exactly {", ".join(COLUMNS)}, '
                              f'got {entry!r}')
        rows.append(tuple(_number(entry[c], f'{path}: ranges[{i}].{c}') for c in COLUMNS))
    return line_speed(rows, str(path))  # type: ignore[arg-type]


def _csv_rows(path: Path) -> list[tuple[float, float, float]]:
    """(from_km, to_km, speed_kmh) rows of a CSV file with that header."""
    try:
        with path.open(newline='', encoding='utf-8') as f:
            reader = csv.DictReader(f)
            if tuple(reader.fieldnames or ()) != COLUMNS:
                raise ConfigError(f'{path}: expected the header {",".join(COLUMNS)}, got '
                                  f'{",".join(reader.fieldnames or ())}')
            return [(_number(r['from_km'], f'{path}: line {reader.line_num}: from_km'),
                     _number(r['to_km'], f'{path}: line {reader.line_num}: to_km'),
                     _number(r['speed_kmh'], f'{path}: line {reader.line_num}: speed_kmh'))
                    for r in reader]
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read ({exc.strerror or exc})') from None
    except UnicodeDecodeError:
        raise ConfigError(f'{path}: not a UTF-8 text file') from None


def _number(value: Any, at: str) -> float:
    """A finite number (km or km/h); ConfigError naming the field otherwise."""
    try:
        number = float(value) if not isinstance(value, bool) else float('nan')
    except (TypeError, ValueError):
        number = float('nan')
    if not np.isfinite(number):
        raise ConfigError(f'{at}: expected a number, got {value!r}')
    return number
