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
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import fft, linalg

from railgsa_ros.inverse.kalman import OMEGA_C, OMEGA_R
from railgsa_ros.vehicle import frequency_response

TABLE_S = 64.0  # span of the covariance table, s (frequency resolution 1 / TABLE_S Hz)
CONTEXT_S = 1.0  # history before a gap that conditions the fill, s
CONTEXT_POINTS = 400  # at most this many history samples (evenly thinned)
STANDSTILL_MPS = 0.1  # below: no track signal, the fill is the mean
MEAN_STD = 0.01  # uncertainty of the running mean (slow bias drift), m/s^2


def acceleration_covariance(theta: np.ndarray, speed_mps: float, av: float, rate_hz: float
                            ) -> np.ndarray:
    """R(k / rate_hz) ((m/s^2)^2) of the car-body acceleration for lags k = 0 .. TABLE_S rate."""
    n = fft.next_fast_len(int(2 * TABLE_S * rate_hz), real=True)
    f = fft.rfftfreq(n, 1.0 / rate_hz)
    w = 2 * np.pi * f[1:]
    omega = w / speed_mps
    s_t = av * OMEGA_C ** 2 / ((omega ** 2 + OMEGA_R ** 2) * (omega ** 2 + OMEGA_C ** 2))
    s_a = np.zeros(f.size)
    s_a[1:] = np.abs(frequency_response(theta, 1j * w)) ** 2 * s_t / speed_mps
    dw = 2 * np.pi * rate_hz / n
    return fft.irfft(s_a * dw, n)[:n // 2] * (n / 2)  # sum_k S_a(w_k) cos(w_k tau) dw


class GapFiller:
    """Fills bridged samples from the history before the gap and the sample after it.

    ``theta`` (5,): the vehicle; ``av``: German spectrum amplitude (m rad); ``rate_hz``: the IMU
    rate; ``noise_var``: the sensor's white-noise variance ((m/s^2)^2). The history is the last
    CONTEXT_S of accepted samples by count and the mean a sum in sample order: the fill does
    not depend on how the stream is chunked.
    """

    def __init__(self, theta: np.ndarray, av: float, rate_hz: float, noise_var: float) -> None:
        self.theta = np.asarray(theta, float)
        self.av = av
        self.rate_hz = rate_hz
        self.noise_var = noise_var
        self.keep = max(2, round(CONTEXT_S * rate_hz))
        self._table: tuple[float, np.ndarray] | None = None  # (speed, covariance table)
        self.reset()

    def reset(self) -> None:
        """Forget the history (a filter restart)."""
        self._t = np.zeros(2 * self.keep, np.int64)  # history buffers: the last self._n
        self._a = np.zeros(2 * self.keep)  # entries, moved to the front when full
        self._n = 0
        self._sum, self._count = 0.0, 0

    @property
    def stamps(self) -> np.ndarray:
        """Stamps (ns) of the remembered samples, oldest first."""
        return self._t[max(0, self._n - self.keep):self._n]

    @property
    def accel(self) -> np.ndarray:
        """Accelerations (m/s^2) of the remembered samples, oldest first."""
        return self._a[max(0, self._n - self.keep):self._n]

    def bridge(self, stamps_ns: np.ndarray, accel: np.ndarray, synthetic: np.ndarray,
               speed_mps: np.ndarray) -> np.ndarray:
        """accel (N,) m/s^2 with every run of synthetic samples replaced by its fill; the
        accepted samples are remembered. A run ends at an accepted sample (the sanitiser's
        contract: the sample that closed the gap)."""
        if not synthetic.any():
            self._observe(stamps_ns, accel)
            return accel
        out = np.array(accel, dtype=float)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], synthetic.view(np.int8), [0]])))
        lo = 0
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            self._observe(stamps_ns[lo:start], accel[lo:start])
            if stop < out.size:
                out[start:stop] = self.fill(stamps_ns[start:stop], int(stamps_ns[stop]),
                                            float(accel[stop]), float(speed_mps[stop]))
            lo = stop
        self._observe(stamps_ns[lo:], accel[lo:])
        return out

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
                                                          self.rate_hz))
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

    def fill(self, gap_ns: np.ndarray, after_ns: int, after: float, speed_mps: float
             ) -> np.ndarray:
        """Conditional mean (m/s^2) at the gap stamps (K,) ns given the history and the sample
        (after_ns, after) that ended the gap, at the gap's speed (m/s)."""
        stamps, accel = self._history()
        t_obs, y = np.append(stamps, after_ns), np.append(accel, after)
        mean = self._sum / self._count if self._count else float(np.mean(y))
        if abs(speed_mps) < STANDSTILL_MPS:
            return np.full(gap_ns.size, mean)
        cov = self._cov(speed_mps)
        c_oo = cov(t_obs, t_obs) + self.noise_var * np.eye(t_obs.size)
        return mean + cov(gap_ns, t_obs) @ linalg.cho_solve(linalg.cho_factor(c_oo), y - mean)

    def fill_covariance(self, gap_ns: np.ndarray, after_ns: int, speed_mps: float
                        ) -> np.ndarray:
        """Posterior covariance (K, K) ((m/s^2)^2) of the fill's error in the model: what the
        data before and after cannot tell about the gap (the limit of any linear bridge)."""
        t_obs = np.append(self._history()[0], after_ns)
        cov = self._cov(speed_mps)
        c_oo = cov(t_obs, t_obs) + self.noise_var * np.eye(t_obs.size)
        c_go = cov(gap_ns, t_obs)
        return cov(gap_ns, gap_ns) - c_go @ linalg.cho_solve(linalg.cho_factor(c_oo), c_go.T)
