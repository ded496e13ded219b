"""Waiting for due times on a monotonic clock, with a lateness record (no ROS)."""

from __future__ import annotations

from collections.abc import Callable
import time

#: Longest single sleep (s), so that a shutdown request is seen within this time.
SLICE_S = 0.05


class Pacer:
    """Sleeps until ``start + due_ns`` (monotonic ns) and keeps lateness statistics (ns)."""

    def __init__(self, clock: Callable[[], int] = time.monotonic_ns,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        """``clock`` returns ns, ``sleep`` takes seconds (injectable for tests)."""
        self._clock = clock
        self._sleep = sleep
        self.start_ns = clock()
        self.count = 0
        self.late_max_ns = 0
        self.late_sum_ns = 0

    def restart(self) -> None:
        """Make now the zero of the due times."""
        self.start_ns = self._clock()

    def wait(self, due_ns: int, ok: Callable[[], bool] = lambda: True) -> bool:
        """Sleep until ``due_ns`` after the start; False (at once) when ``ok()`` turns False."""
        while ok():
            remaining = self.start_ns + due_ns - self._clock()
            if remaining <= 0:
                self.count += 1
                self.late_max_ns = max(self.late_max_ns, -remaining)
                self.late_sum_ns -= remaining
                return True
            self._sleep(min(remaining / 1e9, SLICE_S))
        return False

    @property
    def late_mean_ns(self) -> float:
        """Mean lateness of the waits so far (ns)."""
        return self.late_sum_ns / self.count if self.count else 0.0
