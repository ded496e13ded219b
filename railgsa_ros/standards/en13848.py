"""EN 13848 wavelength bands and the EN 13848-5 quality levels of isolated defects, as the
infrastructure manager applies them: a limit table per speed range, the line's permitted speed.

Values: EN 13848-5:2008+A1:2010 as commonly reproduced in secondary sources, NOT checked against
the standard's text (docs/review.md, tag [M]). Isolated defects are mean-to-peak values of the
band-filtered signal (D1: 3-25 m, D2: 25-70 m). The standard gives ranges for the alert (AL) and
intervention (IL) limits, within which the infrastructure manager chooses; the immediate-action
limit (IAL) is one value. The 200 m standard deviations are the informative annex's AL range for
D1. ``en13848_table`` is the standard's table at one end of its ranges (the default);
``load_limit_table`` reads a manager's table (config/limits_en13848.yaml documents the schema).

Speed ranges by their upper bound in km/h: v <= 80, 80 < v <= 120, ..., 230 < v <= 300; above
the last bound the table does not apply (no limits). EN 13848-5 classes a place by the line's
permitted speed there (``line_speed.LineSpeed``); without it a place is classed by the measuring
train's speed (``MEASURING_BASIS``), which is lower or equal and so never stricter.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from railgsa_ros.config import key_list, load_yaml
from railgsa_ros.errors import ConfigError
from railgsa_ros.standards.line_speed import LineSpeed

BANDS_M = {'d1': (3.0, 25.0), 'd2': (25.0, 70.0), 'd3': (70.0, 200.0)}  # wavelengths, m
SOURCE = ('EN 13848-5:2008+A1:2010 as reproduced in secondary sources, not checked against the '
          'standard text [M]')
LEVELS = ('AL', 'IL', 'IAL')  # alert, intervention, immediate action, in rising severity
ENDS = ('lower', 'upper')
MEASURING_BASIS = 'class by measuring speed (no --line-speed given)'
MM = 1e-3
NAN = float('nan')

_UPPER_KMH = (80.0, 120.0, 160.0, 230.0, 300.0)
# D1 isolated defects, mm: (AL range, IL range, IAL) per speed range [M]
_D1_MM = (((12, 18), (17, 21), 28), ((8, 12), (10, 17), 26), ((6, 10), (8, 14), 23),
          ((5, 9), (7, 12), 20), ((4, 8), (6, 10), 16))
# D2: IAL only above 160 km/h [M]; no AL/IL in the table
_D2_IAL_MM = (NAN, NAN, NAN, 33.0, 28.0)
# D1 standard deviation over 200 m, AL range in mm (informative annex) [M]
_SD_MM = ((2.3, 3.0), (1.8, 2.7), (1.4, 2.4), (1.2, 1.9), (1.0, 1.5))


@dataclass(frozen=True)
class LimitTable:
    """A limit table: upper bounds (C,) km/h of the speed ranges, per band the isolated-defect
    limits (C, 3) m (AL, IL, IAL; NaN where the table has none) and the 200 m SD alert range
    (C, 2) m (NaN without), and a name saying where it comes from."""

    name: str
    upper_kmh: np.ndarray
    isolated_m: Mapping[str, np.ndarray]
    sd_range_m: Mapping[str, np.ndarray]

    def index(self, speed_kmh: np.ndarray) -> np.ndarray:
        """Speed range index per speed (km/h, sign ignored): 0..C-1, -1 above the last bound or
        not finite."""
        kmh = np.round(np.abs(np.asarray(speed_kmh, dtype=float)), 6)  # 120 / 3.6 * 3.6 > 120
        idx = np.searchsorted(self.upper_kmh, kmh, side='left')
        return np.where((idx < self.upper_kmh.size) & np.isfinite(kmh), idx, -1)

    def label(self, index: int) -> str:
        """'v <= 80 km/h', '80 < v <= 120 km/h', ... or 'v > 300 km/h' (index -1)."""
        top = self.upper_kmh
        if index < 0 or index >= top.size:
            return f'v > {top[-1]:g} km/h'
        return f'v <= {top[0]:g} km/h' if index == 0 else \
            f'{top[index - 1]:g} < v <= {top[index]:g} km/h'

    def rows(self, band: str) -> tuple[np.ndarray, np.ndarray]:
        """(isolated (C, 3), SD range (C, 2)) m of ``band``; ConfigError for a band the table
        has no limits for."""
        if band not in self.isolated_m:
            raise ConfigError(f'band: the limit table {self.name!r} has limits for '
                              f'{", ".join(self.isolated_m) or "no band"}, not {band!r}')
        return self.isolated_m[band], self.sd_range_m[band]

    def thresholds(self, band: str, speed_kmh: np.ndarray) -> np.ndarray:
        """AL, IL, IAL (K, 3) m at speeds (K,) km/h; NaN rows beyond the table."""
        isolated = self.rows(band)[0]
        return np.vstack([isolated, np.full((1, 3), NAN)])[self.index(speed_kmh)]

    def sd_ranges(self, band: str, speed_kmh: np.ndarray) -> np.ndarray:
        """200 m SD alert range (S, 2) m at section speeds (S,) km/h; NaN beyond the table."""
        sd = self.rows(band)[1]
        return np.vstack([sd, np.full((1, 2), NAN)])[self.index(speed_kmh)]


def en13848_table(end: str = 'lower') -> LimitTable:
    """The EN 13848-5 table taking the ``end`` ('lower': the strictest value an infrastructure
    manager may choose, the default for screening a reconstruction; 'upper': the most lenient)
    of the AL and IL ranges (D1 and D2)."""
    if end not in ENDS:
        raise ConfigError(f'limit end: expected lower or upper, got {end!r}')
    pick = ENDS.index(end)
    d1 = np.array([[al[pick], il[pick], ial] for al, il, ial in _D1_MM], dtype=float)
    d2 = np.column_stack([np.full(5, NAN), np.full(5, NAN), _D2_IAL_MM])
    return LimitTable(f'EN 13848-5, {end} end of the AL/IL ranges', np.array(_UPPER_KMH),
                      {'d1': d1 * MM, 'd2': d2 * MM},
                      {'d1': np.array(_SD_MM) * MM, 'd2': np.full((5, 2), NAN)})


def level_of(magnitude: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Highest level passed per value (K,): 0 none, 1 AL, 2 IL, 3 IAL, for magnitudes (K,) and
    thresholds (K, 3) in the same unit; a value passes a limit when it is above it (a value
    exactly at a limit has not passed it); NaN limits are never passed."""
    with np.errstate(invalid='ignore'):
        passed = np.asarray(magnitude, dtype=float)[:, None] > thresholds
    return np.max(np.where(passed, np.arange(1, 4), 0), axis=1, initial=0)


