"""Model-based bridging of IMU dropouts: the conditional mean of the missing accelerations.

The car-body acceleration is modelled as a stationary Gaussian process: the German track
spectrum S(Omega) (one-sided, m^2/(rad/m), amplitude ``track_spectrum_av``) mapped to time at
the speed v, S_t(w) = S(w / v) / v, through the vehicle, S_a(w) = |G(j w)|^2 S_t(w), plus white
sensor noise of the IMU's variance. Its autocovariance R(tau) = int_0^inf S_a(w) cos(w tau) dw
is tabulated by one inverse FFT. Given the last accepted samples before a gap and the first one
after it, the missing samples are filled with their conditional mean about the running mean of
the accepted samples since the filters (re)started (bias and gravity: a mean estimated from the
second before the gap carries the body's oscillation, and the model, whose spectrum vanishes at
DC, turns an offset into a large swing; the mean's own error enters as a constant of variance
MEAN_STD^2), the best linear estimate in the model; a straight
line between the two ends (the old bridge) ignores the car body's oscillation and costs several
times more D1 error over a 0.2 s gap (docs/inversion.md, "Gaps").

The hold: the samples after a gap tell as much about it as those before (the car body keeps
oscillating across it), so a gap's fill waits for ``hold`` accepted samples after it (fewer when
the next gap or the end of the stream comes first) and conditions on them too; everything from
the gap on waits with it. Measured against the Bayes-optimal smoother on all samples
(docs/inversion.md, "Gaps"): 0.5 s takes most of what the data after the gap hold.

The fill's error is what the data cannot tell; its posterior covariance through the band FIR
(``error_variance``) is the variance of the output error the fill leaves at each output near the
gap, largest next to it and decaying as the FIR weight of the filled samples does: the band's
gap term (``uncertainty.terms``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import fft, linalg, signal

from railgsa_ros.inverse.kalman import OMEGA_C, OMEGA_R
from railgsa_ros.vehicle import frequency_response

TABLE_S = 64.0  # span of the covariance table, s (frequency resolution 1 / TABLE_S Hz)
CONTEXT_S = 1.0  # history before a gap that conditions the fill, s
CONTEXT_POINTS = 400  # at most this many history samples (evenly thinned)
AFTER_POINTS = 200  # at most this many samples after the gap (evenly thinned)
STANDSTILL_MPS = 0.1  # below: no track signal, the fill is the mean
MEAN_STD = 1e-3  # uncertainty of the running mean (slow bias drift), m/s^2
ERROR_BLOCKS = 200  # the error variance sums the gap in at most this many blocks
RANK_TOLERANCE = 1e-9  # posterior eigenvalues below this fraction of the largest are dropped

Taps = Callable[[float], np.ndarray]  # speed (m/s) -> zero-phase band FIR (2 d + 1,) at the rate
#: (f (F,) Hz, speed m/s) -> the accelerometer's response (F,) per metre of profile: a model's
#: ``track_response`` (the coach); None: the quarter car theta's G
Response = Callable[[np.ndarray, float], np.ndarray]


def acceleration_covariance(theta: np.ndarray, speed_mps: float, av: float, rate_hz: float,
                            response: Response | None = None) -> np.ndarray:
    """R(k / rate_hz) ((m/s^2)^2) of the car-body acceleration for lags k = 0 .. TABLE_S rate
    (the vehicle: ``response`` when given, else the quarter car theta)."""
    n = fft.next_fast_len(int(2 * TABLE_S * rate_hz), real=True)
    f = fft.rfftfreq(n, 1.0 / rate_hz)
    w = 2 * np.pi * f[1:]
    omega = w / speed_mps
    s_t = av * OMEGA_C ** 2 / ((omega ** 2 + OMEGA_R ** 2) * (omega ** 2 + OMEGA_C ** 2))
    s_a = np.zeros(f.size)
    g = frequency_response(theta, 1j * w) if response is None else response(f[1:], speed_mps)
    s_a[1:] = np.abs(g) ** 2 * s_t / speed_mps
    dw = 2 * np.pi * rate_hz / n
    return fft.irfft(s_a * dw, n)[:n // 2] * (n / 2)  # sum_k S_a(w_k) cos(w_k tau) dw


class GapFiller:
    """Fills bridged samples from the history before the gap and the sample after it.

    ``theta`` (5,): the vehicle; ``av``: German spectrum amplitude (m rad); ``rate_hz``: the IMU
    rate; ``noise_var``: the sensor's white-noise variance ((m/s^2)^2). The history is the last
    CONTEXT_S of accepted samples by count and the mean a sum in sample order: the fill does
    not depend on how the stream is chunked. With ``taps`` (the band FIR from acceleration to
    u at a speed) every fill also leaves in ``errors`` (first, variance): the variance (m^2) of
    the output error it causes at the outputs from sample ``first`` on (counted over the
    samples ``bridge`` released since the reset; ``error_variance``); the caller takes them
    away. ``hold``: accepted samples after a gap that its fill waits for (at least 1: the
    sample that ended it). ``response``: the vehicle's accelerometer response instead of the
    quarter car theta's (a coach).
    """

    def __init__(self, theta: np.ndarray, av: float, rate_hz: float, noise_var: float,
                 taps: Taps | None = None, hold: int = 1,
                 response: Response | None = None) -> None:
        self.theta = np.asarray(theta, float)
        self.response = response
        self.av = av
        self.rate_hz = rate_hz
        self.noise_var = noise_var
        self.keep = max(2, round(CONTEXT_S * rate_hz))
        self._table: tuple[float, np.ndarray] | None = None  # (speed, covariance table)
        self._chol: tuple[tuple, tuple[np.ndarray, bool]] | None = None  # (key, factor)
        self._taps = taps
        self.hold = max(1, int(hold))
        self.errors: list[tuple[int, np.ndarray]] = []
        self.reset()

    def reset(self) -> None:
        """Forget the history (a filter restart)."""
        self._t = np.zeros(2 * self.keep, np.int64)  # history buffers: the last self._n
        self._a = np.zeros(2 * self.keep)  # entries, moved to the front when full
        self._n = 0
        self._sum, self._count = 0.0, 0
        self._held: tuple[np.ndarray, ...] | None = None  # samples from an unfilled gap on
        self._released = 0  # samples released since the reset

    @property
    def stamps(self) -> np.ndarray:
        """Stamps (ns) of the remembered samples, oldest first."""
        return self._t[max(0, self._n - self.keep):self._n]

    @property
    def accel(self) -> np.ndarray:
        """Accelerations (m/s^2) of the remembered samples, oldest first."""
        return self._a[max(0, self._n - self.keep):self._n]

    def bridge(self, stamps_ns: np.ndarray, accel: np.ndarray, synthetic: np.ndarray,
               speed_mps: np.ndarray, *extra: np.ndarray) -> tuple[np.ndarray, ...]:
        """Samples in, samples released: (stamps, accel, synthetic, speed, *extra), all (N,),
        with every run of synthetic samples replaced by its fill once ``hold`` accepted samples
        after it have come (the samples from such a run on wait here; ``extra`` columns wait
        with them). The accepted samples are remembered. A run ends at an accepted sample (the
        sanitiser's contract: the sample that closed the gap)."""
        cols = (stamps_ns, accel, synthetic, speed_mps, *extra)
        if self._held is None and not synthetic.any():  # the usual case: no copy
            self._observe(stamps_ns, accel)
            self._released += accel.size
            return cols
        if self._held is not None:
            cols = tuple(np.concatenate([h, c]) for h, c in zip(self._held, cols, strict=True))
        return self._release(cols, final=False)

    def flush(self) -> tuple[np.ndarray, ...] | None:
        """The waiting samples (columns as ``bridge``), their gaps filled from the samples
        there are; None when nothing waits. Then the filler starts afresh."""
        held, self._held = self._held, None
        out = None if held is None else self._release(held, final=True)
        self.reset()
        return out

    def _release(self, cols: tuple[np.ndarray, ...], final: bool) -> tuple[np.ndarray, ...]:
        """Fill the gaps of cols whose hold is complete (all with ``final``) and release the
        samples up to the first gap that must still wait."""
        stamps, accel, synthetic, speed = cols[:4]
        out = np.array(accel, dtype=float)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], synthetic.view(np.int8), [0]])))
        starts, stops = edges[::2], edges[1::2]
        lo, end = 0, out.size
        for i, (start, stop) in enumerate(zip(starts, stops, strict=True)):
            following = int(starts[i + 1]) if i + 1 < starts.size else out.size
            count = min(self.hold, following - stop)
            if count < self.hold and following == out.size and not final:
                end = int(start)  # wait for more samples after this gap
                break
            self._observe(stamps[lo:start], accel[lo:start])
            after = slice(stop, stop + count)
            v = float(speed[stop]) if count else float(speed[start])
            gap = stamps[start:stop]
            out[start:stop] = self.fill(gap, stamps[after], accel[after], v)
            if self._taps is not None and abs(v) >= STANDSTILL_MPS:
                taps = self._taps(abs(v))
                self.errors.append((self._released + int(start) - (taps.size - 1) // 2,
                                    self.error_variance(gap, stamps[after], v, taps)))
            lo = stop
        self._observe(stamps[lo:end], accel[lo:end])
        self._held = tuple(c[end:] for c in cols) if end < out.size else None
        self._released += end
        return (stamps[:end], out[:end], *(c[:end] for c in cols[2:]))

    def _observe(self, stamps_ns: np.ndarray, accel: np.ndarray) -> None:
        """Remember accepted samples (a buffer, not a concatenation: the live push is one
        sample) and add them to the running sum in sample order."""
        n = accel.size
        if not n:
            return
        if n >= self.keep:
            self._t[:self.keep], self._a[:self.keep] = stamps_ns[-self.keep:], accel[-self.keep:]
            self._n = self.keep
        else:
            if self._n + n > self._t.size:  # keep the newest keep - 1 or fewer at the front
                old = self._n - (self.keep - n) if self._n > self.keep - n else 0
                self._t[:self._n - old] = self._t[old:self._n]
                self._a[:self._n - old] = self._a[old:self._n]
                self._n -= old
            self._t[self._n:self._n + n], self._a[self._n:self._n + n] = stamps_ns, accel
            self._n += n
        if n == 1:
            self._sum += float(accel[0])
        else:
            self._sum = float(np.cumsum(np.concatenate([[self._sum], accel]))[-1])
        self._count += n

    def _covariance(self, speed: float) -> np.ndarray:
        if self._table is None or self._table[0] != speed:
            self._table = (speed, acceleration_covariance(self.theta, speed, self.av,
                                                          self.rate_hz, self.response))
        return self._table[1]

    def _history(self) -> tuple[np.ndarray, np.ndarray]:
        """The history thinned to CONTEXT_POINTS, newest kept: stamps (ns), accel (m/s^2)."""
        stride = max(1, -(-self.stamps.size // CONTEXT_POINTS))
        return self.stamps[::-1][::stride][::-1], self.accel[::-1][::stride][::-1]

    def _cov(self, speed_mps: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """Covariance ((m/s^2)^2) between two stamp arrays (ns) at the speed, plus the mean's."""
        table = self._covariance(abs(speed_mps))
        lags = np.arange(table.size) / self.rate_hz

        def cov(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return np.interp(np.abs(a[:, None] - b[None, :]) * 1e-9, lags, table,
                             right=0.0) + MEAN_STD ** 2
        return cov

    def _observed(self, after_ns: np.ndarray, after: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """The conditioning samples: the history and the samples after the gap, each thinned
        (newest history and oldest after kept): stamps (ns), accel (m/s^2)."""
        stride = max(1, -(-after_ns.size // AFTER_POINTS))
        stamps, accel = self._history()
        a = np.zeros(after_ns.size) if after is None else after
        return (np.concatenate([stamps, after_ns[::stride]]),
                np.concatenate([accel, a[::stride]]))

    def fill(self, gap_ns: np.ndarray, after_ns: np.ndarray, after: np.ndarray,
             speed_mps: float) -> np.ndarray:
        """Conditional mean (m/s^2) at the gap stamps (K,) ns given the history and the samples
        after the gap (stamps after_ns (M,) ns, values after (M,) m/s^2), at the gap's speed
        (m/s)."""
        t_obs, y = self._observed(after_ns, after)
        mean = self._sum / self._count if self._count else float(np.mean(y))
        if abs(speed_mps) < STANDSTILL_MPS:
            return np.full(gap_ns.size, mean)
        return mean + self._cov(speed_mps)(gap_ns, t_obs) @ linalg.cho_solve(
            self._factor(t_obs, speed_mps), y - mean)

    def _factor(self, t_obs: np.ndarray, speed_mps: float) -> tuple[np.ndarray, bool]:
        """Cholesky factor of the covariance of the conditioning samples t_obs (ns), kept for
        the next call with the same samples (a fill and its error variance)."""
        key = (t_obs.tobytes(), speed_mps)
        if self._chol is None or self._chol[0] != key:
            c_oo = self._cov(speed_mps)(t_obs, t_obs) + self.noise_var * np.eye(t_obs.size)
            self._chol = (key, linalg.cho_factor(c_oo))
        return self._chol[1]

    def fill_covariance(self, gap_ns: np.ndarray, after_ns: np.ndarray, speed_mps: float,
                        blocks: np.ndarray | None = None) -> np.ndarray:
        """Posterior covariance (K, K) ((m/s^2)^2) of the fill's error in the model: what the
        history and the samples after the gap (stamps after_ns (M,)) cannot tell about it.
        ``blocks`` (B, K): that of the block sums ``blocks @ error`` instead, (B, B)."""
        t_obs = self._observed(after_ns)[0]
        cov = self._cov(speed_mps)
        c_go, c_gg = cov(gap_ns, t_obs), cov(gap_ns, gap_ns)
        if blocks is not None:
            c_go, c_gg = blocks @ c_go, blocks @ c_gg @ blocks.T
        return c_gg - c_go @ linalg.cho_solve(self._factor(t_obs, speed_mps), c_go.T)

    def error_variance(self, gap_ns: np.ndarray, after_ns: np.ndarray, speed_mps: float,
                       taps: np.ndarray) -> np.ndarray:
        """Variance (K + 2 d,) m^2 of the output error the fill of gap_ns (K,) leaves at the
        outputs from d samples before the gap's first sample to d after its last (taps (2 d + 1,):
        the band FIR, u[n] = sum_j taps[j] a[n + d - j]): diag(W P W^T), P = fill_covariance.

        Computed as sum_r (taps * sqrt(lambda_r) v_r)^2 over the eigenpairs of P (rank-reduced
        at RANK_TOLERANCE), with the gap summed in blocks of ceil(K / ERROR_BLOCKS) samples (a
        block's weight taken at its centre: exact up to 200 samples, a fraction of a band period
        beyond) so that a 1 s gap costs a 200 x 200 eigenproblem."""
        k = gap_ns.size
        stride = -(-k // ERROR_BLOCKS)
        first = np.arange(0, k, stride)
        blocks = (np.arange(k)[None, :] // stride == np.arange(first.size)[:, None]).astype(float)
        lam, vec = np.linalg.eigh(self.fill_covariance(gap_ns, after_ns, speed_mps, blocks))
        big = lam > RANK_TOLERANCE * max(lam[-1], 0.0)
        if not big.any():
            return np.zeros(k + taps.size - 1)
        impulses = np.zeros((int(big.sum()), k))
        centres = np.minimum(first + stride // 2, k - 1)
        impulses[:, centres] = (vec[:, big] * np.sqrt(lam[big])).T
        return np.sum(signal.oaconvolve(impulses, taps[None, :], axes=-1) ** 2, axis=0)
