"""A series of simulated passes over one line: growing defects, a new defect, varied trains.

Every pass runs over the SAME track (one line seed, ``track.line_profile``) and the same line
geometry (``geo.default_line``), on its own date, with its own start position, speed (a cruise
with ripple, every ``stop_every``-th pass with a stop and restart), vehicle (parameters drawn
within +-``vehicle_spread``), wheel-diameter error and sensor/GNSS noise. Everything is drawn
from one seed. Defects may grow between dates and appear from a given pass on; see
``parse_growing_defects``. ``plan_series`` returns, per pass, the run's parameters and its truth
(dates, defect positions in km and WGS84, depths, odometry scale). Units: m, s, m/s, days.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
import math
import re
from typing import Any

import numpy as np

from railgsa_ros.errors import ConfigError
from railgsa_ros.geo import Line
from railgsa_ros.speed_profile import parse_speed_profile
from railgsa_ros.track import MAX_DEFECT_SIZE_M, Defect, parse_defects
from railgsa_ros.vehicle import VehicleParams

DAY_S = 86400.0
BRAKE_MPS2 = 0.7  # service braking and acceleration of the stop-and-restart passes
STOP_S = 20.0
STOP_CLEARANCE_M = 150.0  # a stop keeps this far from every defect (and the section ends)
RIPPLE_MPS = 0.3
_SERIES_KEYS = ('growth', 'depths', 'from')


@dataclass(frozen=True)
class GrowingDefect:
    """A defect of the series: its shape at the first pass, growth of its depth (or corrugation
    amplitude) in m/day or explicit sizes per pass, and the first pass (1-based) it exists in."""

    defect: Defect
    growth_m_per_day: float = 0.0
    sizes_m: tuple[float, ...] | None = None
    first_pass: int = 1

    def size_at(self, index: int, days: float) -> float:
        """Depth (amplitude for corrugation) in m at pass ``index`` (0-based), ``days`` after
        the first pass of the series."""
        if self.sizes_m is not None:
            return self.sizes_m[index]
        base = self.defect.amplitude if self.defect.kind == 'corrugation' else self.defect.depth
        return base + self.growth_m_per_day * days

    def at(self, index: int, days: float) -> Defect | None:
        """The defect as it is at pass ``index`` (None before it appears)."""
        if index + 1 < self.first_pass:
            return None
        size = self.size_at(index, days)
        key = 'amplitude' if self.defect.kind == 'corrugation' else 'depth'
        sized: dict[str, Any] = {key: size}
        return replace(self.defect, **sized)

    @property
    def centre_m(self) -> float:
        """Chainage of the defect's middle (the deepest point of a dip), m."""
        return self.defect.start + 0.5 * self.defect.length


def parse_growing_defects(spec: str, n_passes: int) -> list[GrowingDefect]:
    """Defects spec of ``track.parse_defects`` with three more keys per token:
    ``growth=M_PER_DAY`` (depth or amplitude growth, linear in the date), ``depths=A/B/...``
    (one size in m per pass, instead of growth) and ``from=K`` (appears from pass K on,
    1-based). E.g. ``dip@600:len=8:depth=7e-3:growth=4e-5,dip@1400:len=6:depth=7e-3:from=3``.
    """
    out = []
    for token in (spec or '').split(','):
        if not token.strip():
            continue
        parts = token.split(':')
        extra = {}
        for item in parts[1:]:
            key, _, value = item.partition('=')
            if key.strip() in _SERIES_KEYS:
                extra[key.strip()] = value.strip()
        base = ':'.join([parts[0]] + [p for p in parts[1:]
                                      if p.partition('=')[0].strip() not in _SERIES_KEYS])
        (defect,) = parse_defects(base)
        out.append(_growing(token.strip(), defect, extra, n_passes))
    return out


def _growing(token: str, defect: Defect, extra: dict[str, str], n_passes: int
             ) -> GrowingDefect:
    """GrowingDefect from the series keys of one token; ConfigError naming the token."""
    if 'growth' in extra and 'depths' in extra:
        raise ConfigError(f'defects: {token!r}: give growth= or depths=, not both')
    try:
        growth = float(extra.get('growth', 0.0))
        sizes = tuple(float(v) for v in extra['depths'].split('/')) if 'depths' in extra \
            else None
        first = int(extra.get('from', 1))
    except ValueError:
        raise ConfigError(f'defects: {token!r}: growth, depths (A/B/...) and from must be '
                          f'numbers') from None
    if not math.isfinite(growth):
        raise ConfigError(f'defects: {token!r}: growth must be finite (m/day)')
    if sizes is not None and len(sizes) != n_passes:
        raise ConfigError(f'defects: {token!r}: depths= gives {len(sizes)} sizes for '
                          f'{n_passes} passes')
    if not 1 <= first <= n_passes:
        raise ConfigError(f'defects: {token!r}: from= must be a pass number 1..{n_passes}')
    if sizes is not None and not all(0 < s <= MAX_DEFECT_SIZE_M for s in sizes):
        raise ConfigError(f'defects: {token!r}: depths must be in (0, {MAX_DEFECT_SIZE_M}] m')
    return GrowingDefect(defect, growth, sizes, first)


