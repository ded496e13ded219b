"""A dependency-free progress bar on stderr, drawn only on a terminal or when forced."""

from __future__ import annotations

import sys
import time
from typing import TextIO

WIDTH = 30  # bar characters
MIN_INTERVAL_S = 0.1  # redraw at most this often


class Progress:
    """``update(done)`` redraws ``label [#####     ]  42 %`` in place; ``close()`` ends the line.

    ``enabled``: True (forced), False, or None = only when ``stream`` is a TTY.
    """

    def __init__(self, total: int, label: str = '', stream: TextIO | None = None,
                 enabled: bool | None = None) -> None:
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, 'isatty', None)
        self.enabled = bool(isatty and isatty()) if enabled is None else enabled
        self.total = max(int(total), 1)
        self.label = label
        self._last = float('-inf')
        self._drawn = False

    def update(self, done: int, label: str | None = None) -> None:
        """Show ``done`` of ``total`` (throttled, always drawn when complete)."""
        if label is not None:
            self.label = label
        now = time.monotonic()
        if not self.enabled or (now - self._last < MIN_INTERVAL_S and done < self.total):
            return
        self._last = now
        frac = min(max(done / self.total, 0.0), 1.0)
        fill = round(frac * WIDTH)
        self.stream.write(f'\r{self.label} [{"#" * fill}{" " * (WIDTH - fill)}] '
                          f'{100 * frac:3.0f} %')
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        """Finish the line (if anything was drawn)."""
        if self._drawn:
            self.stream.write('\n')
            self.stream.flush()
            self._drawn = False
