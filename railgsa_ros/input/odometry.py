"""Odometry and speed: the speed at each IMU stamp, and the distance across stretches without one.

The speed at an IMU stamp is the newest odometry sample at or before it if it is not older than
``odom_timeout_s`` (before the stream's first odometry sample: that one, if not newer than
``odom_timeout_s``), else UNKNOWN (the output is INVALID). Odometry must arrive in stamp order:
older odometry is counted and ignored, odometry going back by more than ``backward_reset_s``
restarts it. Non-finite odometry, speeds beyond SPEED_LIMIT_MPS and jumps beyond
``speed_step`` from the last accepted speed are counted and ignored; a negative speed is reverse
running (the chainage decreases), counted and reported. ``speed_mps`` is used only with
``use_odom`` false (``--speed`` offline).
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from railgsa_ros.input.findings import OK, WARN, Finding, Findings
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.sanitize import SMALL, SPEED_LIMIT_MPS
from railgsa_ros.inverse.config import InversionConfig

#: an odometry speed changing faster than this (beyond ODOM_NOISE_MPS) is implausible: 2 g,
#: where trains brake at up to about 3 m/s^2 in an emergency (a margin for simulated
#: profiles); a sign flip at 20 m/s is 2000 m/s^2 at 50 Hz, a drop to 0 is 1000 m/s^2
ODOM_ACCEL_MPS2 = 20.0
ODOM_NOISE_MPS = 1.0  #: odometry speed noise allowed on top of ODOM_ACCEL_MPS2, m/s


def speed_step(dt_ns: np.ndarray | int) -> np.ndarray | float:
    """Largest odometry speed change (m/s) a train makes in dt_ns: ODOM_ACCEL_MPS2 x dt plus
    ODOM_NOISE_MPS for the odometry's own noise."""
    return ODOM_ACCEL_MPS2 * np.asarray(dt_ns) * 1e-9 + ODOM_NOISE_MPS


def held_speeds(odom_t: np.ndarray, odom_v: np.ndarray, stamps: np.ndarray, timeout_ns: int
                ) -> tuple[np.ndarray, np.ndarray, int]:
    """(speed m/s, known, first odometry sample used) at the stamps: the newest odometry
    sample at or before each, if at most ``timeout_ns`` older; before the first odometry
    sample (the odometry started after the IMU), that first one, if at most ``timeout_ns``
    newer: the first IMU sample's chainage then counts the distance to the first odometry
    sample. Unknown speeds are 0."""
    if odom_t.size == 0:
        return np.zeros(stamps.size), np.zeros(stamps.size, bool), 0
    idx = np.searchsorted(odom_t, stamps, side='right') - 1
    j = np.maximum(idx, 0)
    known = np.abs(stamps - odom_t[j]) <= timeout_ns  # before or after odom_t[j]
    return np.where(known, odom_v[j], 0.0), known, int(j.min())


def speed_verdict(options: InputOptions, speed_mps: float, lost: bool, reverse: int,
                  total_reverse: int) -> Finding:
    """The 'speed' finding of a release (``speed_mps``: the fixed speed without odometry;
    ``lost``: its newest sample has no speed; ``reverse``: its samples at negative speed,
    ``total_reverse`` so far)."""
    if not options.use_odom:
        return Finding('speed', OK, f'fixed speed_mps {speed_mps:g} m/s (use_odom false)')
    if lost:
        return Finding('speed', WARN, (
            f'no odometry within odom_timeout_s ({options.odom_timeout_s:g} s) of the IMU '
            'stamps: outputs are INVALID until a speed is known; check the odom topic (offline: '
            '--speed)'))
    if reverse:
        return Finding('speed', WARN, (
            f'reverse running: {total_reverse} samples at negative speed (the chainage '
            'decreases); if the train ran forward, the odometry sign is reversed'))
    return Finding('speed', OK, 'speed from odometry')


