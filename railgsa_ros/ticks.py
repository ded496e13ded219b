"""How a slower sensor (odometry, GNSS) samples a faster stream, chunk by chunk."""

from __future__ import annotations

import numpy as np


class TickSampler:
    """How a slower sensor (odometry, GNSS) samples a stream: the first sample at or after each
    tick of a ``rate_hz`` clock that starts at the first stamp, over consecutive chunks."""

    def __init__(self, rate_hz: float) -> None:
        self.period_ns = 1e9 / rate_hz
        self.start_ns: int | None = None
        self.next_tick = 0  # index of the first tick not yet assigned to a sample

    def take(self, stamps_ns: np.ndarray) -> np.ndarray:
        """Indices into this chunk's stamps (increasing int64 ns) of the sampled samples."""
        stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
        if stamps_ns.size == 0:
            return np.zeros(0, dtype=np.int64)
        if self.start_ns is None:
            self.start_ns = int(stamps_ns[0])
        last = int((stamps_ns[-1] - self.start_ns) // self.period_ns)
        ticks = self.start_ns + np.round(
            np.arange(self.next_tick, last + 2) * self.period_ns).astype(np.int64)
        ticks = ticks[ticks <= stamps_ns[-1]]
        self.next_tick += ticks.size
        return np.unique(np.searchsorted(stamps_ns, ticks, side='left'))
