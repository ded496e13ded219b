"""Named speed profiles of real operation: acceleration, cruise with ripple, braking, standstill.

A profile is a comma-separated list of segments, run one after the other (speeds in m/s,
durations in s, an optional ``s`` suffix allowed):

- ``accel:V0-V1:D`` and ``brake:V0-V1:D``: speed linear from V0 to V1 over D (accel needs
  V1 > V0, brake V1 < V0);
- ``cruise:V:D[:ripple=A][:period=P]``: V + A sin(2 pi n t / D) with n = max(1, round(D / P))
  whole periods (default P = 20 s), so the ripple starts and ends at V and adds no distance;
- ``stop:D``: standstill (v = 0: the chainage does not advance, the IMU still samples).

Each segment must start at the speed the previous one ended with (the first at 0 or any speed),
and the mean acceleration of a ramp must not exceed MAX_ACCEL_MPS2. Presets (``PRESETS``) name
typical runs. Distances are analytic: ``SpeedProfile.distance_m``.
"""

from __future__ import annotations

from dataclasses import dataclass
import itertools
import math
import re

import numpy as np

from railgsa_ros.errors import ConfigError

MAX_ACCEL_MPS2 = 5.0  # far above rail service (about 1 m/s^2) and emergency braking (2.5 m/s^2)
DEFAULT_RIPPLE_PERIOD_S = 20.0
SPEED_TOLERANCE_MPS = 1e-9  # junctions between segments must agree to this

PRESETS = {
    # a regional train between stations: start, cruise, stop for passengers, start again
    'station': 'accel:0-30:40s,cruise:30:120s:ripple=0.5,brake:30-0:30s,stop:30s,'
               'accel:0-30:40s,cruise:30:60s',
    # congested running: short hops with standstills
    'stop-and-go': 'accel:0-15:20s,cruise:15:30s:ripple=0.3,brake:15-0:15s,stop:10s,'
                   'accel:0-12:15s,cruise:12:20s,brake:12-0:12s,stop:10s,accel:0-15:20s',
}


@dataclass(frozen=True)
class Segment:
    """One segment: kind, start and end speed (m/s), duration (s), ripple amplitude (m/s) and
    number of whole ripple periods."""

    kind: str
    v0: float
    v1: float
    duration_s: float
    ripple_mps: float = 0.0
    ripple_periods: int = 1

    def speed(self, tau: np.ndarray) -> np.ndarray:
        """Speed (m/s) at times tau (s) from the segment start, 0 <= tau <= duration_s."""
        frac = np.asarray(tau, dtype=float) / self.duration_s
        v = self.v0 + (self.v1 - self.v0) * frac
        if self.ripple_mps:
            v = v + self.ripple_mps * np.sin(2 * np.pi * self.ripple_periods * frac)
        return v

    @property
    def distance_m(self) -> float:
        """Distance covered (m): the ripple integrates to zero over whole periods."""
        return 0.5 * (self.v0 + self.v1) * self.duration_s


@dataclass(frozen=True)
class SpeedProfile:
    """A sequence of segments; call it with times (s from the start) for speeds (m/s)."""

    segments: tuple[Segment, ...]
    spec: str

    @property
    def duration_s(self) -> float:
        """Total duration (s)."""
        return float(sum(s.duration_s for s in self.segments))

    @property
    def distance_m(self) -> float:
        """Total distance (m), analytic."""
        return float(sum(s.distance_m for s in self.segments))

    @property
    def max_speed_mps(self) -> float:
        """Highest speed (m/s) anywhere in the profile."""
        return max(max(s.v0, s.v1) + s.ripple_mps for s in self.segments)

    @property
    def bounds_s(self) -> np.ndarray:
        """Segment start times and the end time (s), shape (n_segments + 1,)."""
        return np.concatenate([[0.0], np.cumsum([s.duration_s for s in self.segments])])

    def __call__(self, t_s: np.ndarray) -> np.ndarray:
        """Speeds (m/s) at times t_s (s); clipped to [0, duration_s]."""
        t = np.clip(np.asarray(t_s, dtype=float), 0.0, self.duration_s)
        bounds = self.bounds_s
        index = np.clip(np.searchsorted(bounds, t, side='right') - 1, 0, len(self.segments) - 1)
        v = np.empty_like(t)
        for i, seg in enumerate(self.segments):  # a handful of segments, each vectorised
            mine = index == i
            v[mine] = seg.speed(t[mine] - bounds[i])
        return v


