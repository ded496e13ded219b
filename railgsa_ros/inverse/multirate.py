"""Multirate band stage: anti-alias FIR and decimation by R, the band FIR at fs / R, polyphase
interpolation back to fs, with an output for every input sample the moment it has arrived.

The band response is negligible far above the band's upper edge, while the IMU samples at 1 kHz:
at fs / R the long band FIR has R times fewer taps and runs over R times fewer samples. Both rate
changes use the same linear-phase Kaiser low-pass A (odd length 2 Da + 1, flat within the FIR
tolerance up to f_pass, below it from fs / R - f_pass, so nothing aliases onto the band). Low
sample m is taken at input index m R: y[m] = sum_j a[j] x[m R - j]; the band FIR gives w from y;
the output is z[n] = R sum_m w[m] a[n - m R]. All three stages are zero-phase with their delays,
so the cascade has the fixed delay Da + R Dl + Da input samples (Dl: the band FIR's delay in low
samples).

Precision: the rate changes may run in float32 (``rate_dtype``) when their input is the measured
acceleration, bounded by the sensor's range and quantised coarser than float32's 24-bit mantissa
(a 20-bit ADC at best). They are memory bound and float32 halves the traffic (the whole pipeline
15-20 % faster) while the rounding stays far below the filters' design tolerance (measured:
3e-7 of the output's peak over the cascade, for a tolerance of 1e-5). The band FIR at fs / R
always runs in float64, and so do both rate changes after a state-space stage (feedback, Kalman),
whose output carries the unbounded double-integrated drift that the band removes.

Why our own streaming code instead of ``scipy.signal.upfirdn``/``resample_poly``: those filter a
whole record without carrying state between calls. Low samples and output phases sit at absolute
sample indices and every product is an ``np.einsum`` or a fixed sequence of whole-array
multiply-adds (no BLAS: their sums run in a fixed order whatever the chunk shape, while BLAS picks
other kernels for small chunks and changes the last bit), so the output is bit-identical for any
chunking.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import as_strided
from scipy import signal

from railgsa_ros.inverse.convolve import DEFAULT_SIZES, History, PartitionedFir

PASS_FACTOR = 1.5  # anti-alias passband edge / the band's upper edge at max_speed_mps
TRANSITION = 1.0  # anti-alias transition width / passband edge: fs / R >= (2 + this) f_pass
FLOAT32_TOLERANCE = 1e-5  # design tolerances from this up: rate changes in float32 (30x margin)
MAX_SWITCH = 4096  # input samples: longest period between band redesigns (speed tracking)
SMALL_COUNT = 16  # low samples up to which the interpolation sums all products at once


def decimation(rate_hz: float, f_top_hz: float) -> int:
    """Largest R with fs / R >= (2 + TRANSITION) PASS_FACTOR f_top (f_top: band edge, Hz)."""
    return int(rate_hz // ((2.0 + TRANSITION) * PASS_FACTOR * f_top_hz))


def rolloff(f_hz: np.ndarray, f_top_hz: float, rate_hz: float) -> np.ndarray:
    """Raised cosine from 1 at PASS_FACTOR f_top to 0 at the Nyquist frequency of ``rate_hz``
    (the low rate), Hz: the band FIR's response there is irrelevant (the anti-alias filters
    remove it) and tapering it to 0 avoids the slowly decaying ringing of a response cut at
    Nyquist (the D1 spectral FIR at 70 m/s: half-length 5024 instead of 111 low samples)."""
    f_pass, nyquist = PASS_FACTOR * f_top_hz, 0.5 * rate_hz
    frac = np.clip((np.abs(f_hz) - f_pass) / (nyquist - f_pass), 0.0, 1.0)
    return 0.5 + 0.5 * np.cos(np.pi * frac)


def rate_dtype(tol: float, measured: bool) -> type:
    """Arithmetic of the rate changes for filters designed to tolerance ``tol`` whose input is
    the ``measured`` acceleration (else a state-space stage's output)."""
    return np.float32 if measured and tol >= FLOAT32_TOLERANCE else np.float64


def antialias_taps(rate_hz: float, r: int, f_top_hz: float, tol: float) -> np.ndarray:
    """Kaiser low-pass (odd length, unit DC gain): within ``tol`` of 1 up to PASS_FACTOR f_top
    and below ``tol`` from fs / R - PASS_FACTOR f_top (Hz)."""
    f_pass = PASS_FACTOR * f_top_hz
    width = rate_hz / r - 2.0 * f_pass
    numtaps, beta = signal.kaiserord(-20.0 * math.log10(tol), width / (0.5 * rate_hz))
    return signal.firwin(numtaps | 1, 0.5 * rate_hz / r, window=('kaiser', beta), fs=rate_hz)


class MultirateFir:
    """Streaming band stage at fs / R: ``process(x (C_in, T)) -> z (C, T)``, same interface as
    ``PartitionedFir`` (``set_taps``, ``reset``, ``switch_period`` in input samples).

    ``taps``: band FIR (F, L) at the low rate, F = 1 or C; ``antialias``: taps of A (odd length)
    at the input rate. C_in = 1 (shared input, decimated once) or C. ``dtype``: arithmetic of
    the two rate changes (see ``rate_dtype``); the output is float64.
    """

    def __init__(self, taps: np.ndarray, channels: int, r: int, antialias: np.ndarray,
                 dtype: type[np.floating] = np.float64) -> None:
        self.r = int(r)
        self.dtype = dtype
        sizes = tuple(s for s in DEFAULT_SIZES if s == DEFAULT_SIZES[0] or s * r <= MAX_SWITCH)
        self.low = PartitionedFir(taps, channels, sizes)
        self.switch_period = self.r * self.low.switch_period
        # reversed: window product
        self._dec: np.ndarray = np.asarray(antialias, dtype=dtype)[::-1].copy()
        k = -(-self._dec.size // self.r)
        pad = np.zeros(k * self.r)
        pad[:self._dec.size] = self.r * np.asarray(antialias, dtype=float)
        # phase p of low sample q: sum_j w[q - k + 1 + j] pad[(k - 1 - j) r + p]
        self._phases: np.ndarray = pad.reshape(k, self.r)[::-1].T.astype(dtype)  # (r, k)
        self.reset()

    @property
    def half_delay(self) -> int:
        """Delay Da (input samples) of the anti-alias filter, the same for the interpolator."""
        return (self._dec.size - 1) // 2

    def set_taps(self, taps: np.ndarray) -> None:
        """New band FIR (F, L') at the low rate; applies to every tap at once when called at a
        multiple of ``switch_period`` input samples."""
        self.low.set_taps(taps)

    def reset(self) -> None:
        """Zero state and restart absolute sample indices at 0."""
        self.n_total = 0
        self._x: History | None = None  # last len(A) - 1 inputs (zeros before the start)
        self._w: np.ndarray = np.zeros((self.low.channels, self._phases.shape[1]),
                                       self.dtype)  # last k w

    def process(self, x: np.ndarray) -> np.ndarray:
        """Filter a chunk x of shape (C_in, T) or (T,)."""
        x = np.atleast_2d(np.asarray(x, dtype=self.dtype))
        t_len, r = x.shape[-1], self.r
        if t_len == 0:
            return np.zeros((self.low.channels, 0))
        n0 = self.n_total
        if self._x is None:
            keep = self._dec.size - 1
            self._x = History(keep, np.zeros((x.shape[0], keep), self.dtype))
        hist = self._x.extend(x)  # hist[:, i] is x[n0 - len(A) + 1 + i]
        m0, m1 = -(-n0 // r), (n0 + t_len - 1) // r + 1  # low samples taken in this chunk
        w = self._w
        if m1 > m0:
            win = _windows(hist[:, m0 * r - n0:], self._dec.size, m1 - m0, r)
            y = np.einsum('cmj,j->cm', win, self._dec)
            w = np.concatenate([w, self.low.process(y).astype(self.dtype)], axis=1)
        # w[:, i] is w[m1 - w.shape[1] + i]; output phases of low samples q0 .. m1 - 1
        k = self._phases.shape[1]
        q0 = n0 // r
        src = w[:, q0 - k + 1 - (m1 - w.shape[1]):]
        p = n0 - q0 * r  # output phase of the first sample
        if t_len == 1:  # a live push: that phase's products alone, summed in the same order
            z = np.cumsum(src[:, :k] * self._phases[p], axis=-1)[:, -1:]
        else:
            z = self._interpolate(src, src.shape[1] - k + 1).reshape(w.shape[0], -1)
            z = z[:, p:p + t_len]
        self.n_total = n0 + t_len
        self._w = w[:, w.shape[1] - k:]
        return z.astype(float)

    def _interpolate(self, w: np.ndarray, count: int) -> np.ndarray:
        """Output phases (C, count, R) of low samples: [c, i, p] = sum_j w[c, i + j] phases[p, j],
        summed over j in order as whole-array multiply-adds along the low samples (faster than
        a window product of k-long dots, and the same order whatever the chunk). A few low
        samples (a live push) take all products at once and a running sum over j instead: the
        same products added in the same order, in 3 numpy calls instead of 2 k."""
        if count <= SMALL_COUNT:
            win = _windows(w, self._phases.shape[1], count, 1)
            terms = win[:, :, None, :] * self._phases  # (C, count, R, k)
            return np.cumsum(terms, axis=-1)[..., -1]
        phases = self._phases[None, :, :, None]  # (1, R, k, 1)
        z = phases[:, :, 0] * w[:, None, :count]  # (C, R, count)
        term = np.empty_like(z)
        for j in range(1, self._phases.shape[1]):
            np.multiply(phases[:, :, j], w[:, None, j:j + count], out=term)
            z += term
        return z.transpose(0, 2, 1)


def _windows(x: np.ndarray, length: int, count: int, step: int) -> np.ndarray:
    """View (C, count, length) of x (C, T): window i is x[:, i step:i step + length]; what
    ``sliding_window_view(x, length, axis=-1)[:, ::step][:, :count]`` gives, without its
    checks (a quarter of the cost of a live push)."""
    assert (count - 1) * step + length <= x.shape[1]
    if count == 1:  # a live push's one window: a plain view (as_strided costs some 5 us)
        return x[:, None, :length]
    rows, cols = x.strides
    return as_strided(x, (x.shape[0], count, length), (rows, step * cols, cols), writeable=False)