class Odometry:
    """The odometry kept for the held IMU samples, their speeds, the 'odometry' and 'speed'
    findings; counts into ``counts`` (odom_received, odom_malformed, odom_nan,
    odom_implausible, odom_out_of_order, odom_time_reset, speed_unknown, reverse)."""

    def __init__(self, config: InversionConfig, options: InputOptions, counts: Counter[str],
                 findings: Findings) -> None:
        self.config, self.options = config, options
        self._counts, self._findings = counts, findings
        self._t = np.zeros(0, np.int64)
        self._v = np.zeros(0)
        self._old: tuple[np.ndarray, np.ndarray] | None = None  # before a time reset
        self._known_at: tuple[int, float] | None = None  # stamp, speed: newest known released
        self._gap_span: tuple[int, int] | None = None  # stamps: released without speed since

    @property
    def newest(self) -> int:
        """Stamp (ns) of the newest odometry sample kept (int64 min before any)."""
        return self._t[-1] if self._t.size else np.iinfo(np.int64).min

    def add(self, stamps_ns: np.ndarray, speed_mps: np.ndarray) -> None:
        """Odometry samples (stamps (M,) int64 ns, speeds (M,) m/s, in stamp order as they
        came): the plausible ones kept, the others counted."""
        stamps = np.atleast_1d(np.asarray(stamps_ns, dtype=np.int64))
        speed = np.broadcast_to(np.asarray(speed_mps, dtype=float), stamps.shape)
        self._counts['odom_received'] += stamps.size
        stamped = stamps > 0  # else malformed, as a node's intake finds it
        finite = stamped & np.isfinite(speed)
        plausible = finite & (np.abs(speed) <= SPEED_LIMIT_MPS)
        self._counts['odom_malformed'] += int((~stamped).sum())
        self._counts['odom_nan'] += int((stamped & ~finite).sum())
        self._counts['odom_implausible'] += int((finite & ~plausible).sum())
        t_ok, v_ok = stamps[plausible], speed[plausible]
        t_all = np.concatenate([self._t[-1:], t_ok])
        v_all = np.concatenate([self._v[-1:], v_ok])
        if t_ok.size and np.all(np.diff(t_all) > 0) and np.all(  # in order, no jump
                np.abs(np.diff(v_all)) <= speed_step(np.diff(t_all))):
            # in order after the newest (as recorded): what the loop below appends, at once
            self._t = np.concatenate([self._t, t_ok])
            self._v = np.concatenate([self._v, v_ok])
        else:
            for t, v in zip(t_ok.tolist(), v_ok.tolist(), strict=True):
                self._add_one(t, v)
        self._report()

    def _add_one(self, t: int, v: float) -> None:
        if self._t.size and t <= self._t[-1]:
            if t < self._t[-1] - self.options.backward_reset_s * 1e9:
                self._counts['odom_time_reset'] += 1  # a new odometry stream
                # the old one still gives the speed of the old IMU stream's last samples
                self._old = (self._t, self._v)
                self._t, self._v = self._t[:0], self._v[:0]
            else:
                self._counts['odom_out_of_order'] += 1
                return
        elif self._t.size and abs(v - self._v[-1]) > speed_step(t - int(self._t[-1])):
            self._counts['odom_implausible'] += 1  # a jump no train makes: a glitch, a slide
            return
        self._t = np.append(self._t, np.int64(t))
        self._v = np.append(self._v, v)

    def _report(self) -> None:
        """The 'odometry' finding: WARN once odometry samples were ignored."""
        c = self._counts
        bad = {k: c[k] for k in ('odom_nan', 'odom_implausible', 'odom_out_of_order') if c[k]}
        if bad:
            text = ', '.join(f'{k[5:]} {v}' for k, v in bad.items())
            self._findings.set('odometry', WARN,
                               f'odometry samples ignored ({text}): check the odometry source')

    def new_stream(self, first_ns: int) -> None:
        """The IMU stamps went back (a time reset) to ``first_ns``: keep the odometry of the
        new stream alone, forget the gap across the reset."""
        self._known_at = self._gap_span = self._old = None
        recent = self._t <= first_ns + round(self.options.backward_reset_s * 1e9)
        self._t, self._v = self._t[recent], self._v[recent]  # its own

    def speeds(self, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(speed m/s, known) at the stamps; unknown speeds are 0 (the chainage holds)."""
        if not self.options.use_odom:
            return np.full(stamps.size, self.config.speed_mps), np.ones(stamps.size, bool)
        timeout = round(self.options.odom_timeout_s * 1e9)
        speed, known, keep = held_speeds(self._t, self._v, stamps, timeout)
        self._t, self._v = self._t[keep:], self._v[keep:]  # older: unused
        if self._old is not None and not known.all():  # before an odometry time reset
            old, in_old, _ = held_speeds(*self._old, stamps, timeout)
            speed, known = np.where(known, speed, old), known | in_old
        return speed, known

    def report(self, unknown: int, reverse: int, last_known: bool) -> None:
        """Count the samples of a release without a speed and at negative speed; the 'speed'
        finding (``last_known``: the newest one has a speed)."""
        self._counts['speed_unknown'] += unknown
        self._counts['reverse'] += reverse
        total, options, v_fixed = self._counts['reverse'], self.options, self.config.speed_mps
        lost = bool(unknown) and not last_known
        self._findings.later('speed', lambda: speed_verdict(options, v_fixed, lost, reverse,
                                                            total))

    def missed_distance(self, stamps: np.ndarray, speed: np.ndarray, known: np.ndarray
                        ) -> list[tuple[int, float]]:
        """Where a released sample with a known speed follows samples without one (no
        odometry for longer than odom_timeout_s: their speed is 0, the chainage held): its
        index in the chunk and the distance (m) the held chainage missed, the speed taken as
        linear from the last known sample before the gap to this one. Carries the newest known
        sample and the open gap across calls."""
        if self._gap_span is None and (bool(known.all()) if known.size > SMALL
                                       else all(known.tolist())):
            self._known_at = (int(stamps[-1]), float(speed[-1]))
            return []
        missed = []
        for i, (t, v, k) in enumerate(zip(stamps.tolist(), speed.tolist(), known.tolist(),
                                          strict=True)):
            if not k:
                self._gap_span = (t if self._gap_span is None else self._gap_span[0], t)
                continue
            if self._gap_span is not None and self._known_at is not None:
                (ta, va), (t1, tn) = self._known_at, self._gap_span
                if ta < t1 <= tn < t:  # one stream (a time reset adds no distance)
                    # linear speed over [ta, t] less the trapezoids to and from speed 0
                    missed.append((i, 0.5e-9 * ((va + v) * (t - ta) - va * (t1 - ta)
                                                - v * (t - tn))))
            self._gap_span, self._known_at = None, (t, v)
        return missed