@dataclass(frozen=True)
class SeriesSpec:
    """What varies over the series and how much (see the module docstring)."""

    n_passes: int
    section_m: tuple[float, float]  # chainage span every pass covers, m
    defects: list[GrowingDefect]
    first_date: datetime = datetime(2024, 1, 8, tzinfo=UTC)
    days_between: float = 7.0
    speed_range_mps: tuple[float, float] = (15.0, 30.0)
    start_spread_m: float = 200.0  # passes start up to this far before the section
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    vehicle_spread: float = 0.03
    odom_error_max: float = 0.005
    stop_every: int = 3  # every k-th pass stops once (0: never)
    seed: int = 0

    def __post_init__(self) -> None:
        lo, hi = self.section_m
        checks = {
            'passes': self.n_passes >= 1,
            'section': math.isfinite(lo) and math.isfinite(hi) and lo >= 0 and hi > lo,
            'days between': math.isfinite(self.days_between) and self.days_between > 0,
            'speed range': 3.0 <= self.speed_range_mps[0] <= self.speed_range_mps[1] < 100.0,
            'start spread': math.isfinite(self.start_spread_m) and self.start_spread_m >= 0,
            'vehicle spread': 0 <= self.vehicle_spread < 0.5,
            'odometry error': 0 <= self.odom_error_max < 0.1,
            'stop every': self.stop_every >= 0,
        }
        for name, ok in checks.items():
            if not ok:
                raise ConfigError(f'pass series: invalid {name}')
        for d in self.defects:
            if not (lo <= d.defect.start and d.defect.start + d.defect.length <= hi):
                raise ConfigError(f'pass series: a defect at {d.defect.start:g} m lies outside '
                                  f'the section {lo:g}-{hi:g} m')


@dataclass(frozen=True)
class PassPlan:
    """One pass: its run parameters and its truth."""

    index: int  # 0-based
    start_time_s: float  # stamp of the first sample, s since the epoch
    days: float  # since the first pass's start (fractional: the stamps' time)
    start_m: float
    speed_profile: str
    duration_s: float
    vehicle: VehicleParams
    odom_scale_error: float
    seed: int
    defects: list[tuple[GrowingDefect, Defect]]  # the defects present, as they are now

    @property
    def end_m(self) -> float:
        """Chainage at the end of the pass, m."""
        return self.start_m + parse_speed_profile(self.speed_profile).distance_m

    @property
    def defect_spec(self) -> str:
        """The present defects as a ``track.parse_defects`` spec."""
        return ','.join(_spec_token(d) for _, d in self.defects)

    def truth(self, line: Line, spec: SeriesSpec) -> dict[str, Any]:
        """The pass's truth as a JSON-ready dict (see docs/simulation.md)."""
        date = datetime.fromtimestamp(self.start_time_s, UTC)
        entries = []
        for k, grow in enumerate(spec.defects):
            present = next((d for g, d in self.defects if g is grow), None)
            lat, lon = line.position(np.array([grow.centre_m]))
            size = grow.size_at(self.index, self.days)
            entries.append({
                'id': k, 'kind': grow.defect.kind, 'start_m': grow.defect.start,
                'length_m': grow.defect.length, 'centre_m': grow.centre_m,
                'centre_km': grow.centre_m / 1e3, 'lat_deg': float(lat[0]),
                'lon_deg': float(lon[0]), 'present': present is not None,
                'depth_m': size if present is not None else 0.0,
                'new': present is not None and grow.first_pass == self.index + 1
                and self.index > 0,
                'first_pass': grow.first_pass, 'growth_m_per_day': grow.growth_m_per_day})
        return {
            'pass': self.index + 1, 'date': date.isoformat(), 'days': self.days,
            'start_time_s': self.start_time_s, 'line_id': line.line_id,
            'start_m': self.start_m, 'start_km': self.start_m / 1e3,
            'end_m': self.end_m,
            'speed_profile': self.speed_profile, 'duration_s': self.duration_s,
            'odom_scale_error': self.odom_scale_error,
            'odom_scale': 1.0 + self.odom_scale_error, 'vehicle': self.vehicle.as_dict(),
            'seed': self.seed, 'defects': entries}