def _number(token: str, text: str, what: str, unit: str = '') -> float:
    """A finite number from ``text`` (an ``s`` suffix allowed for durations)."""
    body = text.strip()
    if unit and body.endswith(unit):
        body = body[:-len(unit)]
    try:
        value = float(body)
    except ValueError:
        raise ConfigError(f'speed profile: {token!r}: {what} is not a number: {text!r}') from None
    if not math.isfinite(value) or value < 0:
        raise ConfigError(f'speed profile: {token!r}: {what} must be a finite number >= 0')
    return value


def _parse_segment(token: str) -> Segment:
    """One ``kind:...`` token -> Segment; ConfigError naming the token."""
    parts = [p.strip() for p in token.strip().split(':')]
    kind = parts[0]
    positional = [p for p in parts[1:] if '=' not in p]
    options = dict(p.split('=', 1) for p in parts[1:] if '=' in p)
    shapes = {'accel': 2, 'brake': 2, 'cruise': 2, 'stop': 1}
    if kind not in shapes:
        raise ConfigError(f'speed profile: {token!r}: unknown segment {kind!r}; expected '
                          f'{", ".join(shapes)} or a preset ({", ".join(PRESETS)})')
    allowed = {'ripple', 'period'} if kind == 'cruise' else set()
    if len(positional) != shapes[kind] or set(options) - allowed:
        usage = {'accel': 'accel:V0-V1:DURs', 'brake': 'brake:V0-V1:DURs',
                 'cruise': 'cruise:V:DURs[:ripple=A][:period=P]', 'stop': 'stop:DURs'}[kind]
        raise ConfigError(f'speed profile: {token!r}: expected {usage} (m/s, s)')
    duration = _number(token, positional[-1], 'duration', 's')
    if duration <= 0:
        raise ConfigError(f'speed profile: {token!r}: duration must be > 0 s')
    if kind == 'stop':
        return Segment('stop', 0.0, 0.0, duration)
    if kind == 'cruise':
        v = _number(token, positional[0], 'speed')
        ripple = _number(token, options.get('ripple', '0'), 'ripple')
        period = _number(token, options.get('period', str(DEFAULT_RIPPLE_PERIOD_S)), 'period',
                         's')
        if period <= 0:
            raise ConfigError(f'speed profile: {token!r}: period must be > 0 s')
        if ripple > v:
            raise ConfigError(f'speed profile: {token!r}: ripple {ripple:g} m/s would drive '
                              f'the speed below 0')
        return Segment('cruise', v, v, duration, ripple, max(1, round(duration / period)))
    match = re.fullmatch(r'([^-]+)-([^-]+)', positional[0])
    if not match:
        raise ConfigError(f'speed profile: {token!r}: expected speeds V0-V1 (m/s)')
    v0, v1 = (_number(token, g, 'speed') for g in match.groups())
    if (kind == 'accel') != (v1 > v0):
        raise ConfigError(f'speed profile: {token!r}: {kind} needs V1 '
                          f'{">" if kind == "accel" else "<"} V0')
    if abs(v1 - v0) / duration > MAX_ACCEL_MPS2:
        raise ConfigError(f'speed profile: {token!r}: {abs(v1 - v0) / duration:.2g} m/s^2 is '
                          f'not plausible (max {MAX_ACCEL_MPS2:g}); speeds are in m/s')
    return Segment(kind, v0, v1, duration)


def parse_speed_profile(spec: str) -> SpeedProfile:
    """Parse a profile spec or preset name (see the module docstring)."""
    if not isinstance(spec, str) or not spec.strip():
        raise ConfigError('speed profile: empty; expected segments or a preset '
                          f'({", ".join(PRESETS)})')
    text = PRESETS.get(spec.strip(), spec)
    segments = tuple(_parse_segment(token) for token in text.split(','))
    for prev, seg in itertools.pairwise(segments):
        if abs(seg.v0 - prev.v1) > SPEED_TOLERANCE_MPS:
            raise ConfigError(f'speed profile: {seg.kind} starts at {seg.v0:g} m/s but the '
                              f'segment before ends at {prev.v1:g} m/s')
    if max(max(s.v0, s.v1) for s in segments) <= 0:
        raise ConfigError('speed profile: the train never moves')
    return SpeedProfile(segments, spec.strip())


def speed_profile(spec: str, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, v_mps) of a profile spec sampled at ``rate_hz`` from 0 to its duration inclusive."""
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f'speed profile: rate must be a positive number, got {rate_hz!r}')
    profile = parse_speed_profile(spec)
    t = np.arange(round(profile.duration_s * rate_hz) + 1) / rate_hz
    return t, profile(t)
