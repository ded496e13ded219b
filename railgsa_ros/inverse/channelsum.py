"""Multi-input band stage: P outputs from C input channels, one FIR per (output, channel), summed.

z_p[n] = sum_c (h_pc * x_c)[n]: a coach's LMMSE inverse from vertical acceleration and pitch
rate (``design.py``). It wraps a single-input stage (``PartitionedFir`` or ``MultirateFir``) of
P C channels, row p C + c filtering channel c with h_pc, so that streaming, redesign at a switch
boundary and bit-identity for any chunking are the wrapped stage's.
"""

from __future__ import annotations

import numpy as np

from railgsa_ros.inverse.convolve import PartitionedFir
from railgsa_ros.inverse.multirate import MultirateFir


class ChannelSum:
    """``process(x (C, T)) -> z (P, T)``; ``set_taps(taps (P C, L))`` rows ordered p C + c;
    ``reset``, ``switch_period`` (input samples) as the wrapped ``stage`` of P C channels."""

    def __init__(self, stage: PartitionedFir | MultirateFir, outputs: int, inputs: int) -> None:
        self.stage = stage
        self.outputs = int(outputs)
        self.inputs = int(inputs)
        self.switch_period = stage.switch_period

    def set_taps(self, taps: np.ndarray) -> None:
        """New taps (P C, L') for every (output, channel) pair."""
        self.stage.set_taps(taps)

    def reset(self) -> None:
        """Zero the wrapped stage's state."""
        self.stage.reset()

    def process(self, x: np.ndarray) -> np.ndarray:
        """Filter a chunk of the C channels (C, T); the outputs (P, T)."""
        x = np.asarray(x)
        z = self.stage.process(np.tile(x, (self.outputs, 1)))
        return z.reshape(self.outputs, self.inputs, -1).sum(axis=1)