def classify(values_mm: np.ndarray, km: np.ndarray, band: str, table: LimitTable,
             speeds: LineSpeed | np.ndarray) -> np.ndarray:
    """EN 13848-5 level per isolated-defect value (K,): 0 none, 1 AL, 2 IL, 3 IAL, for
    mean-to-peak values (K,) mm (sign ignored) at km-posts (K,) km, in ``band`` of ``table``;
    ``speeds``: the line's permitted speed (looked up at km), else the measuring train's speed
    (K,) km/h at each value (``MEASURING_BASIS``). Every class of the review and the fleet
    comes from here."""
    speed = speeds.at(km) if isinstance(speeds, LineSpeed) else np.asarray(speeds, float)
    return level_of(np.abs(np.asarray(values_mm, float)) * MM, table.thresholds(band, speed))


def level_name(level: int) -> str:
    """'AL', 'IL', 'IAL' of a level 1-3, '' for 0."""
    return LEVELS[level - 1] if level > 0 else ''


@dataclass(frozen=True)
class Limits:
    """The limits one band of a table puts on a run or a line: by the line's permitted speed
    when given, else by the measuring speed; positions x (m) on the run map to km-posts by
    ``km_of`` (default x / 1000: a line frame in metres of km-post)."""

    table: LimitTable
    band: str
    line_speed: LineSpeed | None = None
    km_of: Callable[[np.ndarray], np.ndarray] = field(default=lambda x: np.asarray(x) / 1e3)

    def __post_init__(self) -> None:
        self.table.rows(self.band)  # ConfigError now, not at the first sample

    @property
    def basis(self) -> str:
        """What sets the speed range: the line speed file, else ``MEASURING_BASIS``."""
        if self.line_speed is None:
            return MEASURING_BASIS
        return f'class by the line\'s permitted speed ({self.line_speed.name})'

    def speed_kmh(self, x_m: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
        """Speed (K,) km/h that sets the speed range at positions x (K,) m, measured speeds (K,)
        m/s: the line's permitted speed there (NaN outside its km ranges), else |speed|."""
        if self.line_speed is not None:
            return self.line_speed.at(self.km_of(np.asarray(x_m, dtype=float)))
        return np.abs(np.asarray(speed_mps, dtype=float)) * 3.6

    def at(self, x_m: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
        """AL, IL, IAL (K, 3) m at positions (K,) m and measured speeds (K,) m/s."""
        return self.table.thresholds(self.band, self.speed_kmh(x_m, speed_mps))

    def sd_at(self, x_m: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
        """200 m SD alert range (S, 2) m at section centres (S,) m and speeds (S,) m/s."""
        return self.table.sd_ranges(self.band, self.speed_kmh(x_m, speed_mps))

    def classify(self, magnitude_m: np.ndarray, x_m: np.ndarray,
                 speed_mps: np.ndarray) -> np.ndarray:
        """``classify`` of magnitudes (K,) m at positions (K,) m and measured speeds (K,) m/s."""
        speeds = self.line_speed if self.line_speed is not None else \
            self.speed_kmh(x_m, speed_mps)
        return classify(np.asarray(magnitude_m, float) / MM,
                        self.km_of(np.asarray(x_m, float)), self.band, self.table, speeds)


_TABLE_KEYS = {'name', 'speed_ranges'}
_RANGE_KEYS = {'up_to_kmh', *BANDS_M}
_BAND_KEYS = {*LEVELS, 'SD'}


def load_limit_table(path: str | Path) -> LimitTable:
    """A manager's limit table from YAML (schema in config/limits_en13848.yaml): ``name`` and
    ``speed_ranges``, a list of ``{up_to_kmh, d1: {AL, IL, IAL, SD: [lo, hi]}, d2: ...}`` in
    mm, ranges in rising speed, levels optional (no limit) but AL < IL < IAL where given; every
    range gives the same bands. ConfigError naming the file and the field."""
    doc = load_yaml(path)
    where = str(path)
    if not isinstance(doc, dict) or set(doc) - _TABLE_KEYS or 'speed_ranges' not in doc:
        extra = key_list(set(doc) - _TABLE_KEYS) if isinstance(doc, dict) else ''
        raise ConfigError(f'{where}: expected a mapping with name and speed_ranges'
                          + (f' (unknown: {extra})' if extra else ''))
    ranges = doc['speed_ranges']
    if not isinstance(ranges, list) or not ranges:
        raise ConfigError(f'{where}: speed_ranges: expected a non-empty list')
    upper: list[float] = []
    bands: list[str] | None = None
    isolated: dict[str, list[list[float]]] = {}
    sd: dict[str, list[list[float]]] = {}
    for i, entry in enumerate(ranges):
        at = f'{where}: speed_ranges[{i}]'
        if not isinstance(entry, dict) or set(entry) - _RANGE_KEYS or 'up_to_kmh' not in entry:
            extra = key_list(set(entry) - _RANGE_KEYS) if isinstance(entry, dict) else ''
            raise ConfigError(f'{at}: expected up_to_kmh and bands {", ".join(BANDS_M)}'
                              + (f' (unknown: {extra})' if extra else ''))
        top = _number(entry['up_to_kmh'], f'{at}.up_to_kmh')
        if not top > (upper[-1] if upper else 0.0):
            raise ConfigError(f'{at}.up_to_kmh: expected above the previous range '
                              f'({upper[-1] if upper else 0:g} km/h), got {top:g}')
        upper.append(top)
        given = [b for b in BANDS_M if b in entry]
        if bands is None:
            bands = given
        if given != bands or not given:
            raise ConfigError(f'{at}: expected the bands of the first range '
                              f'({", ".join(bands) or "at least one"}), got '
                              f'{", ".join(given) or "none"}')
        for band in given:
            row, span = _band_row(entry[band], f'{at}.{band}')
            isolated.setdefault(band, []).append(row)
            sd.setdefault(band, []).append(span)
    name = doc.get('name', where)
    return LimitTable(str(name), np.array(upper),
                      {b: np.array(v) * MM for b, v in isolated.items()},
                      {b: np.array(v) * MM for b, v in sd.items()})


def _band_row(values: Any, at: str) -> tuple[list[float], list[float]]:
    """(AL, IL, IAL) and the SD range (lo, hi) mm of one band of one range (NaN: none)."""
    if not isinstance(values, dict) or set(values) - _BAND_KEYS:
        extra = key_list(set(values) - _BAND_KEYS) if isinstance(values, dict) else ''
        raise ConfigError(f'{at}: expected a mapping of {", ".join(LEVELS)} and SD in mm'
                          + (f' (unknown: {extra})' if extra else ''))
    row = [NAN if values.get(k) is None else _number(values[k], f'{at}.{k}') for k in LEVELS]
    given = [v for v in row if np.isfinite(v)]
    if any(b <= a for a, b in pairwise(given)):
        raise ConfigError(f'{at}: expected AL < IL < IAL, got '
                          + ', '.join(f'{k} {v:g}' for k, v in zip(LEVELS, row, strict=True)
                                      if np.isfinite(v)))
    span = [NAN, NAN]
    if values.get('SD') is not None:
        sd = values['SD']
        if not isinstance(sd, list) or len(sd) != 2:
            raise ConfigError(f'{at}.SD: expected [lower, upper] mm, got {sd!r}')
        span = [_number(v, f'{at}.SD') for v in sd]
        if span[1] < span[0]:
            raise ConfigError(f'{at}.SD: expected lower <= upper, got {span}')
    return row, span


def _number(value: Any, at: str) -> float:
    """A positive finite number; ConfigError naming the field otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not np.isfinite(value) or value <= 0:
        raise ConfigError(f'{at}: expected a positive number, got {value!r}')
    return float(value)