def _spec_token(d: Defect) -> str:
    """A Defect back as a spec token (full precision)."""
    start, length = float(d.start), float(d.length)
    if d.kind == 'corrugation':
        return (f'corrugation@{start!r}:len={length!r}:wl={float(d.wavelength)!r}:'
                f'amp={float(d.amplitude)!r}')
    return f'{d.kind}@{start!r}:len={length!r}:depth={float(d.depth)!r}'


def _speed_profile(distance_m: float, v: float, stop_at_m: float | None) -> str:
    """A cruise at v (m/s) with ripple over distance_m; with a stop centred at stop_at_m
    (braking and restart at BRAKE_MPS2, STOP_S standing)."""
    ripple = min(RIPPLE_MPS, 0.1 * v)
    if stop_at_m is None:
        return f'cruise:{v!r}:{distance_m / v!r}s:ripple={ripple!r}'
    ramp_s = v / BRAKE_MPS2
    ramp_m = 0.5 * v * ramp_s
    before = stop_at_m - ramp_m
    after = distance_m - stop_at_m - ramp_m
    return (f'cruise:{v!r}:{before / v!r}s:ripple={ripple!r},brake:{v!r}-0:{ramp_s!r}s,'
            f'stop:{STOP_S!r}s,accel:0-{v!r}:{ramp_s!r}s,cruise:{v!r}:{after / v!r}s')


def _stop_position(spec: SeriesSpec, start: float, end: float, v: float,
                   rng: np.random.Generator) -> float | None:
    """A stop position (m from the pass start) clear of the defects by STOP_CLEARANCE_M plus
    the braking distance, or None when the section has no room."""
    ramp_m = 0.5 * v * v / BRAKE_MPS2
    margin = STOP_CLEARANCE_M + ramp_m
    keep_out = [(d.defect.start - margin, d.defect.start + d.defect.length + margin)
                for d in spec.defects]
    grid = np.arange(start + margin, end - margin, 10.0)
    ok = np.ones(grid.size, bool)
    for lo, hi in keep_out:
        ok &= (grid < lo) | (grid > hi)
    if not ok.any():
        return None
    return float(rng.choice(grid[ok])) - start


def plan_series(spec: SeriesSpec) -> list[PassPlan]:
    """Every pass of the series (deterministic in ``spec.seed``)."""
    rng = np.random.default_rng([spec.seed, 0x9A55])
    lo, hi = spec.section_m
    base = spec.first_date.timestamp()
    theta0 = spec.vehicle.as_array()
    # every pass on its day, between 05:00 and 20:00 UTC
    starts = base + (np.arange(spec.n_passes) * spec.days_between
                     + rng.uniform(5, 20, spec.n_passes) / 24.0) * DAY_S
    plans = []
    for i in range(spec.n_passes):
        start_time = float(starts[i])
        days = float(starts[i] - starts[0]) / DAY_S  # exact: the defects grow with the stamps
        start = max(0.0, lo - float(rng.uniform(0.0, spec.start_spread_m)))
        v = float(rng.uniform(*spec.speed_range_mps))
        end = hi + float(rng.uniform(20.0, 100.0))  # run on past the section
        stop = _stop_position(spec, start, end, v, rng) \
            if spec.stop_every and (i + 1) % spec.stop_every == 0 else None
        profile = _speed_profile(end - start, v, stop)
        vehicle = VehicleParams(*(theta0 * (1 + rng.uniform(-1, 1, 5) * spec.vehicle_spread)))
        odom = float(rng.uniform(-1, 1) * spec.odom_error_max)
        present = [(g, d) for g in spec.defects
                   if (d := g.at(i, days)) is not None]
        for g, d in present:
            size = d.amplitude if d.kind == 'corrugation' else d.depth
            if not 0 < size <= MAX_DEFECT_SIZE_M:
                raise ConfigError(f'pass series: the defect at {g.defect.start:g} m reaches '
                                  f'{size:g} m at pass {i + 1}; sizes must stay in '
                                  f'(0, {MAX_DEFECT_SIZE_M}] m')
        plans.append(PassPlan(i, start_time, days, start, profile,
                              parse_speed_profile(profile).duration_s, vehicle, odom,
                              int(rng.integers(0, 2**31)), present))
    return plans


def parse_range(text: str, what: str) -> tuple[float, float]:
    """'A-B' (or one number) -> (A, B); ConfigError naming ``what``."""
    match = re.fullmatch(r'\s*([0-9.eE+]+)\s*(?:-\s*([0-9.eE+]+)\s*)?', text or '')
    try:
        if match is None:
            raise ValueError(text)
        lo = float(match.group(1))
        hi = float(match.group(2) or match.group(1))
    except ValueError:
        raise ConfigError(f'{what}: expected A-B or a number, got {text!r}') from None
    if not lo <= hi:
        raise ConfigError(f'{what}: expected A <= B, got {text!r}')
    return lo, hi
