"""Streaming long FIR filters with per-sample output: non-uniformly partitioned overlap-save.

``PartitionedFir`` computes the causal convolution z[n] = sum_j h[j] x[n - j] of C channels with
F = 1 or C filters of L taps, and returns z[n] as soon as x[n] has arrived (no block latency).

Why our own scheme instead of ``scipy.signal.oaconvolve``: oaconvolve needs the whole record and a
live stream needs each output the moment its newest input arrives. Taps are split as in Gardner's
low-latency convolution (J. Audio Eng. Soc. 43(3), 1995): the first ``sizes[0]`` taps run as a
direct dot product per sample; the taps from ``sizes[i]`` to ``sizes[i+1]`` run in partitions of
``sizes[i]`` taps through frequency-domain delay lines (one real FFT of 2 * sizes[i] input samples
per block); a level's block contribution needs only inputs of earlier blocks, so it is ready when
the block starts. Blocks sit at absolute sample indices and every sum has a fixed order, so the
output is bit-identical for any chunking of the input.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import fft

DEFAULT_SIZES = (32, 256, 2048)
_HEAD_ROWS = 4096  # rows of the direct-form window product evaluated at once (memory bound)
_MIN_ROOM = 64  # samples of spare room in a new History buffer at least


class History:
    """The newest ``keep`` samples (last axis) of a stream followed by each chunk appended,
    as one contiguous view. A chunk is copied into spare room behind the kept samples, which
    move to a new buffer only when the room is used up: joining them with every chunk copied
    the whole history per call (a live push of one sample copied 4096 of them).

    ``initial``: (C, k) samples kept at the start; ``extend(x (C, T))`` returns the view (C,
    k + T) of the k <= ``keep`` kept samples and x, valid until the next call."""

    def __init__(self, keep: int, initial: np.ndarray) -> None:
        self.keep = keep
        self._buf = initial
        self._span = (0, initial.shape[1])  # columns of the kept samples in _buf

    @property
    def kept(self) -> int:
        """Samples kept (before the next chunk)."""
        return self._span[1] - self._span[0]

    def extend(self, x: np.ndarray) -> np.ndarray:
        """Append a chunk (C, T); the kept samples and the chunk (C, k + T)."""
        lo, hi = self._span
        t = x.shape[-1]
        buf = self._buf
        if hi + t > buf.shape[1]:  # no room: a new buffer with room for keep more samples
            size = hi - lo + t
            fresh = np.empty((buf.shape[0], size + max(self.keep, _MIN_ROOM)), buf.dtype)
            fresh[:, :hi - lo] = buf[:, lo:hi]
            buf, lo, hi = fresh, 0, hi - lo
            self._buf = buf
        buf[:, hi:hi + t] = x
        self._span = (max(lo, hi + t - self.keep), hi + t)
        return buf[:, lo:hi + t]


class _Level:
    """Taps [size, stop) in partitions of ``size`` taps through a frequency-domain delay line."""

    def __init__(self, size: int, stop: int) -> None:
        self.size = size
        self.stop = stop
        self.n_part = (stop - size) // size
        self.spectra = np.zeros(0, complex)  # (n_part, C, size + 1): X_{b} newest first
        self.current: np.ndarray | None = None  # (C, size): contribution of the current block

    def set_taps(self, taps: np.ndarray) -> None:
        """Partition spectra G_q (n_part, F, size + 1) of taps (F, L) for this level."""
        s = self.size
        part = taps[:, s:self.stop].reshape(taps.shape[0], self.n_part, s)
        self.gains = fft.rfft(np.moveaxis(part, 1, 0), n=2 * s, axis=-1)

    def reset(self, channels: int) -> None:
        """Zero input history."""
        self.spectra = np.zeros((self.n_part, channels, self.size + 1), complex)
        self.current = None

    def process(self, hist: np.ndarray, hist_start: int, n0: int, t_len: int) -> np.ndarray:
        """Contribution to z[n0 : n0 + t_len]; hist holds x from absolute index hist_start."""
        s = self.size
        first, last = n0 // s, (n0 + t_len - 1) // s
        # blocks starting inside the chunk need their contribution computed now
        new = np.arange(first if n0 % s == 0 else first + 1, last + 1)
        blocks: list[np.ndarray] = []
        if n0 % s != 0:  # a chunk inside a block continues the block's contribution
            assert self.current is not None
            blocks.append(self.current)
        if new.size:
            # frame b = blocks b-1 and b of the input; block m uses frames m-1-q, q < n_part
            first_frame = (new[0] - 2) * s - hist_start  # frame of block m: x[(m-2)s, m s)
            lead = max(0, -first_frame)  # zeros before the stream start
            src = np.concatenate([np.zeros((hist.shape[0], lead)), hist], axis=1) if lead \
                else hist
            frames = sliding_window_view(src[:, first_frame + lead:], 2 * s, axis=-1)[:, ::s]
            xs = fft.rfft(np.moveaxis(frames[:, :new.size], 1, 0), axis=-1)  # (M, C, s + 1)
            ext = np.concatenate([self.spectra[::-1], xs], axis=0)  # chronological
            k = self.n_part  # ext[k + i] is frame new[i] - 1
            acc = np.zeros_like(xs)
            for q in range(self.n_part):
                acc += self.gains[q][None] * ext[k - q:k - q + new.size]
            out = fft.irfft(acc, n=2 * s, axis=-1)[..., s:]  # (M, C, s)
            self.spectra = ext[::-1][:self.n_part].copy()
            blocks.append(np.moveaxis(out, 0, 1).reshape(out.shape[1], -1))  # (C, M s)
        flat = np.concatenate(blocks, axis=-1)
        start = n0 - first * s
        self.current = flat[:, -s:]
        return flat[:, start:start + t_len]


class PartitionedFir:
    """Streaming causal FIR bank: ``process(x (C, T)) -> z (C, T)``, state carried between calls.

    ``taps`` has shape (F, L), F = 1 (shared) or F = C (one filter per channel). ``set_taps``
    swaps the filter; it takes effect for every tap at once when called at a multiple of
    ``switch_period`` samples (all block boundaries align there).
    """

    def __init__(self, taps: np.ndarray, channels: int,
                 sizes: tuple[int, ...] = DEFAULT_SIZES) -> None:
        taps = np.atleast_2d(np.asarray(taps, dtype=float))
        self.channels = int(channels)
        self.length = taps.shape[-1]
        self._levels: list[_Level] = []
        for i, s in enumerate(sizes):
            if s >= self.length:
                break
            nxt = sizes[i + 1] if i + 1 < len(sizes) else self.length
            if nxt >= self.length:
                self._levels.append(_Level(s, -(-self.length // s) * s))
                break
            self._levels.append(_Level(s, nxt))
        self.head = min(sizes[0], self.length)
        self.padded = self._levels[-1].stop if self._levels else self.head
        self.switch_period = self._levels[-1].size if self._levels else 1
        self._keep = 2 * max([lv.size for lv in self._levels] + [self.head])
        self.set_taps(taps)
        self.reset()

    def set_taps(self, taps: np.ndarray) -> None:
        """Use new taps (F, L') with L' <= L, zero-padded to the partitioned length."""
        taps = np.atleast_2d(np.asarray(taps, dtype=float))
        padded = np.zeros((taps.shape[0], self.padded))
        padded[:, :taps.shape[-1]] = taps
        self._head_taps = padded[:, self.head - 1::-1].copy()  # reversed for the window product
        for level in self._levels:
            level.set_taps(padded)

    def reset(self) -> None:
        """Zero state and restart absolute sample indices at 0."""
        self.n_total = 0
        self._hist = History(self._keep, np.zeros((self.channels, 0)))
        for level in self._levels:
            level.reset(self.channels)

    def process(self, x: np.ndarray) -> np.ndarray:
        """Filter a chunk x of shape (C, T) (or (T,) broadcast to every channel)."""
        x = np.asarray(x, dtype=float)
        if x.shape[0] != self.channels or x.ndim != 2:  # (T,) or one channel for all
            x = np.broadcast_to(x, (self.channels, x.shape[-1]))
        t_len = x.shape[-1]
        if t_len == 0:
            return np.zeros((self.channels, 0))
        n0 = self.n_total
        hist_start = n0 - self._hist.kept
        hist = self._hist.extend(x)
        out = self._head(hist, hist_start, n0, t_len)
        for level in self._levels:
            out += level.process(hist, hist_start, n0, t_len)
        self.n_total = n0 + t_len
        return out

    def _head(self, hist: np.ndarray, hist_start: int, n0: int, t_len: int) -> np.ndarray:
        """Direct form for the first ``head`` taps; rows summed in a fixed order."""
        h = self.head
        lead = h - 1 - (n0 - hist_start)
        seg = hist[:, max(0, n0 - hist_start - (h - 1)):]
        if lead > 0:
            seg = np.concatenate([np.zeros((self.channels, lead)), seg], axis=1)
        out = np.empty((self.channels, t_len))
        for a in range(0, t_len, _HEAD_ROWS):
            b = min(a + _HEAD_ROWS, t_len)
            win = seg[:, None, a:a + h] if b - a == 1 else \
                sliding_window_view(seg[:, a:b + h - 1], h, axis=-1)  # (C, b - a, h)
            out[:, a:b] = np.einsum('ctk,ck->ct', win, self._head_taps)
        return out
