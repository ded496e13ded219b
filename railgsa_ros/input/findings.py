"""Findings: the one-line verdicts of the input checks, and the book that keeps each one's newest.

A finding says what is wrong and what to do in one line (docs/inversion.md, "Input policy");
its level is a diagnostic_msgs/DiagnosticStatus level. The texts of the checks that run on
every live push are made when the findings are read (``Findings.later``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

OK, WARN, ERROR = 0, 1, 2  #: finding levels (diagnostic_msgs/DiagnosticStatus levels)

#: what to do when every sample is rejected, by the commonest reason
HINTS = {'wrong_frame': "set frame_id to the driver's frame_id or wrong_frame_policy to "
                        'accept',
         'nan': 'the accelerations are NaN or marked absent (covariance[0] = -1)',
         'saturated': 'check saturation_mps2 and the units of the accelerometer',
         'stuck': 'the sensor repeats one value: it is frozen, or raise stuck_s',
         'out_of_order': 'the stamps do not increase: check the driver clock',
         'duplicate': 'the stamps repeat: check the driver clock'}


@dataclass(frozen=True)
class Finding:
    """One plausibility verdict: key ('gravity', 'rate', 'jitter', 'rest', 'mounting',
    'speed', 'odometry', 'frame', 'order', 'rejected', 'acceleration', 'noise'), level
    (OK/WARN/ERROR) and a one-line message saying what to do."""

    key: str
    level: int
    message: str


class Findings:
    """The newest finding of each check, in the order the checks first reported."""

    def __init__(self) -> None:
        self._shown: dict[str, Finding | None] = {}  # None: made from _lazy when read
        self._lazy: dict[str, Callable[[], Finding]] = {}

    def __contains__(self, key: str) -> bool:
        return key in self._shown

    def get(self, key: str) -> Finding | None:
        """The finding ``key`` as last set (None if lazy or never set)."""
        return self._shown.get(key)

    def set(self, key: str, level: int, message: str) -> None:
        """Finding ``key`` is now (level, message)."""
        self._shown[key] = Finding(key, level, message)

    def later(self, key: str, make: Callable[[], Finding]) -> None:
        """Finding ``key`` is ``make()``, made when the findings are read: the checks of every
        live push would otherwise format a message per sample."""
        self._lazy[key] = make
        self._shown.setdefault(key, None)  # its place in the order

    @property
    def all(self) -> list[Finding]:
        """The current verdict of each check made so far."""
        for key, make in self._lazy.items():
            self._shown[key] = make()
        self._lazy.clear()
        return [f for f in self._shown.values() if f is not None]

    @property
    def status(self) -> Finding:
        """The worst finding (ERROR > WARN > OK), or OK 'ok' before any."""
        worst = max(self.all, key=lambda f: f.level, default=None)
        if worst is None or worst.level == OK:
            return Finding('status', OK, 'ok')
        return worst
